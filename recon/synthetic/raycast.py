"""Ray casting for the renderer: Open3D's BVH where Open3D is installed, torch elsewhere.

The renderer casts only rays that share one end: primary rays leave the camera centre, shadow
rays join surface points to one light, a line-of-sight test is one ray. Both backends answer the
same three questions with the same conventions (directions unnormalised, `t` in units of their
length, so a camera-frame z of 1 makes `t` the z-depth; barycentric (u, v) as Open3D reports
them: hit = (1 - u - v) v0 + u v1 + v v2).

`TorchRaycaster` exists for machines without Open3D, such as the lent GPU machines, where the
training data is rendered on CUDA. With one shared origin, the Moller-Trumbore terms of every
(ray, triangle) pair are three (N, 3) @ (3, T) products, so brute force over a room's few
thousand triangles is a few matrix products per frame on a GPU.
"""
from __future__ import annotations

import numpy as np

PARALLEL_EPS = 1e-12  # |det| below this: the ray runs parallel to the triangle's plane
RAY_CHUNK_ELEMENTS = 1 << 25  # rays x triangles per chunk (a few hundred MB of float32 temporaries)


class Open3DRaycaster:
    """Open3D's `RaycastingScene` over a triangle soup (T, 3, 3)."""

    def __init__(self, triangles: np.ndarray):
        import open3d as o3d
        import open3d.core as o3c

        self._o3c = o3c
        verts = np.ascontiguousarray(triangles.reshape(-1, 3), dtype=np.float32)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3c.Tensor(verts), o3c.Tensor(np.arange(len(verts), dtype=np.uint32).reshape(-1, 3)))

    def _cast(self, rays: np.ndarray) -> dict:
        return self._scene.cast_rays(self._o3c.Tensor.from_numpy(rays))

    def nearest(self, origin: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rays from `origin` (3,) along `directions` (N, 3) float32: t (N,) (inf = miss), face (N,), bary (N, 2)."""
        rays = np.empty((len(directions), 6), np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = directions
        hit = self._cast(rays)
        return hit["t_hit"].numpy(), hit["primitive_ids"].numpy(), hit["primitive_uvs"].numpy()

    def blocked(self, starts: np.ndarray, towards: np.ndarray, light: np.ndarray) -> np.ndarray:
        """(N,) bool: a surface lies on the segment from each start (N, 3) to start + towards (N, 3), which
        ends at `light` (3,) give or take the start's offset from its surface."""
        rays = np.empty((len(starts), 6), np.float32)
        rays[:, :3] = starts
        rays[:, 3:] = towards
        return self._cast(rays)["t_hit"].numpy() < 1.0

    def sees(self, eye: np.ndarray, target: np.ndarray, share: float) -> bool:
        """Whether the first `share` of the way from `eye` to `target` is free of surfaces."""
        ray = np.concatenate([np.asarray(eye, np.float32), np.asarray(target, np.float32) - np.asarray(eye, np.float32)])
        return bool(self._cast(ray[None])["t_hit"].numpy()[0] >= share)


class TorchRaycaster:
    """Brute-force Moller-Trumbore over every triangle, for rays that share one origin (torch, any device)."""

    def __init__(self, triangles: np.ndarray, device: str | None = None):
        import torch

        self._torch = torch
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        tris = torch.as_tensor(np.asarray(triangles, np.float64).reshape(-1, 3, 3))
        self._v0 = tris[:, 0].to(self.device, torch.float32)
        self._e1 = (tris[:, 1] - tris[:, 0]).to(self.device, torch.float32)
        self._e2 = (tris[:, 2] - tris[:, 0]).to(self.device, torch.float32)
        self._det_normal = torch.linalg.cross(self._e2, self._e1)  # det = d . (e2 x e1)

    def _terms(self, origin: np.ndarray):
        """Per triangle, the origin-dependent vectors: u-numerator normal b (T, 3), q (T, 3), t-numerator (T,)."""
        o = self._torch.as_tensor(np.asarray(origin, np.float32), device=self.device)
        tvec = o - self._v0
        q = self._torch.linalg.cross(tvec, self._e1)
        return self._torch.linalg.cross(self._e2, tvec), q, (self._e2 * q).sum(1)

    def _chunks(self, directions: np.ndarray):
        d = self._torch.as_tensor(np.ascontiguousarray(directions, np.float32), device=self.device)
        step = max(1, RAY_CHUNK_ELEMENTS // max(len(self._v0), 1))
        for start in range(0, len(d), step):
            yield start, d[start:start + step]

    def _solve(self, d, b, q, t_num):
        """For rays d (n, 3): t (n, T) with inf where the ray misses the triangle, and u, v (n, T)."""
        torch = self._torch
        det = d @ self._det_normal.T
        ok = det.abs() > PARALLEL_EPS
        inv = torch.where(ok, 1.0 / torch.where(ok, det, torch.ones_like(det)), torch.zeros_like(det))
        u = (d @ b.T) * inv
        v = (d @ q.T) * inv
        t = t_num[None] * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        return torch.where(hit, t, torch.full_like(t, float("inf"))), u, v

    def nearest(self, origin: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """As `Open3DRaycaster.nearest`; a miss has face 2**32 - 1, as Open3D's invalid id."""
        n = len(directions)
        t_out, face_out, bary_out = (np.full(n, np.inf, np.float32), np.full(n, np.iinfo(np.uint32).max, np.uint32),
                                     np.zeros((n, 2), np.float32))
        if n == 0 or len(self._v0) == 0:
            return t_out, face_out, bary_out
        b, q, t_num = self._terms(origin)
        with self._torch.no_grad():
            for start, d in self._chunks(directions):
                t, u, v = self._solve(d, b, q, t_num)
                t_min, face = t.min(1)
                idx = face[:, None]
                bary = self._torch.stack([u.gather(1, idx)[:, 0], v.gather(1, idx)[:, 0]], 1)
                hit = self._torch.isfinite(t_min)
                stop = start + len(d)
                t_out[start:stop] = t_min.cpu().numpy()
                face_out[start:stop] = np.where(hit.cpu().numpy(), face.cpu().numpy(), face_out[start:stop])
                bary_out[start:stop] = self._torch.where(hit[:, None], bary, 0).cpu().numpy()
        return t_out, face_out, bary_out

    def blocked(self, starts: np.ndarray, towards: np.ndarray, light: np.ndarray) -> np.ndarray:
        """As `Open3DRaycaster.blocked`, cast the other way: from the light (the shared origin) to each start."""
        out = np.zeros(len(starts), bool)
        if len(starts) == 0 or len(self._v0) == 0:
            return out
        light = np.asarray(light, np.float32)
        b, q, t_num = self._terms(light)
        with self._torch.no_grad():
            for start, d in self._chunks(np.asarray(starts, np.float32) - light):
                t, _, _ = self._solve(d, b, q, t_num)
                out[start:start + len(d)] = (t < 1.0).any(1).cpu().numpy()
        return out

    def sees(self, eye: np.ndarray, target: np.ndarray, share: float) -> bool:
        offset = np.asarray(target, np.float32) - np.asarray(eye, np.float32)
        return bool(self.nearest(np.asarray(eye, np.float32), offset[None])[0][0] >= share)


def make_raycaster(triangles: np.ndarray, backend: str = "auto"):
    """`backend`: 'open3d', 'torch' or 'auto' (Open3D when installed, else torch on CUDA if present)."""
    if backend == "auto":
        try:
            import open3d  # noqa: F401

            backend = "open3d"
        except ImportError:
            backend = "torch"
    if backend == "open3d":
        return Open3DRaycaster(triangles)
    if backend == "torch":
        return TorchRaycaster(triangles)
    raise ValueError(f"unknown ray-casting backend {backend!r} (open3d, torch or auto)")
