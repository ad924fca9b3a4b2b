"""Camera geometry for the depth network, in torch (batched, differentiable).

Conventions match `recon.geometry`: poses are camera-to-world 4x4 with OpenCV axes,
pixel centres sit at integer coordinates, so `grid_sample(..., align_corners=True)`
maps normalised -1 / +1 to the first / last pixel centre.
"""
from __future__ import annotations

from contextlib import nullcontext

import torch
import torch.nn.functional as F

SPACINGS = ("linear", "inverse", "log")


def _warp_depth(depth: torch.Tensor, spacing: str) -> torch.Tensor:
    """The coordinate in which planes are evenly spaced: depth, inverse depth or log depth."""
    if spacing == "linear":
        return depth
    if spacing == "inverse":
        return 1.0 / depth.clamp_min(1e-6)
    if spacing == "log":
        return torch.log(depth.clamp_min(1e-6))
    raise ValueError(f"unknown plane spacing {spacing!r} (expected one of {SPACINGS})")


def _unwarp_depth(x: torch.Tensor, spacing: str) -> torch.Tensor:
    """Inverse of `_warp_depth`."""
    if spacing == "linear":
        return x
    if spacing == "inverse":
        return 1.0 / x
    if spacing == "log":
        return torch.exp(x)
    raise ValueError(f"unknown plane spacing {spacing!r} (expected one of {SPACINGS})")


def depth_planes(min_depth: torch.Tensor, max_depth: torch.Tensor, num_planes: int,
                 spacing: str = "linear") -> torch.Tensor:
    """Depth values of `num_planes` fronto-parallel planes between min and max depth.

    min_depth, max_depth: (B,) -> (B, D). `linear` spaces planes evenly in depth (the
    paper), `inverse` evenly in inverse depth (denser near the camera), `log` evenly in
    log depth (the same relative step at every depth).
    """
    steps = torch.linspace(0.0, 1.0, num_planes, dtype=min_depth.dtype, device=min_depth.device)
    return depth_at_index(steps[None] * (num_planes - 1), min_depth, max_depth, num_planes, spacing)


def plane_index(depth: torch.Tensor, min_depth: torch.Tensor, max_depth: torch.Tensor, num_planes: int,
                spacing: str = "linear") -> torch.Tensor:
    """Fractional plane index (0 .. D-1) of depths, the inverse of `depth_planes`.

    depth: (B, ...) ; min_depth, max_depth: (B,) -> (B, ...)
    """
    shape = (-1,) + (1,) * (depth.dim() - 1)
    lo, hi = _warp_depth(min_depth.view(shape), spacing), _warp_depth(max_depth.view(shape), spacing)
    return (_warp_depth(depth, spacing) - lo) / (hi - lo) * (num_planes - 1)


def depth_at_index(index: torch.Tensor, min_depth: torch.Tensor, max_depth: torch.Tensor, num_planes: int,
                   spacing: str = "linear") -> torch.Tensor:
    """Depth at a fractional plane index, the inverse of `plane_index` (interpolates between planes).

    index: (B, ...) ; min_depth, max_depth: (B,) -> (B, ...)
    """
    shape = (-1,) + (1,) * (index.dim() - 1)
    lo, hi = _warp_depth(min_depth.view(shape), spacing), _warp_depth(max_depth.view(shape), spacing)
    return _unwarp_depth(lo + (hi - lo) * index / (num_planes - 1), spacing)


def scale_intrinsics(K: torch.Tensor, scale_x: float, scale_y: float) -> torch.Tensor:
    """K of the same camera after resizing the image by (scale_x, scale_y).

    Same convention as `recon.scan.Intrinsics.resized`: c' = (c + 0.5) * s - 0.5.
    K: (B, 3, 3) -> (B, 3, 3)
    """
    out = K.clone()
    out[:, 0, 0] = K[:, 0, 0] * scale_x
    out[:, 1, 1] = K[:, 1, 1] * scale_y
    out[:, 0, 2] = (K[:, 0, 2] + 0.5) * scale_x - 0.5
    out[:, 1, 2] = (K[:, 1, 2] + 0.5) * scale_y - 0.5
    return out


