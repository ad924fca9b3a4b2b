"""Classical plane-sweep stereo on an analytically rendered textured scene."""
import numpy as np
import pytest
import torch

from depth.planesweep import PlaneSweepOptions, plane_sweep_depth, to_gray
from recon.plane_scene import plane_scan


def _inputs(scan):
    imgs = torch.stack([torch.from_numpy(scan.image(i)).permute(2, 0, 1).float() / 255 for i in range(len(scan))])
    return (to_gray(imgs), torch.from_numpy(scan.camera_to_world).float(),
            torch.from_numpy(scan.intrinsics.K).float())


def test_planesweep_reaches_low_abs_rel_on_textured_scene():
    scan = plane_scan(5, 160, 128, step=0.08)
    gray, poses, K = _inputs(scan)
    depth, conf = plane_sweep_depth(gray[2], gray[[0, 1, 3, 4]], K, poses[2], poses[[0, 1, 3, 4]], (1.0, 5.0))
    gt = torch.from_numpy(scan.depth(2))
    valid = (depth > 0) & (gt > 0)
    abs_rel = ((depth[valid] - gt[valid]).abs() / gt[valid]).mean().item()
    assert valid.float().mean() > 0.6, "too few pixels survive the filters"
    assert abs_rel < 0.1
    assert ((conf > 0) == (depth > 0)).all() and conf.max() <= 1.0
    # Sub-plane refinement: typical error well under one plane step (~4 % of depth here).
    assert np.median(((depth[valid] - gt[valid]).abs() / gt[valid]).numpy()) < 0.01


def test_planesweep_rejects_textureless_and_wrong_geometry():
    scan = plane_scan(3, 96, 80, step=0.08)
    gray, poses, K = _inputs(scan)
    flat = torch.full_like(gray, 0.5)
    depth, _ = plane_sweep_depth(flat[1], flat[[0, 2]], K, poses[1], poses[[0, 2]], (1.0, 5.0))
    assert (depth == 0).all()
    # Sources whose poses are swapped contradict each other: the consistency check removes most pixels
    # and what survives is not accurate.
    good, _ = plane_sweep_depth(gray[1], gray[[0, 2]], K, poses[1], poses[[0, 2]], (1.0, 5.0),
                                PlaneSweepOptions(num_planes=48))
    bad, _ = plane_sweep_depth(gray[1], gray[[0, 2]], K, poses[1], poses[[2, 0]], (1.0, 5.0),
                               PlaneSweepOptions(num_planes=48))
    assert (bad > 0).float().mean() < 0.5 * (good > 0).float().mean()


def test_refine_depth_pulls_a_wrong_prior_onto_the_surface_and_keeps_it_where_blank():
    from depth.planesweep import refine_depth

    scan = plane_scan(5, 160, 128, step=0.08)
    gray, poses, K = _inputs(scan)
    gt = torch.from_numpy(scan.depth(2))
    prior = gt * 1.3  # 30 % too far: inside the +-50 % band
    depth, score = refine_depth(gray[2], gray[[0, 1, 3, 4]], K, poses[2], poses[[0, 1, 3, 4]], prior)
    refined = score > 0
    assert refined.float().mean() > 0.6
    assert np.median(((depth[refined] - gt[refined]).abs() / gt[refined]).numpy()) < 0.01
    assert torch.equal(depth[~refined], prior[~refined]) and score.max() <= 1.0
    # A blank image matches nowhere: the prior comes back untouched.
    flat = torch.full_like(gray, 0.5)
    depth, score = refine_depth(flat[2], flat[[1, 3]], K, poses[2], poses[[1, 3]], prior)
    assert torch.equal(depth, prior) and (score == 0).all()
    # A prior outside the band cannot reach the surface: no minimum inside it, nothing refined.
    _, score = refine_depth(gray[2], gray[[0, 1, 3, 4]], K, poses[2], poses[[0, 1, 3, 4]], gt * 2.5)
    assert (score > 0).float().mean() < 0.1


def test_refine_agreement_keeps_only_pixels_the_sources_confirm():
    from depth.planesweep import refine_depth

    scan = plane_scan(3, 96, 80, step=0.08)
    gray, poses, K = _inputs(scan)
    prior = torch.from_numpy(scan.depth(1)) * 1.2
    opts = PlaneSweepOptions(refine_agreement=True)
    _, plain = refine_depth(gray[1], gray[[0, 2]], K, poses[1], poses[[0, 2]], prior)
    _, agreed = refine_depth(gray[1], gray[[0, 2]], K, poses[1], poses[[0, 2]], prior, opts)
    assert (agreed > 0).float().mean() > 0.5  # right poses: the sources confirm most of what the match found
    assert ((agreed > 0) & ~(plain > 0)).sum() == 0  # the check only removes
    # One source's pose 4 cm off: the mean match still passes, but that source's own best depth disagrees.
    off = poses[[0, 2]].clone()
    off[1, 0, 3] += 0.04
    _, plain_off = refine_depth(gray[1], gray[[0, 2]], K, poses[1], off, prior)
    _, agreed_off = refine_depth(gray[1], gray[[0, 2]], K, poses[1], off, prior, opts)
    assert (plain_off > 0).float().mean() > 0.5
    assert (agreed_off > 0).float().mean() < 0.5 * (plain_off > 0).float().mean()


@pytest.mark.data
def test_planesweep_on_real_iclnuim_frames(iclnuim):
    from depth.metrics import on_gt_grid
    from depth.options import DepthOptions
    from depth.planesweep import run_planesweep
    from recon.readers import open_scan

    scan = open_scan(iclnuim).select(0, 5, 9)
    results = list(run_planesweep(scan, DepthOptions(mode="planesweep", depth_range=(0.3, 6.0)),
                                  skip=frozenset(i for i in range(9) if i != 4)))
    assert [r.index for r in results] == [4]
    gt = scan.depth(4)
    depth = on_gt_grid(results[0].depth, gt)
    valid = (depth > 0) & (gt > 0)
    abs_rel = np.mean(np.abs(depth[valid] - gt[valid]) / gt[valid])
    assert valid.sum() > 0.1 * (gt > 0).sum()
    assert abs_rel < 0.1


def test_box_filter_is_the_window_mean_inside_the_image():
    import torch.nn.functional as F

    from depth.planesweep import _box
    x = torch.rand(3, 2, 20, 27, generator=torch.Generator().manual_seed(0))
    expected = F.avg_pool2d(x, 7, 1, 3, count_include_pad=False)
    assert torch.allclose(_box(x, 7), expected, atol=1e-6)
    corner = x[0, 1, :4, :4].mean()  # a 7x7 window at (0, 0) covers 4x4 pixels of the image
    assert torch.allclose(_box(x, 7)[0, 1, 0, 0], corner, atol=1e-6)
