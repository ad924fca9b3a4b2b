"""Which frames get a depth map, and which neighbours each one is matched against.

Neighbouring video frames are too close to triangulate depth, and depth for every
frame is wasted work. The rule of DeepVideoMVS and SimpleRecon: a frame becomes a
keyframe once its combined pose distance from the last keyframe,

    d = sqrt(|t_rel|^2 + r^2),   r = sqrt(2 (1 - trace(R_rel) / 3))   (about 0.82 x the angle)

passes a threshold of about 0.1: 10 cm of travel or 7 degrees of turn. Each keyframe's source frames are
the neighbouring keyframes whose distance to it is closest to an optimal baseline
(DeepVideoMVS: translation 0.15 with no rotation), skipping those too close to add
parallax. Distances are in scan units: with SfM poses, run this after the scale
normalisation (poses.scale) so 0.1 means what it means in metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ReconError
from .geometry import invert_pose


@dataclass
class KeyframeConfig:
    min_pose_distance: float = 0.1  # a new keyframe once the combined distance from the last one passes this
    num_sources: int = 2  # source frames per keyframe
    source_window: int = 4  # keyframes on each side considered as sources
    optimal_translation: float = 0.15  # baseline (scan units) the sources should ideally have
    optimal_rotation: float = 0.0  # rotation measure the sources should ideally have
    min_source_distance: float = 0.05  # closer candidates add too little parallax to be used
    online: bool = False  # sources from the past only (live capture); otherwise both sides


def pose_distance(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """(combined, rotation, translation) distance between two camera-to-world poses."""
    rel = invert_pose(np.asarray(a, np.float64)) @ np.asarray(b, np.float64)
    trace = min(3.0, float(np.trace(rel[:3, :3])))
    rotation = float(np.sqrt(2.0 * (1.0 - trace / 3.0)))
    translation = float(np.linalg.norm(rel[:3, 3]))
    return float(np.hypot(translation, rotation)), rotation, translation


def select_keyframes(camera_to_world: np.ndarray, config: KeyframeConfig | None = None) -> list[int]:
    """Indices of keyframes in order: the first frame, then each frame far enough from the last keyframe.

    camera_to_world: (N, 4, 4).
    """
    config = config or KeyframeConfig()
    poses = np.asarray(camera_to_world, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not len(poses):
        raise ReconError(f"keyframe selection needs (N, 4, 4) poses, got shape {poses.shape}")
    keyframes = [0]
    for i in range(1, len(poses)):
        if pose_distance(poses[keyframes[-1]], poses[i])[0] >= config.min_pose_distance:
            keyframes.append(i)
    return keyframes


def select_sources(camera_to_world: np.ndarray, keyframes: list[int],
                   config: KeyframeConfig | None = None) -> dict[int, list[int]]:
    """For each keyframe index, up to `num_sources` frame indices (other keyframes) with a useful baseline.

    The penalty (t - t_opt)^2 + (r - r_opt)^2 ranks candidates (DeepVideoMVS); ties go to the
    nearer keyframe in time. When no candidate clears `min_source_distance`, the nearest
    keyframes are used anyway so every keyframe gets sources.
    """
    config = config or KeyframeConfig()
    poses = np.asarray(camera_to_world, np.float64)
    out: dict[int, list[int]] = {}
    for k, ref in enumerate(keyframes):
        lo = max(0, k - config.source_window)
        hi = k if config.online else min(len(keyframes), k + config.source_window + 1)
        candidates = [keyframes[j] for j in range(lo, hi) if j != k]
        scored = []
        for c in candidates:
            _, rot, trans = pose_distance(poses[ref], poses[c])
            penalty = (trans - config.optimal_translation) ** 2 + (rot - config.optimal_rotation) ** 2
            scored.append((np.hypot(trans, rot) < config.min_source_distance, penalty, abs(c - ref), c))
        scored.sort()
        out[ref] = [c for *_, c in scored[: config.num_sources]]
    return out
