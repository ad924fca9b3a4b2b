"""Which frames get depth and which neighbours serve as their sources.

One implementation of the rules lives in `recon.keyframes` (DeepVideoMVS / SimpleRecon pose
distance, keyframes, sources ranked by closeness to an optimal baseline); this module adapts
it to the depth stage: a source closer than `min_baseline` cannot triangulate and is dropped
instead of being used as a fallback, so a frame without enough real sources is reported.
"""
from __future__ import annotations

import numpy as np

from recon.errors import ReconError
from recon.keyframes import KeyframeConfig
from recon.keyframes import pose_distance as _pose_distance
from recon.keyframes import select_keyframes as _select_keyframes
from recon.keyframes import select_sources as _select_sources

WINDOWS = ("offline", "online")


def pose_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Combined translation/rotation distance between two camera-to-world poses (4x4)."""
    return _pose_distance(a, b)[0]


def select_keyframes(camera_to_world: np.ndarray, threshold: float = 0.1) -> list[int]:
    """Indices of keyframes: the first frame, then each frame at least `threshold` from the last
    keyframe. camera_to_world: (N, 4, 4)."""
    return _select_keyframes(camera_to_world, KeyframeConfig(min_pose_distance=threshold))


def select_sources(camera_to_world: np.ndarray, count: int = 2, window: str = "offline", baseline: float = 0.15,
                   min_baseline: float = 0.02, search: int = 10) -> dict[int, list[int]]:
    """Usable source frames of every frame: {index: [source indices, best first]}.

    Candidates are the frames within `search` on both sides (offline) or before (online),
    ranked by how close their translation is to `baseline` (`recon.keyframes.select_sources`);
    those closer than `min_baseline` in pose distance are dropped, so a frame may get fewer
    than `count` sources (the caller decides whether that is an error).
    camera_to_world: (N, 4, 4).
    """
    if window not in WINDOWS:
        raise ReconError(f"unknown source window {window!r} (expected one of {WINDOWS})")
    poses = np.asarray(camera_to_world, np.float64)
    config = KeyframeConfig(num_sources=count, source_window=search, optimal_translation=baseline,
                            min_source_distance=min_baseline, online=window == "online")
    ranked = _select_sources(poses, list(range(len(poses))), config)
    return {i: [j for j in srcs if pose_distance(poses[i], poses[j]) >= min_baseline]
            for i, srcs in ranked.items()}
