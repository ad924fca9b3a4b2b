"""An exact little scene for tests: the inside of an axis-aligned box room, depth by ray casting.

Independent of the project's synthetic generator, so foundation tests do not depend on it.
"""
from __future__ import annotations

import numpy as np
import trimesh

from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

ROOM_MIN = np.array([-2.0, -1.5, -2.0])
ROOM_MAX = np.array([2.0, 1.2, 2.5])


def look_at(eye, target, down=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Camera-to-world (OpenCV axes: z forward, y down) looking from eye at target."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(down, float), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], axis=1)
    pose[:3, 3] = eye
    return pose


def room_depth(intr: Intrinsics, camera_to_world: np.ndarray) -> np.ndarray:
    """Exact z-depth of the box walls seen from inside. (H, W) float32 metres."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    rays_cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)
    rays = rays_cam @ camera_to_world[:3, :3].T
    origin = camera_to_world[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_max = np.maximum((ROOM_MIN - origin) / rays, (ROOM_MAX - origin) / rays)
    t_exit = np.min(np.where(np.isfinite(t_max), t_max, np.inf), axis=-1)
    return t_exit.astype(np.float32)  # rays_cam has z = 1, so the ray parameter is the z-depth


def room_texture(intr: Intrinsics, camera_to_world: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """A color that is a function of the 3D surface point (checker + gradient), so views agree."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    pts = np.stack([(u - intr.cx) / intr.fx * depth, (v - intr.cy) / intr.fy * depth, depth], -1)
    world = pts @ camera_to_world[:3, :3].T + camera_to_world[:3, 3]
    checker = (np.floor(world * 4).sum(-1) % 2)[..., None]
    rgb = 60 + 120 * checker + 60 * (world - ROOM_MIN) / (ROOM_MAX - ROOM_MIN)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def box_room_scan(n_frames: int = 8, width: int = 96, height: int = 72) -> Scan:
    """In-memory scan circling inside the room, looking at varying walls."""
    intr = Intrinsics(0.8 * width, 0.8 * width, (width - 1) / 2, (height - 1) / 2, width, height)
    frames = []
    for i in range(n_frames):
        a = 2 * np.pi * i / n_frames
        eye = np.array([0.6 * np.cos(a), -0.2 + 0.1 * np.sin(3 * a), 0.6 * np.sin(a)])
        target = eye + np.array([np.cos(a + 1.2), 0.15, np.sin(a + 1.2)])
        pose = look_at(eye, target)
        depth = room_depth(intr, pose)
        frames.append(Frame(name=f"{i:06d}", camera_to_world=pose, image_array=room_texture(intr, pose, depth),
                            depth_array=depth))
    return Scan(intr, frames, ScanMetadata(metric_scale=True, source="box room"))


def box_room_mesh() -> trimesh.Trimesh:
    """The walls as a closed box mesh (exact ground truth)."""
    return trimesh.creation.box(bounds=np.stack([ROOM_MIN, ROOM_MAX]))
