"""Plane-sweep and epipolar warping against scenes whose answer is known analytically."""
import math

import numpy as np
import pytest
import torch

from depth.geometry import (depth_planes, epipolar_warp_volume, plane_index, plane_sweep_warp,
                            scale_intrinsics)
from recon.scan import Intrinsics


def _rot_y(angle):
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=torch.float64)


def _pose(rot, trans):
    p = torch.eye(4, dtype=torch.float64)
    p[:3, :3] = rot
    p[:3, 3] = torch.tensor(trans, dtype=torch.float64)
    return p


def _texture(x, y):
    return 0.5 + 0.2 * torch.sin(7.0 * x + 1.0) * torch.cos(5.0 * y) + 0.15 * torch.sin(11.0 * x * y + 3.0 * y)


def _render_plane(K, camera_to_world, plane_z, h, w):
    """Image of the textured world plane z = plane_z seen by a pinhole camera (ray-plane intersection)."""
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    rays_cam = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], -1)
    rays = rays_cam @ camera_to_world[:3, :3].T
    origin = camera_to_world[:3, 3]
    t = (plane_z - origin[2]) / rays[..., 2]
    pts = origin + t[..., None] * rays
    return _texture(pts[..., 0], pts[..., 1])


def test_homography_warp_reproduces_reference_only_at_true_plane():
    h, w, plane_z = 48, 64, 2.0
    K = torch.tensor([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]], dtype=torch.float64)
    ref_pose = torch.eye(4, dtype=torch.float64)
    src_pose = _pose(_rot_y(0.05), [0.3, 0.05, 0.1])
    ref = _render_plane(K, ref_pose, plane_z, h, w)
    src = _render_plane(K, src_pose, plane_z, h, w)
    depths = torch.tensor([[1.2, 1.6, 2.0, 2.5, 3.2]], dtype=torch.float64)
    warped, valid = plane_sweep_warp(src[None, None], K[None], K[None], ref_pose[None], src_pose[None], depths)
    assert warped.shape == (1, 1, 5, h, w) and valid.shape == (1, 5, h, w)
    errors = []
    for k in range(5):
        m = valid[0, k]
        assert m.float().mean() > 0.5
        errors.append((warped[0, 0, k][m] - ref[m]).abs().mean().item())
    # Bilinear resampling of a smooth texture: tiny error at the true plane, large elsewhere.
    assert errors[2] < 0.01
    assert min(errors[:2] + errors[3:]) > 5 * errors[2]
    assert min(errors[:2] + errors[3:]) > 0.03


