"""A tiny analytic renderer: textured axis-aligned rectangles seen by pinhole cameras.

Ray casting against a handful of planes gives exact depth and aliasing-free texture,
so tests and benchmarks of the depth stage get ground truth without a mesh renderer
(the full synthetic-room generator lives in recon.synthetic). Returns canonical Scans.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.geometry import pixel_rays
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata


@dataclass(frozen=True)
class Rect:
    """The rectangle {p : p[axis] = offset, lo <= other coordinates <= hi} in world metres."""

    axis: int
    offset: float
    lo: tuple[float, float] = (-50.0, -50.0)
    hi: tuple[float, float] = (50.0, 50.0)


# A back wall, a floor and a box face in front of the wall (OpenCV world: y down, z forward).
ROOM = (Rect(2, 3.5), Rect(1, 1.0), Rect(2, 2.0, (-0.5, -0.4), (0.3, 0.6)))


def texture(points: np.ndarray, seed: int = 0, components: int = 24) -> np.ndarray:
    """Band-limited random texture: (..., 3) world points -> (..., 3) RGB in [0, 1]."""
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(components, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freqs = dirs * rng.uniform(4.0, 30.0, size=(components, 1))
    phases = rng.uniform(0, 2 * np.pi, size=components)
    mix = rng.uniform(0.3, 1.0, size=(components, 3))
    waves = np.sin(points @ freqs.T + phases)  # (..., K)
    rgb = 0.5 + waves @ mix / (0.9 * np.sqrt(components) * mix.mean(0) * 2.5)
    return np.clip(rgb, 0.0, 1.0)


def render(intr: Intrinsics, camera_to_world: np.ndarray, rects=ROOM, seed: int = 0,
           ) -> tuple[np.ndarray, np.ndarray]:
    """uint8 RGB (H, W, 3) and float32 depth (H, W) (0 where no rectangle is hit)."""
    h, w = intr.height, intr.width
    rays = pixel_rays(intr.K, w, h) @ camera_to_world[:3, :3].T
    origin = camera_to_world[:3, 3]
    best = np.full((h, w), np.inf)
    for r in rects:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (r.offset - origin[r.axis]) / rays[..., r.axis]
        p = origin + t[..., None] * rays
        others = [a for a in range(3) if a != r.axis]
        hit = np.isfinite(t) & (t > 1e-6)
        for k, a in enumerate(others):
            hit &= (p[..., a] >= r.lo[k]) & (p[..., a] <= r.hi[k])
        best = np.where(hit & (t < best), t, best)
    hit = np.isfinite(best)
    points = origin + np.where(hit, best, 0.0)[..., None] * rays
    rgb = np.where(hit[..., None], texture(points, seed), 0.0)
    depth = np.where(hit, best, 0.0)  # rays_cam has z = 1, so the ray parameter is the depth
    return (rgb * 255 + 0.5).astype(np.uint8), depth.astype(np.float32)


def lateral_path(num_frames: int, step: float = 0.06, yaw_per_frame: float = 0.01) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) sliding along x and slowly turning, looking along +z."""
    poses = np.repeat(np.eye(4)[None], num_frames, 0)
    for i in range(num_frames):
        s = i - (num_frames - 1) / 2
        a = yaw_per_frame * s
        poses[i, :3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
        poses[i, :3, 3] = [step * s, 0.03 * np.sin(0.7 * i), 0.0]
    return poses


def plane_scan(num_frames: int = 5, width: int = 160, height: int = 128, step: float = 0.06,
               seed: int = 0, rects=ROOM) -> Scan:
    """An in-memory Scan of the textured rectangles with GT depth and its depth range."""
    intr = Intrinsics(0.8 * width, 0.8 * width, (width - 1) / 2, (height - 1) / 2, width, height)
    frames = []
    for i, pose in enumerate(lateral_path(num_frames, step)):
        rgb, depth = render(intr, pose, rects, seed)
        frames.append(Frame(name=f"{i:06d}", camera_to_world=pose, image_array=rgb, depth_array=depth,
                            source_index=i))
    meta = ScanMetadata(source="recon.plane_scene", source_format="synthetic", depth_range=(1.0, 5.0))
    return Scan(intr, frames, meta)
