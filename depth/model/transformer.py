"""EST transformer: attention over epipolar-warped memory volumes, fused into the query value."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from ..geometry import epipolar_warp_volume
from .layers import Conv3d


@dataclass
class MemoryEntry:
    """Key and (fused) value volumes of one estimated frame, kept for later frames.

    key, value: (B, C/2, D, h, w) in the frame's own camera; camera_to_world (B, 4, 4).
    """

    key: torch.Tensor
    value: torch.Tensor
    camera_to_world: torch.Tensor
    name: str = ""

    def detached(self) -> "MemoryEntry":
        return MemoryEntry(self.key.detach(), self.value.detach(), self.camera_to_world, self.name)


class ESTransformer(nn.Module):
    """Query key/value (B, c, D, h, w) + memories -> fused value (B, c, D, h, w).

    Memories are warped into the query camera (`epipolar_warp_volume`). Per voxel the
    attention is softmax_j(<q, k_j> / sqrt(c)) over memories whose sample is valid; the
    retrieved volume y is the weighted sum of values. `adaptive` fusion is GRU-like:
    w, r = sigmoid(gates(v_q, y)); out = w * y + (1 - w) * tanh(g(v_q, r * y)).
    `concat` fusion is tanh(conv(concat(v_q, y))). Voxels with no valid memory get y = 0.
    """

    def __init__(self, channels: int, fusion: str, plane_spacing: str):
        super().__init__()
        self.fusion = fusion
        self.plane_spacing = plane_spacing
        c = channels
        if fusion == "adaptive":
            self.gates = Conv3d(2 * c, 2 * c, 3, 1, 1)
            self.gate_norm = nn.GroupNorm(2, 2 * c)
        self.candidate = Conv3d(2 * c, c, 3, 1, 1)
        self.candidate_norm = nn.GroupNorm(1, c)

    def retrieve(self, key: torch.Tensor, memories: list[MemoryEntry], camera_to_world: torch.Tensor,
                 K: torch.Tensor, planes: torch.Tensor) -> torch.Tensor:
        """Attention-weighted memory value in the query camera, (B, c, D, h, w)."""
        c = key.shape[1]
        if not memories:
            return torch.zeros_like(key)
        scores, values = [], []
        for m in memories:
            warped, valid = epipolar_warp_volume(torch.cat([m.key, m.value], 1), K, m.camera_to_world,
                                                 camera_to_world, planes, self.plane_spacing)
            score = (key * warped[:, :c]).sum(1) / math.sqrt(c)
            scores.append(score.masked_fill(~valid, float("-inf")))
            values.append(warped[:, c:])
        scores = torch.stack(scores, 0)  # (N, B, D, h, w)
        any_valid = torch.isfinite(scores).any(0)
        attention = torch.softmax(scores.masked_fill(~any_valid, 0.0), 0) * any_valid
        return (attention.unsqueeze(2) * torch.stack(values, 0)).sum(0)

    def forward(self, key: torch.Tensor, value: torch.Tensor, memories: list[MemoryEntry],
                camera_to_world: torch.Tensor, K: torch.Tensor, planes: torch.Tensor) -> torch.Tensor:
        """key, value (B, c, D, h, w); K (B, 3, 3) at volume res; planes (B, D) -> (B, c, D, h, w)."""
        y = self.retrieve(key, memories, camera_to_world, K, planes)
        if self.fusion == "concat":
            return torch.tanh(self.candidate_norm(self.candidate(torch.cat([value, y], 1))))
        w, r = torch.sigmoid(self.gate_norm(self.gates(torch.cat([value, y], 1)))).chunk(2, 1)
        g = torch.tanh(self.candidate_norm(self.candidate(torch.cat([value, r * y], 1))))
        return w * y + (1 - w) * g
