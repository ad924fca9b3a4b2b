"""Matching features: a PSMNet-style residual CNN with spatial pyramid pooling, 1/4 resolution."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..config import ESTConfig
from .layers import conv2d_bn


class ResidualBlock2d(nn.Module):
    """Two 3x3 convs with a (projected) shortcut; no ReLU after the sum, as in PSMNet."""

    def __init__(self, cin: int, cout: int, stride: int, dilation: int):
        super().__init__()
        self.body = nn.Sequential(conv2d_bn(cin, cout, 3, stride, dilation),
                                  conv2d_bn(cout, cout, 3, 1, dilation, relu=False))
        self.shortcut = (nn.Identity() if stride == 1 and cin == cout
                         else conv2d_bn(cin, cout, 1, stride, relu=False))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x) + self.shortcut(x)


class SPPFeatures(nn.Module):
    """Image (B, 3, H, W) -> matching features (B, F, H/4, W/4).

    Stem (three 3x3 convs, stride 2), four residual groups (the second with stride 2,
    the last dilated), average-pooled pyramid branches on the last group, and a fusion
    of the 1/4-res group-2 and group-4 features with the pyramid.
    """

    def __init__(self, cfg: ESTConfig):
        super().__init__()
        s = cfg.feature_stem_channels
        self.stem = nn.Sequential(conv2d_bn(3, s, 3, 2), conv2d_bn(s, s), conv2d_bn(s, s))
        groups, cin = [], s
        for i, (n, c, dil) in enumerate(zip(cfg.feature_block_counts, cfg.feature_block_channels,
                                            cfg.feature_block_dilations)):
            blocks = [ResidualBlock2d(cin if k == 0 else c, c, 2 if (i == 1 and k == 0) else 1, dil)
                      for k in range(n)]
            groups.append(nn.Sequential(*blocks))
            cin = c
        self.groups = nn.ModuleList(groups)
        self.pool_sizes = cfg.spp_pool_sizes
        self.branches = nn.ModuleList(conv2d_bn(cin, cfg.spp_branch_channels, 1) for _ in cfg.spp_pool_sizes)
        fused = cfg.feature_block_channels[1] + cin + cfg.spp_branch_channels * len(cfg.spp_pool_sizes)
        self.fuse = nn.Sequential(conv2d_bn(fused, cin, 3),
                                  nn.Conv2d(cin, cfg.feature_channels, 1, bias=False))

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        x = self.stem(image)
        x = self.groups[0](x)
        quarter = self.groups[1](x)
        x = self.groups[3](self.groups[2](quarter))
        h, w = x.shape[-2:]
        pyramid = [quarter, x]
        for size, branch in zip(self.pool_sizes, self.branches):
            k = (min(size, h), min(size, w))
            pooled = branch(F.avg_pool2d(x, k, k))
            pyramid.append(F.interpolate(pooled, (h, w), mode="bilinear", align_corners=False))
        return self.fuse(torch.cat(pyramid, 1))


class PyramidFeatures(nn.Module):
    """Encoder features at 1/4, 1/8, 1/16 -> matching features (B, F, H/4, W/4), FPN style.

    Each level is projected to F channels (1x1), the coarser sum is upsampled onto the finer one,
    and a 3x3 conv smooths the 1/4-res result: pretrained semantics, 1/4-res localisation.
    """

    def __init__(self, encoder_channels: list[int], channels: int):
        super().__init__()
        self.lateral = nn.ModuleList(nn.Conv2d(c, channels, 1) for c in encoder_channels)
        self.output = nn.Sequential(conv2d_bn(channels, channels), nn.Conv2d(channels, channels, 1, bias=False))

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        x = self.lateral[-1](feats[-1])
        for lateral, f in zip(self.lateral[-2::-1], feats[-2::-1]):
            x = lateral(f) + F.interpolate(x, size=f.shape[-2:], mode="bilinear", align_corners=False)
        return self.output(x)