def pixel_grid(height: int, width: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """Homogeneous pixel coordinates (3, H*W), row-major, x fastest."""
    v, u = torch.meshgrid(torch.arange(height, dtype=dtype, device=device),
                          torch.arange(width, dtype=dtype, device=device), indexing="ij")
    return torch.stack([u.reshape(-1), v.reshape(-1), torch.ones_like(u).reshape(-1)])


def relative_pose(from_camera_to_world: torch.Tensor, to_camera_to_world: torch.Tensor) -> torch.Tensor:
    """Transform taking points of camera `from` into camera `to`: inv(to) @ from. (B,4,4) -> (B,4,4)"""
    rot = to_camera_to_world[:, :3, :3].transpose(1, 2)
    trans = -rot @ to_camera_to_world[:, :3, 3:]
    world_to_to = torch.cat([torch.cat([rot, trans], 2), to_camera_to_world[:, 3:]], 1)
    return world_to_to @ from_camera_to_world


def _project_planes(K_ref: torch.Tensor, K_src: torch.Tensor, ref_camera_to_world: torch.Tensor,
                    src_camera_to_world: torch.Tensor, depths: torch.Tensor, height: int, width: int
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Where reference pixels at each depth land in the source camera.

    The point at depth d on pixel p's ray is d * K_ref^-1 p, so its source projection is
    d * (K_src R K_ref^-1 p) + K_src t: the plane-induced homography of the plane z = d.
    K_ref, K_src: (B,3,3); poses (B,4,4) camera-to-world; depths: (B,D) planes, or (B,D,H,W) a depth per
    pixel (hypotheses around a prior map) -> uv (B, D, H, W, 2) source pixel coordinates, z (B, D, H, W)
    source-camera depth. Always in float32 or wider: under autocast the products would run in bf16/fp16,
    which puts coordinates up to 0.125 px off at 80x64 (and a relative pose 0.2 degrees).
    """
    work = _sampling_dtype(K_ref)
    device = K_ref.device.type
    with torch.autocast(device, enabled=False) if torch.amp.is_autocast_available(device) else nullcontext():
        K_ref, K_src, depths = K_ref.to(work), K_src.to(work), depths.to(work)
        ref_to_src = relative_pose(ref_camera_to_world.to(work), src_camera_to_world.to(work))
        pix = pixel_grid(height, width, work, K_ref.device)  # (3, HW)
        rays = K_src @ ref_to_src[:, :3, :3] @ torch.linalg.inv(K_ref) @ pix  # (B, 3, HW)
        offset = K_src @ ref_to_src[:, :3, 3:]  # (B, 3, 1)
        b, d = depths.shape[:2]
        scale = depths.reshape(b, d, 1, -1)  # (B, D, 1, 1 or HW)
        pts = scale * rays[:, None] + offset[:, None]  # (B, D, 3, HW)
        z = pts[:, :, 2]
        safe_z = torch.where(z.abs() < 1e-6, torch.full_like(z, 1e-6), z)
        uv = pts[:, :, :2] / safe_z[:, :, None]
    return uv.permute(0, 1, 3, 2).reshape(b, d, height, width, 2), z.reshape(b, d, height, width)


def _sampling_dtype(x: torch.Tensor) -> torch.dtype:
    """At least float32: under bf16/fp16 autocast, normalised coordinates would lose ~0.1 px."""
    return torch.promote_types(x.dtype, torch.float32)


def _normalise(coord: torch.Tensor, size: int) -> torch.Tensor:
    """Pixel coordinate -> [-1, 1] for grid_sample(align_corners=True)."""
    return coord * (2.0 / max(size - 1, 1)) - 1.0


def plane_sweep_warp(src_features: torch.Tensor, K_ref: torch.Tensor, K_src: torch.Tensor,
                     ref_camera_to_world: torch.Tensor, src_camera_to_world: torch.Tensor,
                     depths: torch.Tensor, ref_size: tuple[int, int] | None = None,
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """Warp source features into the reference view at every depth plane (bilinear).

    src_features: (B, C, Hs, Ws); K_ref, K_src: (B, 3, 3) at the feature resolution;
    poses (B, 4, 4) camera-to-world; depths: (B, D) fronto-parallel planes, or (B, D, H, W) one
    depth per reference pixel (H, W as ref_size); ref_size (H, W) of the reference
    grid (default: the source's).
    -> warped (B, C, D, H, W), valid (B, D, H, W) bool: sample inside the source and in front of it.
    """
    b, c, hs, ws = src_features.shape
    h, w = ref_size or (hs, ws)
    uv, z = _project_planes(K_ref, K_src, ref_camera_to_world, src_camera_to_world, depths, h, w)
    d = depths.shape[1]
    valid = (z > 1e-6) & (uv[..., 0] >= -0.5) & (uv[..., 0] <= ws - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= hs - 0.5)
    grid = torch.stack([_normalise(uv[..., 0], ws), _normalise(uv[..., 1], hs)], -1).view(b, d * h, w, 2)
    work = _sampling_dtype(src_features)
    warped = F.grid_sample(src_features.to(work), grid.to(work), mode="bilinear", padding_mode="zeros",
                           align_corners=True).to(src_features.dtype)
    return warped.view(b, c, d, h, w), valid


def epipolar_warp_volume(volume: torch.Tensor, K: torch.Tensor, volume_camera_to_world: torch.Tensor,
                         query_camera_to_world: torch.Tensor, depths: torch.Tensor, spacing: str = "linear",
                         ) -> tuple[torch.Tensor, torch.Tensor]:
    """Resample a cost/feature volume of one camera into another camera's frustum.

    Each query voxel (u, v, d) is lifted to 3D, projected into the volume's camera at
    (u', v') with depth z', and the volume is sampled trilinearly at (u', v', index(z')).
    Both volumes share intrinsics K and depth planes (the same network resolution).
    volume: (B, C, D, H, W); K: (B, 3, 3); poses (B, 4, 4); depths (B, D) with the given spacing
    -> warped (B, C, D, H, W), valid (B, D, H, W) bool (inside the other frustum and plane range).
    """
    b, c, d, h, w = volume.shape
    uv, z = _project_planes(K, K, query_camera_to_world, volume_camera_to_world, depths, h, w)
    idx = plane_index(z, depths[:, 0], depths[:, -1], d, spacing)
    valid = ((z > 1e-6) & (uv[..., 0] >= -0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= -0.5)
             & (uv[..., 1] <= h - 0.5) & (idx >= -0.5) & (idx <= d - 0.5))
    grid = torch.stack([_normalise(uv[..., 0], w), _normalise(uv[..., 1], h), _normalise(idx, d)], -1)
    work = _sampling_dtype(volume)
    warped = F.grid_sample(volume.to(work), grid.to(work), mode="bilinear", padding_mode="zeros",
                           align_corners=True).to(volume.dtype)
    return warped, valid
