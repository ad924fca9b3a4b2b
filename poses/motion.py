"""Registrations that break a video's motion: a block of frames posed away from the path its neighbours draw.

A camera filmed at video rate moves a little between frames. When a stretch of frames sees only a
repeating texture (tiles, a patterned wall), SfM can register it against the same pattern one
repeat away: the block is internally consistent, but the path jumps into it and jumps back out
(docs/poses.md: rendered walks with a block of 34 frames 2.6 m away). Fusing such frames puts
their depth in the wrong place, so `displaced_blocks` finds them and SfM leaves them unposed.
"""
from __future__ import annotations

import numpy as np

JUMP_RATIO = 10.0  # a step this many times the typical step per frame is a jump
MAX_BLOCK_SHARE = 0.4  # a block longer than this share of the frames is not taken for the displaced part


def displaced_blocks(frame_index: np.ndarray, centres: np.ndarray, jump_ratio: float = JUMP_RATIO,
                     max_block_share: float = MAX_BLOCK_SHARE) -> list[np.ndarray]:
    """Blocks of registered frames that the path jumps into and back out of.

    frame_index: (N,) capture order of the registered frames (increasing; gaps where frames did not
    register); centres: (N, 3) their camera centres. A step between consecutive registered frames
    is a jump when its length per frame of index difference exceeds `jump_ratio` times the median
    one. A block between two jumps is displaced when it holds at most `max_block_share` of the
    frames and the frames on either side of it, joined directly, make no jump: the path without it
    is continuous. Returns positions into the inputs, one array per block, in order.
    """
    n = len(frame_index)
    if n < 5:
        return []
    per_frame = np.linalg.norm(np.diff(centres, axis=0), axis=1) / np.diff(frame_index)
    limit = jump_ratio * max(float(np.median(per_frame)), 1e-12)
    jumps = np.flatnonzero(per_frame > limit)
    blocks = []
    for start, end in zip(jumps, jumps[1:]):  # the block is positions start+1 .. end
        size = end - start
        joined = np.linalg.norm(centres[end + 1] - centres[start]) / (frame_index[end + 1] - frame_index[start])
        if size <= max_block_share * n and joined <= limit:
            blocks.append(np.arange(start + 1, end + 1))
    return blocks
