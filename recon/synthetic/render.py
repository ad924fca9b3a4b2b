"""Renderer: exact ray-cast depth, numpy texturing and Lambertian shading.

All rays of a frame are cast at once (`raycast.py`: Open3D's `RaycastingScene` where Open3D is
installed, a torch caster on CUDA or CPU elsewhere). Ray directions are built with a camera-frame z of exactly 1, so the hit distance
the caster returns (in units of the direction's length) *is* the depth along the
optical axis. Color comes from the hit triangle: its barycentric coordinates
drive a precomputed affine map to texel coordinates, the mip level follows the
pixel's footprint on the surface, and a single gather reads the texel from the
library's flat texture array. Shading is ambient plus point lights with a soft
distance falloff, hard shadows from one light (a second cast from the hit points
towards it), then exposure, white balance and a tone curve applied through one
lookup table.
"""
from __future__ import annotations

import numpy as np

from recon.geometry import pixel_rays
from recon.scan import Intrinsics

from .raycast import make_raycaster
from .scene import Scene
from .textures import TextureLibrary, linear_to_srgb

LIGHT_FALLOFF_M = 2.0  # distance at which a light's contribution halves (soft, area-light-like)
SHADOW_RAY_OFFSET_M = 0.002
MIN_FOOTPRINT_COS = 0.3  # caps the mip footprint growth at grazing angles (avoids over-blurring)
TONE_LUT_SIZE = 16384
TONE_LUT_RANGE = 4.0  # linear values up to this are tone-mapped; brighter ones saturate


def _tone_lut() -> np.ndarray:
    """Linear radiance -> uint8 sRGB with a soft shoulder above 0.8, so highlights roll off."""
    x = (np.arange(TONE_LUT_SIZE) + 0.5) / TONE_LUT_SIZE * TONE_LUT_RANGE
    y = np.where(x < 0.8, x, 0.8 + 0.2 * (1 - np.exp(-(x - 0.8) / 0.2)))
    return np.round(np.clip(linear_to_srgb(y), 0, 1) * 255).astype(np.uint8)


