"""Which frames get a depth map, and which neighbours each one is matched against.

Neighbouring video frames are too close to triangulate depth, and depth for every
frame is wasted work. The rule of DeepVideoMVS and SimpleRecon: a frame becomes a
keyframe once its combined pose distance from the last keyframe,

    d = sqrt(|t_rel|^2 + r^2),   r = sqrt(2 (1 - trace(R_rel) / 3))   (about 0.82 x the angle)

passes a threshold of about 0.1: 10 cm of travel or 7 degrees of turn. Each keyframe's source frames are
the neighbouring (key)frames whose distance to it is closest to an optimal baseline
(DeepVideoMVS: translation 0.15 with no rotation), skipping those too close to add
parallax. Distances are in scan units: with SfM poses, run this after the scale
normalisation (poses.scale) so 0.1 means what it means in metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ReconError
from .geometry import invert_pose


WINDOWS = ("offline", "online")


@dataclass(frozen=True)
class KeyframeConfig:
    keyframe_distance: float = 0.1  # a new keyframe once the combined distance from the last one passes this; 0: all

    def validate(self) -> "KeyframeConfig":
        if not self.keyframe_distance >= 0:
            raise ReconError(f"--keyframe-distance must be >= 0, got {self.keyframe_distance}")
        return self


@dataclass(frozen=True)
class SourceConfig:
    """Which frames serve as a frame's sources (the depth stage's matching partners)."""

    num_sources: int = 2
    window: str = "offline"  # candidates before and after the frame ("offline") or before only ("online")
    source_window: int = 10  # frames on each side considered
    source_baseline: float = 0.15  # translation the sources should ideally have (DeepVideoMVS)
    min_baseline: float = 0.02  # closer frames add too little parallax and never serve

    def validate(self) -> "SourceConfig":
        if self.window not in WINDOWS:
            raise ReconError(f"unknown source window {self.window!r} (expected one of {WINDOWS})")
        if self.num_sources < 1 or self.source_window < 1 or self.min_baseline < 0:
            raise ReconError("sources need num_sources >= 1, source_window >= 1 and min_baseline >= 0")
        return self


def pose_distances(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(combined, rotation, translation) distances between camera-to-world poses, broadcast like numpy:
    a (..., 4, 4), b (..., 4, 4) -> three (...) arrays (e.g. a[:, None], b[None] gives every pair)."""
    rel = invert_pose(np.asarray(a, np.float64)) @ np.asarray(b, np.float64)
    trace = np.minimum(3.0, np.trace(rel[..., :3, :3], axis1=-2, axis2=-1))
    rotation = np.sqrt(2.0 * (1.0 - trace / 3.0))
    translation = np.linalg.norm(rel[..., :3, 3], axis=-1)
    return np.hypot(translation, rotation), rotation, translation


def pose_distance(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """(combined, rotation, translation) distance between two camera-to-world poses."""
    combined, rotation, translation = pose_distances(a, b)
    return float(combined), float(rotation), float(translation)


def _check_poses(camera_to_world: np.ndarray) -> np.ndarray:
    poses = np.asarray(camera_to_world, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not len(poses):
        raise ReconError(f"keyframe selection needs (N, 4, 4) poses, got shape {poses.shape}")
    return poses


def select_keyframes(camera_to_world: np.ndarray, config: KeyframeConfig = KeyframeConfig()) -> list[int]:
    """Indices of keyframes in order: the first frame, then each frame far enough from the last keyframe
    (every frame when `keyframe_distance` is 0). camera_to_world: (N, 4, 4)."""
    poses = _check_poses(camera_to_world)
    keyframes = [0]
    for i in range(1, len(poses)):
        if pose_distance(poses[keyframes[-1]], poses[i])[0] >= config.keyframe_distance:
            keyframes.append(i)
    return keyframes


def select_sources(camera_to_world: np.ndarray, config: SourceConfig = SourceConfig()) -> dict[int, list[int]]:
    """Usable sources of every frame: {index: [up to `num_sources` indices, best first]}.

    Candidates are the frames within `source_window` on both sides (offline) or before (online),
    ranked by the penalty (t - source_baseline)^2 + r^2 (DeepVideoMVS), ties to the nearer frame in
    time; those closer than `min_baseline` in pose distance are dropped, so a frame may get fewer
    sources than asked (the caller decides whether that is an error). camera_to_world: (N, 4, 4).
    """
    config.validate()
    poses = _check_poses(camera_to_world)
    out: dict[int, list[int]] = {}
    for i in range(len(poses)):
        lo = max(0, i - config.source_window)
        hi = i if config.window == "online" else min(len(poses), i + config.source_window + 1)
        scored = []
        for j in range(lo, hi):
            combined, rot, trans = pose_distance(poses[i], poses[j])
            if j != i and combined >= config.min_baseline:
                scored.append(((trans - config.source_baseline) ** 2 + rot ** 2, abs(j - i), j))
        out[i] = [j for *_, j in sorted(scored)[: config.num_sources]]
    return out
