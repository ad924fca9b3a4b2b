"""`--mode hybrid`: the plane sweep's depth where it has an estimate, the network's (ESTM) everywhere else.

The two are complementary. The plane sweep is precise where it keeps a pixel (a textured window whose
match several sources confirm: median error 2 % on the demo room and ICL-NUIM) but keeps only 10-45 %
of them; the network is dense but, trained on a CPU budget, its depth is off by 10-20 % in places.
Fusing one map that takes each pixel from the better of the two gave the best meshes on the held-out
scans (docs/depth.md, "Hybrid depth"). Confidence follows the pixel's source: the plane sweep's NCC
score, or the network's peak plane probability.
"""
from __future__ import annotations

from typing import Iterator

import cv2
import numpy as np

from recon.errors import ReconError

from .options import FrameDepth


def on_grid(values: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h', w') map -> (h, w) by nearest neighbour (no new depths invented between pixels)."""
    if values.shape == shape:
        return values
    return cv2.resize(values, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)


def merge_depth(network: FrameDepth, sweep: FrameDepth) -> FrameDepth:
    """One frame: the sweep's depth and confidence where it has depth (> 0), the network's elsewhere, on the
    network's grid. Both must be the same frame."""
    if (network.index, network.name) != (sweep.index, sweep.name):
        raise ReconError(f"hybrid depth: frame {network.name} met the plane sweep's {sweep.name}")
    swept = on_grid(sweep.depth, network.depth.shape)
    has = swept > 0
    return FrameDepth(network.index, network.name, np.where(has, swept, network.depth).astype(np.float32),
                      np.where(has, on_grid(sweep.confidence, network.depth.shape), network.confidence
                               ).astype(np.float32), network.sources)


def merge_streams(network: Iterator[FrameDepth], sweep: Iterator[FrameDepth]) -> Iterator[FrameDepth]:
    """Both modes' frames, in their common order, merged one by one as they come."""
    for net, ps in zip(network, sweep, strict=True):
        yield merge_depth(net, ps)
