"""The multi-stage loss: mean over targets of sum_s 0.8^(3-s) * E(D_s, GT) on valid pixels.

E is the paper's L1 in metres (`l1`), or the L1 of log depth (`log_l1`): the relative error,
which weighs a near wall as much as a far one, as Abs Rel and the depth-range planes do.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

STAGE_DECAY = 0.8
LOSSES = ("l1", "log_l1")


def stage_weights(num_stages: int = 4, decay: float = STAGE_DECAY) -> list[float]:
    """Weights of D0..D{n-1}: the full-resolution output weighs 1, each earlier stage `decay` less."""
    return [decay ** (num_stages - 1 - s) for s in range(num_stages)]


def _pixel_error(pred: torch.Tensor, target: torch.Tensor, kind: str) -> torch.Tensor:
    if kind == "l1":
        return (pred - target).abs()
    if kind == "log_l1":
        return (torch.log(pred.clamp_min(1e-3)) - torch.log(target.clamp_min(1e-3))).abs()
    raise ValueError(f"unknown loss {kind!r} (expected one of {LOSSES})")


def multi_stage_loss(depths: list[list[torch.Tensor]], gt: torch.Tensor, kind: str = "l1",
                     decay: float = STAGE_DECAY) -> tuple[torch.Tensor, list[float]]:
    """Loss over targets and stages.

    depths[t][s]: (B, 1, h_s, w_s) predicted depth of target t at stage s; gt: (B, T, H, W)
    metres, 0 = invalid. Lower-resolution predictions are upsampled (bilinear) to the
    GT resolution, so every stage is judged on the same pixels. Returns the loss and the
    per-stage error averaged over targets (for logging).
    """
    weights = stage_weights(len(depths[0]), decay)
    total = gt.new_zeros(())
    per_stage = [0.0] * len(weights)
    for t, stages in enumerate(depths):
        target = gt[:, t:t + 1]
        valid = (target > 0) & torch.isfinite(target)
        count = valid.sum()
        if count == 0:
            continue
        target = torch.where(valid, target, torch.ones_like(target))
        for s, (w, pred) in enumerate(zip(weights, stages)):
            if pred.shape[-2:] != target.shape[-2:]:
                pred = F.interpolate(pred, target.shape[-2:], mode="bilinear", align_corners=False)
            err = (_pixel_error(pred.float(), target, kind) * valid).sum() / count
            total = total + w * err
            per_stage[s] += float(err.detach()) / len(depths)
    return total / len(depths), per_stage

