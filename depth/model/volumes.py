"""Cost volumes: raw matching volume, MatchNet, hybrid volume, key/value convs, depth head."""
from __future__ import annotations

import torch
from torch import nn

from ..config import ESTConfig
from ..geometry import plane_sweep_warp
from .layers import Conv3d, conv3d_bn


class MatchNet(nn.Module):
    """Per-source raw volumes [ref, warped src] (2F, D, h, w) -> one matching volume (B, C, D, h, w).

    Three 3D convs per source (a 1x1x1 projection to C and a residual pair of 3x3x3),
    view-average pooling over sources, then `match_regularisation_layers` 3x3x3 convs.
    The 1x1x1 projection of the concatenated raw volume equals a projection of the
    reference features plus a projection of the warped source features, and warping
    (bilinear sampling) commutes with a per-pixel linear map, so both halves are applied
    in 2D before the sweep: the same function, without materialising the 2F-channel volume.
    With `match_metadata`, two more channels per source join before the projection: the mean
    dot product of reference and warped source features (an explicit match score) and the mask
    of planes the source sees.
    """

    def __init__(self, cfg: ESTConfig):
        super().__init__()
        c, f = cfg.volume_channels, cfg.feature_channels
        self.project_ref = nn.Conv2d(f, c, 1, bias=False)
        self.project_src = nn.Conv2d(f, c, 1, bias=False)
        self.project_meta = Conv3d(2, c, 1, bias=False) if cfg.match_metadata else None
        self.project_norm = nn.BatchNorm3d(c)
        self.residual = nn.Sequential(conv3d_bn(c, c), conv3d_bn(c, c, activation=None))
        self.regularise = nn.Sequential(*[conv3d_bn(c, c) for _ in range(cfg.match_regularisation_layers)])

    def forward(self, ref_features: torch.Tensor, src_features: torch.Tensor, K: torch.Tensor,
                ref_camera_to_world: torch.Tensor, src_camera_to_world: torch.Tensor,
                planes: torch.Tensor) -> torch.Tensor:
        """ref_features (B, F, h, w); src_features (B, S, F, h, w); K (B, 3, 3) at 1/4 res;
        poses (B, 4, 4) and (B, S, 4, 4); planes (B, D) -> (B, C, D, h, w)."""
        ref_part = self.project_ref(ref_features).unsqueeze(2)
        src_parts = self.project_src(src_features.flatten(0, 1)).unflatten(0, src_features.shape[:2])
        c, total = ref_part.shape[1], None
        for s in range(src_features.shape[1]):
            src = src_parts[:, s] if self.project_meta is None else torch.cat([src_parts[:, s], src_features[:, s]], 1)
            warped, valid = plane_sweep_warp(src, K, K, ref_camera_to_world, src_camera_to_world[:, s], planes)
            mask = valid.unsqueeze(1).to(warped.dtype)
            x = ref_part + warped[:, :c] * mask
            if self.project_meta is not None:
                score = (ref_features.unsqueeze(2) * warped[:, c:]).mean(1, keepdim=True)
                x = x + self.project_meta(torch.cat([score * mask, mask], 1))
            x = self.project_norm(x)
            x = x + self.residual(x)
            total = x if total is None else total + x
        return self.regularise(total / src_features.shape[1])


class HybridVolume(nn.Module):
    """Matching volume (B, C, D, h, w) + context map (B, D, h, w) -> key, value (B, C/2, D, h, w).

    The context map becomes a one-channel volume concatenated to the matching volume
    (C+1 channels), regularised by one 3x3x3 conv, then shared key (ReLU) and value
    (tanh) convolutions.
    """

    def __init__(self, cfg: ESTConfig):
        super().__init__()
        c = cfg.volume_channels
        self.mix = conv3d_bn(c + 1, c + 1)
        self.key = conv3d_bn(c + 1, c // 2, activation="relu")
        self.value = conv3d_bn(c + 1, c // 2, activation="tanh")

    def forward(self, matching: torch.Tensor, context: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = self.mix(torch.cat([context.unsqueeze(1), matching], 1))
        return self.key(x), self.value(x)


class DepthHead(nn.Module):
    """Value volume (B, c, D, h, w) -> plane logits (B, D, h, w): a 3x3x3 conv then a 1x1x1 conv."""

    def __init__(self, channels: int):
        super().__init__()
        self.body = nn.Sequential(conv3d_bn(channels, channels), Conv3d(channels, 1, 1))

    def forward(self, volume: torch.Tensor) -> torch.Tensor:
        return self.body(volume).squeeze(1)


def soft_argmax_depth(logits: torch.Tensor, planes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Expected depth under softmax(logits) over planes, and the peak probability as confidence.

    logits (B, D, h, w); planes (B, D) -> depth (B, 1, h, w), confidence (B, 1, h, w).
    """
    prob = torch.softmax(logits.float(), dim=1)
    depth = (prob * planes.float()[:, :, None, None]).sum(1, keepdim=True)
    return depth.to(logits.dtype), prob.amax(1, keepdim=True).to(logits.dtype)
