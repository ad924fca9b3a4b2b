"""The multi-stage L1 loss: mean over targets of sum_s 0.8^(3-s) * L1(D_s, GT) on valid pixels."""
from __future__ import annotations

import torch
import torch.nn.functional as F

STAGE_DECAY = 0.8


def stage_weights(num_stages: int = 4, decay: float = STAGE_DECAY) -> list[float]:
    """Weights of D0..D{n-1}: the full-resolution output weighs 1, each earlier stage `decay` less."""
    return [decay ** (num_stages - 1 - s) for s in range(num_stages)]


def multi_stage_l1(depths: list[list[torch.Tensor]], gt: torch.Tensor, decay: float = STAGE_DECAY,
                   ) -> tuple[torch.Tensor, list[float]]:
    """Loss over targets and stages.

    depths[t][s]: (B, 1, h_s, w_s) predicted depth of target t at stage s; gt: (B, T, H, W)
    metres, 0 = invalid. Lower-resolution predictions are upsampled (bilinear) to the
    GT resolution, so every stage is judged on the same pixels. Returns the loss and the
    per-stage L1 averaged over targets (for logging).
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
        for s, (w, pred) in enumerate(zip(weights, stages)):
            if pred.shape[-2:] != target.shape[-2:]:
                pred = F.interpolate(pred, target.shape[-2:], mode="bilinear", align_corners=False)
            l1 = ((pred.float() - target).abs() * valid).sum() / count
            total = total + w * l1
            per_stage[s] += float(l1.detach()) / len(depths)
    return total / len(depths), per_stage
