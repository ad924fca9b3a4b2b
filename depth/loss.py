"""The multi-stage loss: mean over targets of sum_s 0.8^(3-s) * E(D_s, GT) on valid pixels.

E is the paper's L1 in metres (`l1`), or the L1 of log depth (`log_l1`): the relative error,
which weighs a near wall as much as a far one, as Abs Rel and the depth-range planes do.
An optional gradient term (`grad_weight`) adds the multi-scale gradient of the log-depth residual
of the full-resolution output: zero for a map that is right up to scale, large where the
prediction smooths over an edge the ground truth has, so it rewards depth that follows the image.
`near_factor` > 1 weighs depth that is too near that many times as much as depth too far: a surface
put in front of the true one costs the fused mesh more than one put behind it, which the evaluation's
visibility culling drops (experiments/error_sides.py), so where the network is unsure it should err far.
`near_margin` m > 0 spares the small near errors: only the part of a near error beyond m (a prediction more
than the fraction m nearer than the truth) weighs the extra F - 1, so the bulk of the pixels, and with them the
map's scale, keep the symmetric loss and only the too-near tail that the mesh pays for is pushed back.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F

STAGE_DECAY = 0.8
LOSSES = ("l1", "log_l1")


def stage_weights(num_stages: int = 4, decay: float = STAGE_DECAY) -> list[float]:
    """Weights of D0..D{n-1}: the full-resolution output weighs 1, each earlier stage `decay` less."""
    return [decay ** (num_stages - 1 - s) for s in range(num_stages)]


def _pixel_error(pred: torch.Tensor, target: torch.Tensor, kind: str, near_factor: float = 1.0,
                 near_margin: float = 0.0) -> torch.Tensor:
    """Per-pixel error; a near error beyond `near_margin` (fraction of the truth) weighs `near_factor` times."""
    if kind == "l1":
        nearer, tolerance = target - pred, near_margin * target
    elif kind == "log_l1":
        nearer = torch.log(target.clamp_min(1e-3)) - torch.log(pred.clamp_min(1e-3))
        tolerance = -math.log1p(-near_margin)
    else:
        raise ValueError(f"unknown loss {kind!r} (expected one of {LOSSES})")
    err = nearer.abs()
    return err if near_factor == 1.0 else err + (near_factor - 1.0) * (nearer - tolerance).clamp_min(0.0)


def log_gradient_error(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor, scales: int = 4
                       ) -> torch.Tensor:
    """Mean |d/dx R| + |d/dy R| of R = log pred - log target over `scales` strides (1, 2, 4, ...).

    pred, target: (B, 1, H, W) metres; valid: (B, 1, H, W) bool. Only differences between two
    valid pixels count. Scale-invariant: pred = c * target gives 0.
    """
    residual = torch.log(pred.clamp_min(1e-3)) - torch.log(target.clamp_min(1e-3))
    total = pred.new_zeros(())
    for k in range(scales):
        r, v = residual[..., ::2 ** k, ::2 ** k], valid[..., ::2 ** k, ::2 ** k]
        dx, vx = (r[..., :, 1:] - r[..., :, :-1]).abs(), v[..., :, 1:] & v[..., :, :-1]
        dy, vy = (r[..., 1:, :] - r[..., :-1, :]).abs(), v[..., 1:, :] & v[..., :-1, :]
        count = vx.sum() + vy.sum()
        if count > 0:
            total = total + ((dx * vx).sum() + (dy * vy).sum()) / count
    return total / scales


def multi_stage_loss(depths: list[list[torch.Tensor]], gt: torch.Tensor, kind: str = "l1",
                     decay: float = STAGE_DECAY, grad_weight: float = 0.0, near_factor: float = 1.0,
                     near_margin: float = 0.0) -> tuple[torch.Tensor, list[float]]:
    """Loss over targets and stages.

    depths[t][s]: (B, 1, h_s, w_s) predicted depth of target t at stage s; gt: (B, T, H, W)
    metres, 0 = invalid. Lower-resolution predictions are upsampled (bilinear) to the
    GT resolution, so every stage is judged on the same pixels. Returns the loss and the
    per-stage error averaged over targets (for logging). `grad_weight` > 0 adds that much of
    `log_gradient_error` of the last (full-resolution) stage per target; `near_factor` weighs depth too near
    (beyond `near_margin`).
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
            err = (_pixel_error(pred.float(), target, kind, near_factor, near_margin) * valid).sum() / count
            total = total + w * err
            per_stage[s] += float(err.detach()) / len(depths)
        if grad_weight > 0:
            total = total + grad_weight * log_gradient_error(pred.float(), target, valid)
    return total / len(depths), per_stage