class Renderer:
    """Renders color and z-depth of a `Scene` from any camera-to-world pose (OpenCV axes)."""

    def __init__(self, scene: Scene, library: TextureLibrary, shadows: bool = True, raycaster: str = "auto"):
        """`raycaster`: 'open3d', 'torch' or 'auto' (`raycast.make_raycaster`)."""
        self.scene, self.library, self.shadows = scene, library, shadows
        self._raycaster = make_raycaster(scene.vertices, raycaster)
        self._face_table, self._face_texture = self._per_face_tables()
        self._rays_cam: dict[Intrinsics, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._lut = _tone_lut()

    def _per_face_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """(13, F) float32: texel affine map (u0, v0, du1, dv1, du2, dv2), normal, tint, texels per metre."""
        s = self.scene
        size = self.library.size
        uv = s.uvs * size
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        edge_m = np.linalg.norm(s.vertices[:, 1] - s.vertices[:, 0], axis=1)
        density = np.linalg.norm(e1, axis=1) / np.maximum(edge_m, 1e-9)
        tints = np.array([m.tint for m in s.materials], dtype=np.float64)[s.face_material]
        table = np.concatenate([uv[:, 0], e1, e2, s.face_normals, tints, density[:, None]], axis=1)
        textures = np.array([m.texture for m in s.materials], dtype=np.int64)[s.face_material]
        return np.ascontiguousarray(table.T.astype(np.float32)), textures

    def _camera_rays(self, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per pixel, the camera-frame ray (x, y, 1) as x (N,), y (N,) and the ray length (N,), float32."""
        if intrinsics not in self._rays_cam:
            rays = pixel_rays(intrinsics.K, intrinsics.width, intrinsics.height).reshape(-1, 3)
            x, y = rays[:, 0], rays[:, 1]
            self._rays_cam[intrinsics] = (x.astype(np.float32), y.astype(np.float32),
                                          np.sqrt(x * x + y * y + 1).astype(np.float32))
        return self._rays_cam[intrinsics]

    def cast(self, camera_to_world: np.ndarray, intrinsics: Intrinsics) -> dict[str, np.ndarray]:
        """Ray-cast one view (all pixels at once, row-major).

        Returns `depth` (N,) float32 z-depth (inf = miss), `face` (N,) triangle ids, `bary` (N, 2)
        barycentric coordinates and `dirs` (3, N) world ray directions (camera-frame z = 1).
        """
        x, y, _ = self._camera_rays(intrinsics)
        rot = camera_to_world[:3, :3].astype(np.float32)
        # Rotating each component separately avoids a BLAS call (slow on small inner dimensions).
        dirs = np.stack([rot[k, 0] * x + rot[k, 1] * y + rot[k, 2] for k in range(3)])
        depth, face, bary = self._raycaster.nearest(camera_to_world[:3, 3].astype(np.float32), dirs.T)
        return {"depth": depth, "face": face, "bary": bary, "dirs": dirs}

    def render_depth(self, camera_to_world: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
        """(H, W) float32 metres along the optical axis, 0 where no surface is hit."""
        depth = self.cast(camera_to_world, intrinsics)["depth"]
        return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32).reshape(intrinsics.height,
                                                                                 intrinsics.width)

    def sees(self, eye: np.ndarray, target: np.ndarray, share: float = 0.9) -> bool:
        """Whether the first `share` of the way from `eye` to `target` (world points) is free of surfaces."""
        return self._raycaster.sees(eye, target, share)

    def render_linear(self, camera_to_world: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
        """Linear radiance (H, W, 3) float32 and z-depth (H, W) float32 (0 = miss)."""
        c = self.cast(camera_to_world, intrinsics)
        depth, face, bary, dirs = c["depth"], c["face"], c["bary"], c["dirs"]
        dir_len = self._camera_rays(intrinsics)[2]
        hit = np.isfinite(depth)
        all_hit = bool(hit.all())
        if all_hit:
            t = depth
        else:
            face, bary, dirs, dir_len, t = face[hit], bary[hit], dirs[:, hit], dir_len[hit], depth[hit]
        rows = self._face_table.take(face, axis=1)
        b1, b2 = bary[:, 0].copy(), bary[:, 1].copy()
        tex_x = rows[0] + b1 * rows[2] + b2 * rows[4]
        tex_y = rows[1] + b1 * rows[3] + b2 * rows[5]
        n_dot_d = rows[6] * dirs[0] + rows[7] * dirs[1] + rows[8] * dirs[2]
        # Mip level from the pixel's footprint on the surface, in texels.
        cos = np.maximum(np.abs(n_dot_d) / dir_len, np.float32(MIN_FOOTPRINT_COS))
        footprint = t * dir_len * rows[12] / (np.float32(intrinsics.fx) * cos)
        level = np.clip(np.frexp(footprint)[1] - 1, 0, self.library.num_levels - 1)
        size = np.int64(self.library.size) >> level
        ix = (np.floor(tex_x).astype(np.int64) >> level) & (size - 1)
        iy = (np.floor(tex_y).astype(np.int64) >> level) & (size - 1)
        index = self.library.level_base[level] + (self._face_texture.take(face) * size + iy) * size + ix
        albedo = self.library.texels.take(index, axis=0)  # (n, 3)
        # Shade with the normal turned towards the camera (thin parts can be seen from behind).
        flip = np.where(n_dot_d > 0, np.float32(-1), np.float32(1))
        nx, ny, nz = rows[6] * flip, rows[7] * flip, rows[8] * flip
        px = np.float32(camera_to_world[0, 3]) + t * dirs[0]
        py = np.float32(camera_to_world[1, 3]) + t * dirs[1]
        pz = np.float32(camera_to_world[2, 3]) + t * dirs[2]
        shade = [np.full(len(t), a, np.float32) for a in self.scene.ambient]
        for k, (pos, color) in enumerate(zip(self.scene.light_positions.astype(np.float32),
                                             self.scene.light_colors.astype(np.float32))):
            lx, ly, lz = pos[0] - px, pos[1] - py, pos[2] - pz
            dist2 = lx * lx + ly * ly + lz * lz
            weight = np.maximum(nx * lx + ny * ly + nz * lz, 0) / (
                np.sqrt(dist2) * (1 + dist2 * np.float32(1 / LIGHT_FALLOFF_M ** 2)))
            if self.shadows and k == self.scene.shadow_light:
                weight *= self._unoccluded(px, py, pz, nx, ny, nz, lx, ly, lz, weight > 0, pos)
            for k in range(3):
                shade[k] += weight * color[k]
        radiance = np.empty((len(hit), 3), np.float32)
        if not all_hit:
            radiance[~hit] = 0
        for k in range(3):
            channel = albedo[:, k] * rows[9 + k] * shade[k]
            if all_hit:
                radiance[:, k] = channel
            else:
                radiance[hit, k] = channel
        depth = depth if all_hit else np.where(hit, depth, 0).astype(np.float32)
        h, w = intrinsics.height, intrinsics.width
        return radiance.reshape(h, w, 3), depth.reshape(h, w)

    def _unoccluded(self, px, py, pz, nx, ny, nz, lx, ly, lz, lit, light) -> np.ndarray:
        """1 where nothing lies between a lit point and the light at `light` (3,), else 0 (float32, shape of px)."""
        idx = np.flatnonzero(lit)
        starts, towards = np.empty((len(idx), 3), np.float32), np.empty((len(idx), 3), np.float32)
        offset = np.float32(SHADOW_RAY_OFFSET_M)
        for k, (p, n, d) in enumerate(((px, nx, lx), (py, ny, ly), (pz, nz, lz))):
            starts[:, k] = p[idx] + n[idx] * offset  # start just off the surface, towards the camera side
            towards[:, k] = d[idx]  # unnormalised: the light sits at t = 1
        visible = np.ones(len(px), np.float32)
        visible[idx[self._raycaster.blocked(starts, towards, light)]] = 0.0
        return visible

    def tone_map(self, radiance: np.ndarray, gain=1.0) -> np.ndarray:
        """Linear radiance times `gain` (scalar exposure or per-channel) -> uint8 sRGB."""
        scaled = radiance * (np.asarray(gain, np.float32) * np.float32(TONE_LUT_SIZE / TONE_LUT_RANGE))
        index = np.minimum(scaled, TONE_LUT_SIZE - 1).astype(np.int32)
        return self._lut[index]

    def auto_exposure(self, radiance: np.ndarray, target: float = 0.2) -> float:
        """Exposure that brings the median luminance to `target` (a camera's mid-grey metering)."""
        luminance = radiance @ np.array([0.2126, 0.7152, 0.0722], np.float32)
        median = float(np.median(luminance[luminance > 0])) if np.any(luminance > 0) else 1.0
        return target / max(median, 1e-6)
