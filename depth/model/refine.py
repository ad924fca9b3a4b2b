"""RefineNet: two image-guided stages from the 1/4-res depth to 1/2 and full resolution."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..config import ESTConfig
from .layers import conv2d_bn


def _to_logit(depth: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    t = ((depth - lo) / (hi - lo)).clamp(1e-4, 1 - 1e-4)
    return torch.log(t) - torch.log1p(-t)


def keep_median(depth: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """`depth` (B, 1, H, W) rescaled per item so its median equals the median of `reference` (B, 1, h, w)."""
    ratio = reference.flatten(1).median(1).values / depth.flatten(1).median(1).values.clamp_min(1e-6)
    return depth * ratio[:, None, None, None]


class RefineNet(nn.Module):
    """Coarse depth (B, 1, h, w) + guidance -> depth at (2h, 2w) and (4h, 4w).

    Stage 1 reads the context map and the fused plane logits at 1/4, upsamples, adds the
    1/2-res encoder feature; stage 2 upsamples again and adds the RGB image. Each stage
    predicts a correction in logit space of the normalised depth, so the output stays
    inside [min_depth, max_depth] and starts as the upsampled coarse depth. With
    `cfg.refine_keeps_scale` both outputs are rescaled to the coarse depth's median (then clamped to
    the range): the stages add edges and detail, the scale stays the EST stage's.
    """

    def __init__(self, cfg: ESTConfig, half_channels: int):
        super().__init__()
        c1, c2 = cfg.refine_channels
        self.stage1_in = conv2d_bn(2 * cfg.num_planes, c1)
        self.stage1_out = conv2d_bn(c1 + half_channels, c1)
        self.stage1_depth = nn.Conv2d(c1, 1, 3, 1, 1)
        self.stage2_in = conv2d_bn(c1, c2)
        self.stage2_out = conv2d_bn(c2 + 3, c2)
        self.stage2_depth = nn.Conv2d(c2, 1, 3, 1, 1)
        self.keeps_scale = cfg.refine_keeps_scale

    def forward(self, depth: torch.Tensor, context: torch.Tensor, logits: torch.Tensor, half: torch.Tensor,
                image: torch.Tensor, depth_range: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """depth (B,1,h,w); context, logits (B,D,h,w); half (B,Ch,2h,2w); image (B,3,4h,4w);
        depth_range (B, 2) -> depth_half (B,1,2h,2w), depth_full (B,1,4h,4w)."""
        lo, hi = depth_range[:, :1, None, None], depth_range[:, 1:, None, None]
        x = F.interpolate(self.stage1_in(torch.cat([context, F.relu(logits)], 1)), scale_factor=2, mode="nearest")
        x = self.stage1_out(torch.cat([x, half], 1))
        up = F.interpolate(depth, scale_factor=2, mode="bilinear", align_corners=False)
        depth_half = lo + (hi - lo) * torch.sigmoid(_to_logit(up, lo, hi) + self.stage1_depth(x))
        x = F.interpolate(self.stage2_in(x), scale_factor=2, mode="nearest")
        x = self.stage2_out(torch.cat([x, image], 1))
        up = F.interpolate(depth_half, scale_factor=2, mode="bilinear", align_corners=False)
        depth_full = lo + (hi - lo) * torch.sigmoid(_to_logit(up, lo, hi) + self.stage2_depth(x))
        if self.keeps_scale:
            depth_half = torch.minimum(torch.maximum(keep_median(depth_half, depth), lo), hi)
            depth_full = torch.minimum(torch.maximum(keep_median(depth_full, depth), lo), hi)
        return depth_half, depth_full
