"""Preview pictures of a mesh by ray casting (Open3D RaycastingScene), for reports.

Rays pass through faces seen from behind, so a room viewed from outside shows its
inside (its walls face inwards, towards the cameras that observed them).
"""
from __future__ import annotations

import numpy as np
import trimesh

from recon.geometry import intrinsic_matrix, pixel_rays

BACKGROUND = np.array([245, 245, 245], dtype=np.float32)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Camera-to-world (OpenCV axes) at `eye` looking at `target`, image-up along `up`. (4, 4)"""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:  # looking along `up`: any perpendicular will do
        x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], 1)
    pose[:3, 3] = eye
    return pose


def render_mesh(mesh: trimesh.Trimesh, camera_to_world: np.ndarray, width: int = 480, height: int = 360,
                fov_deg: float = 60.0, peel: int = 3) -> np.ndarray:
    """uint8 RGB (H, W, 3): vertex colors (or grey) with head-light shading; back faces are skipped."""
    import open3d as o3d
    import open3d.core as o3c

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3c.Tensor(np.asarray(mesh.vertices, np.float32)), o3c.Tensor(np.asarray(mesh.faces, np.uint32)))
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    K = intrinsic_matrix(f, f, (width - 1) / 2, (height - 1) / 2)
    dirs = pixel_rays(K, width, height, np.float32).reshape(-1, 3) @ camera_to_world[:3, :3].T.astype(np.float32)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs = dirs.astype(np.float32)
    origins = np.broadcast_to(camera_to_world[:3, 3].astype(np.float32), dirs.shape).copy()
    n = len(dirs)
    prim = np.full(n, -1, np.int64)
    uvs = np.zeros((n, 2), np.float32)
    normals = np.zeros((n, 3), np.float32)
    todo = np.arange(n)
    for _ in range(peel + 1):
        ans = scene.cast_rays(o3c.Tensor(np.concatenate([origins[todo], dirs[todo]], 1)))
        t = ans["t_hit"].numpy()
        ids = ans["primitive_ids"].numpy().astype(np.int64)
        nrm = ans["primitive_normals"].numpy()
        hit = np.isfinite(t)
        front = hit & (np.einsum("ij,ij->i", nrm, dirs[todo]) < 0)
        done = todo[front]
        prim[done], uvs[done], normals[done] = ids[front], ans["primitive_uvs"].numpy()[front], nrm[front]
        back = hit & ~front
        origins[todo[back]] += dirs[todo[back]] * (t[back, None] + 1e-4)
        todo = todo[back]
        if len(todo) == 0:
            break
    image = np.tile(BACKGROUND, (n, 1))
    hit = prim >= 0
    if hit.any():
        if mesh.visual.kind == "vertex":
            vc = np.asarray(mesh.visual.vertex_colors[:, :3], np.float32)
            tri = vc[np.asarray(mesh.faces)[prim[hit]]]
            a, b = uvs[hit, 0:1], uvs[hit, 1:2]
            base = (1 - a - b) * tri[:, 0] + a * tri[:, 1] + b * tri[:, 2]
        else:
            base = np.full((hit.sum(), 3), 200.0, np.float32)
        shade = 0.35 + 0.65 * np.abs(np.einsum("ij,ij->i", normals[hit], dirs[hit]))
        image[hit] = base * shade[:, None]
    return np.clip(image, 0, 255).astype(np.uint8).reshape(height, width, 3)


def preview_views(mesh: trimesh.Trimesh, up: np.ndarray, count: int = 3, width: int = 480, height: int = 360
                  ) -> list[tuple[str, np.ndarray]]:
    """A top-down view and `count` oblique views around the mesh; [(label, image)]."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    lo, hi = mesh.bounds
    centre = (lo + hi) / 2
    radius = 0.75 * np.linalg.norm(hi - lo)
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    other = np.cross(up, side)
    views = [("top", render_mesh(mesh, look_at(centre + 1.2 * radius * up, centre, other), width, height))]
    for k in range(count):
        a = 2 * np.pi * k / count + np.pi / 4
        eye = centre + radius * (0.8 * (np.cos(a) * side + np.sin(a) * other) + 0.6 * up)
        views.append((f"view {k + 1}", render_mesh(mesh, look_at(eye, centre, up), width, height)))
    return views
