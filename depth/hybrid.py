"""`--mode hybrid`: ESTM's depth, refined by a narrow plane sweep around it where the images match.

The two methods fail in opposite ways. The plane sweep is precise where a textured window matches
(median error 2 % on the demo room and ICL-NUIM) but keeps few pixels and, over the whole range, picks
wrong planes on blur and repeated texture; the network is dense, but trained on a CPU budget its depth
is 10-20 % off in places, too far off for 5 cm meshes. Here each frame's ESTM map is the prior of a
sweep over depth x (1 +- 0.5) only (`depth.planesweep.refine_depth`, the same NCC and sources): where
the match is distinctive the pixel takes the sweep's depth, elsewhere it keeps the network's. On the
held-out scans this gave better meshes and depth than ESTM alone and than merging a full sweep's pixels
into it (docs/depth.md, "Hybrid depth"). Confidence: the match's NCC score where refined, the network's
peak plane probability elsewhere.
"""
from __future__ import annotations

from typing import Iterator

import torch

from recon.scan import Scan

from .options import FrameDepth, PlaneSweepOptions
from .planesweep import grey_frames, refine_depth


def refine_frames(scan: Scan, network: Iterator[FrameDepth], opts: PlaneSweepOptions) -> Iterator[FrameDepth]:
    """Each network frame refined against its own sources, on the network map's grid, as they come."""
    work, gray = None, None
    poses = torch.from_numpy(scan.camera_to_world).float()
    for frame in network:
        h, w = frame.depth.shape
        if work is None:
            work = scan if scan.intrinsics.size == (w, h) else scan.resized(w, h)
            gray = grey_frames(work)
        K = torch.from_numpy(work.intrinsics.K).float()
        prior = torch.from_numpy(frame.depth)
        depth, score = refine_depth(gray(frame.index), torch.stack([gray(j) for j in frame.sources]), K,
                                    poses[frame.index], poses[frame.sources], prior, opts)
        confidence = torch.where(score > 0, score, torch.from_numpy(frame.confidence))
        yield FrameDepth(frame.index, frame.name, depth.numpy(), confidence.numpy(), frame.sources)