def test_per_pixel_depths_warp_like_planes_and_follow_a_depth_map():
    h, w = 48, 64
    K = torch.tensor([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]], dtype=torch.float64)
    ref_pose, src_pose = torch.eye(4, dtype=torch.float64), _pose(_rot_y(0.05), [0.3, 0.05, 0.1])
    src = _render_plane(K, src_pose, 2.0, h, w)
    planes = torch.tensor([[1.6, 2.0, 2.5]], dtype=torch.float64)
    by_plane, valid_plane = plane_sweep_warp(src[None, None], K[None], K[None], ref_pose[None], src_pose[None], planes)
    per_pixel = planes[:, :, None, None].expand(1, 3, h, w)
    by_pixel, valid_pixel = plane_sweep_warp(src[None, None], K[None], K[None], ref_pose[None], src_pose[None],
                                             per_pixel)
    assert torch.allclose(by_plane, by_pixel) and torch.equal(valid_plane, valid_pixel)
    # Half the pixels at the true depth, half 25 % off: only the first half reproduces the reference.
    ref = _render_plane(K, ref_pose, 2.0, h, w)
    mixed = torch.full((1, 1, h, w), 2.0, dtype=torch.float64)
    mixed[..., w // 2:] = 2.5
    warped, valid = plane_sweep_warp(src[None, None], K[None], K[None], ref_pose[None], src_pose[None], mixed)
    err = (warped[0, 0, 0] - ref).abs()
    left, right = valid[0, 0].clone(), valid[0, 0].clone()
    left[:, w // 2:], right[:, :w // 2] = False, False
    assert err[left].mean() < 0.01 and err[right].mean() > 0.03


def test_plane_sweep_valid_mask_marks_samples_outside_source():
    K = torch.tensor([[[50.0, 0, 15.5], [0, 50.0, 11.5], [0, 0, 1]]])
    src_pose = torch.eye(4)[None].clone()
    src_pose[0, 0, 3] = 1.0  # source 1 m to the right: at 1 m depth the shift is 50 px > width
    _, valid = plane_sweep_warp(torch.ones(1, 2, 24, 32), K, K, torch.eye(4)[None], src_pose,
                                torch.tensor([[1.0, 100.0]]))
    assert not valid[0, 0].any()
    assert valid[0, 1].float().mean() > 0.9


def _linear_volume(d, h, w, coeffs=(0.3, -0.2, 0.7, 1.0)):
    k, v, u = torch.meshgrid(torch.arange(d, dtype=torch.float64), torch.arange(h, dtype=torch.float64),
                             torch.arange(w, dtype=torch.float64), indexing="ij")
    a, b, c, e = coeffs
    return (a * u + b * v + c * k + e)[None, None]


def test_epipolar_warp_into_same_camera_is_identity():
    d, h, w = 8, 12, 16
    vol = torch.randn(1, 3, d, h, w, dtype=torch.float64)
    K = torch.tensor([[[20.0, 0, 7.5], [0, 20.0, 5.5], [0, 0, 1]]], dtype=torch.float64)
    pose = _pose(_rot_y(0.3), [1.0, -2.0, 0.5])[None]
    for spacing in ("linear", "inverse"):
        depths = depth_planes(torch.tensor([0.5], dtype=torch.float64), torch.tensor([4.0], dtype=torch.float64),
                              d, spacing)
        warped, valid = epipolar_warp_volume(vol, K, pose, pose, depths, spacing)
        assert valid.all()
        torch.testing.assert_close(warped, vol, atol=1e-9, rtol=0)


@pytest.mark.parametrize("spacing", ["linear", "inverse", "log"])
def test_epipolar_warp_translated_camera_matches_analytic_shift(spacing):
    d, h, w = 10, 12, 40
    fx, cx, cy = 30.0, 19.5, 5.5
    K = torch.tensor([[[fx, 0, cx], [0, fx, cy], [0, 0, 1]]], dtype=torch.float64)
    lo, hi = torch.tensor([1.0], dtype=torch.float64), torch.tensor([5.0], dtype=torch.float64)
    depths = depth_planes(lo, hi, d, spacing)
    vol = _linear_volume(d, h, w)
    volume_pose = torch.eye(4, dtype=torch.float64)[None]
    # Query camera 0.2 m to the left of the volume camera: a point at depth z appears fx*0.2/z px
    # further left in the volume camera, on the same plane.
    query_pose = _pose(torch.eye(3, dtype=torch.float64), [-0.2, 0.0, 0.0])[None]
    warped, valid = epipolar_warp_volume(vol, K, volume_pose, query_pose, depths, spacing)
    k, v, u = torch.meshgrid(torch.arange(d, dtype=torch.float64), torch.arange(h, dtype=torch.float64),
                             torch.arange(w, dtype=torch.float64), indexing="ij")
    u_shift = u - fx * 0.2 / depths[0][:, None, None]
    expected = 0.3 * u_shift - 0.2 * v + 0.7 * k + 1.0
    inside = u_shift >= 0
    assert valid[0][inside].all() and not valid[0][u_shift < -0.51].any()
    torch.testing.assert_close(warped[0, 0][inside], expected[inside], atol=1e-6, rtol=0)
    # Moving the query camera backwards moves points to other planes: z' = z - 0.5 in the volume camera.
    query_pose = _pose(torch.eye(3, dtype=torch.float64), [0.0, 0.0, 0.5])[None]
    warped, valid = epipolar_warp_volume(vol, K, volume_pose, query_pose, depths, spacing)
    z_vol = depths[0][:, None, None] + 0.5
    u_vol = cx + (u - cx) * depths[0][:, None, None] / z_vol
    v_vol = cy + (v - cy) * depths[0][:, None, None] / z_vol
    k_vol = plane_index(z_vol[None], lo, hi, d, spacing)[0]
    expected = 0.3 * u_vol - 0.2 * v_vol + 0.7 * k_vol + 1.0
    inside = (k_vol <= d - 1).expand(d, h, w)
    assert valid[0][inside].all() and not valid[0][k_vol.expand(d, h, w) > d - 0.5].any()
    torch.testing.assert_close(warped[0, 0][inside], expected[inside], atol=1e-6, rtol=0)


def test_depth_planes_spacing_and_index_inverse():
    lo, hi = torch.tensor([0.5, 1.0]), torch.tensor([10.0, 4.0])
    lin = depth_planes(lo, hi, 5, "linear")
    torch.testing.assert_close(lin[1], torch.tensor([1.0, 1.75, 2.5, 3.25, 4.0]))
    inv = depth_planes(lo, hi, 5, "inverse")
    torch.testing.assert_close(1.0 / inv[1], torch.tensor([1.0, 0.8125, 0.625, 0.4375, 0.25]))
    log = depth_planes(lo, hi, 5, "log")
    torch.testing.assert_close(log[1], torch.tensor([1.0, 2 ** 0.5, 2.0, 2 * 2 ** 0.5, 4.0]))
    for spacing, planes in (("linear", lin), ("inverse", inv), ("log", log)):
        torch.testing.assert_close(plane_index(planes, lo, hi, 5, spacing), torch.arange(5.0).expand(2, 5))
    with pytest.raises(ValueError):
        depth_planes(lo, hi, 5, "cubic")


def test_scale_intrinsics_matches_scan_convention():
    intr = Intrinsics(500.0, 480.0, 319.5, 239.5, 640, 480)
    small = intr.resized(160, 120)
    K = scale_intrinsics(torch.tensor(intr.K)[None], 0.25, 0.25)[0].numpy()
    np.testing.assert_allclose(K, small.K, atol=1e-12)


def test_warps_keep_float32_geometry_under_autocast():
    """bf16 autocast (training with --amp, inference with --precision bf16) must not reach the projections:
    in bf16 the pixel coordinates at 80x64 were up to 0.125 px off, the relative pose 0.2 degrees."""
    h, w = 64, 80
    K = torch.tensor([[[60.0, 0, 39.5], [0, 60.0, 31.5], [0, 0, 1]]])
    ref_pose = torch.eye(4)[None]
    src_pose = _pose(_rot_y(0.05), [0.3, 0.05, 0.1]).float()[None]
    features = torch.rand(1, 4, h, w, generator=torch.Generator().manual_seed(0))
    planes = torch.tensor([[0.7, 1.3, 2.9, 5.5]])
    volume = torch.rand(1, 2, 4, h, w, generator=torch.Generator().manual_seed(1))
    exact = (plane_sweep_warp(features, K, K, ref_pose, src_pose, planes),
             epipolar_warp_volume(volume, K, ref_pose, src_pose, planes, "inverse"))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        mixed = (plane_sweep_warp(features, K, K, ref_pose, src_pose, planes),
                 epipolar_warp_volume(volume, K, ref_pose, src_pose, planes, "inverse"))
    for (warped, valid), (warped_mixed, valid_mixed) in zip(exact, mixed):
        assert warped_mixed.dtype == torch.float32 and torch.equal(valid, valid_mixed)
        assert torch.allclose(warped, warped_mixed, atol=1e-6)
