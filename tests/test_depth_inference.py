"""Depth over a scan: ESTM memory, agreement between modes, resizing, outputs on disk, bad input."""
import dataclasses

import cv2
import numpy as np
import pytest
import torch

from depth.checkpoint import save_checkpoint
from depth.config import TINY
from depth.estimator import DepthEstimator, TemporalMemory, _Pass, mirror_intrinsics, mirror_pose
from depth.inference import estimate_depth
from depth.model import ESTNet
from depth.options import DepthOptions
from depth.views import network_view, to_scan_pixels
from recon.keyframes import KeyframeConfig, SourceConfig, pose_distance, select_keyframes, select_sources
from recon.plane_scene import lateral_path, plane_scan
from recon.errors import ReconError
from recon.geometry import invert_pose, project, transform_points
from recon.io import load_confidence_map, load_depth_map


pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def estimator():
    torch.manual_seed(0)
    return DepthEstimator(ESTNet(TINY), "cpu")


@pytest.fixture(scope="module")
def scan():
    return plane_scan(5, 120, 90, step=0.08)  # not the network size: resized in and out


def _run(estimator, scan, window="offline", **kw):
    return list(estimator.run(scan, DepthOptions(sources=SourceConfig(window=window), **kw)))


def test_estm_memory_holds_last_n_and_drops_oldest(estimator, scan):
    memory = TemporalMemory(2)
    seen = []
    for r in estimator.run(scan, DepthOptions(mode="estm"), memory=memory):
        seen.append(list(memory.names))
    names = scan.names
    assert seen == [names[:1], names[:2], names[1:3], names[2:4], names[3:5]]


def test_modes_agree_where_they_should(estimator, scan):
    independent = _run(estimator, scan, mode="independent")
    estm = _run(estimator, scan, mode="estm")
    no_memory = _run(estimator, scan, mode="estm", memory_size=0)
    joint_single = _run(estimator, scan, mode="joint", joint_group=1)
    joint = _run(estimator, scan, mode="joint", joint_group=3)
    for a, b, c in zip(independent, no_memory, joint_single):
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.depth, c.depth)
    # The first ESTM frame has an empty memory: identical to independent; later ones read the memory.
    assert np.array_equal(estm[0].depth, independent[0].depth)
    assert all(np.abs(e.depth - i.depth).max() > 1e-5 for e, i in zip(estm[1:], independent[1:]))
    # Joint on a 3-frame group: every frame attends to the other two, so all differ from independent.
    assert all(np.abs(j.depth - i.depth).max() > 1e-5 for j, i in zip(joint[:3], independent[:3]))
    for r in estm:  # stored at the network's long side (96 of TINY's 96x64), the scan's aspect: 96x72
        assert r.depth.shape == (72, 96) and r.confidence.shape == (72, 96)
        assert r.depth.min() >= 1.0 - 1e-4 and r.depth.max() <= 5.0 + 1e-4


def test_online_window_uses_past_frames_only(estimator, scan):
    results = _run(estimator, scan, mode="estm", window="online")
    # The first two frames have no two past sources: skipped; every other frame looks back only.
    assert [r.index for r in results] == [2, 3, 4]
    assert all(max(r.sources) < r.index for r in results)


def test_estimate_depth_writes_maps_and_summary(tmp_path, scan):
    torch.manual_seed(0)
    weights = save_checkpoint(tmp_path / "tiny.pt", ESTNet(TINY), TINY, {"note": "random"})
    out = tmp_path / "depth"
    calls = []
    summary = estimate_depth(scan, out, DepthOptions(mode="estm", weights=str(weights)),
                             progress=lambda i, n: calls.append((i, n)))
    assert calls[-1] == (5, 5) and summary["config"] == "tiny"
    expected = select_sources(scan.camera_to_world)[2]
    assert summary["frames"][2]["sources"] == [scan.names[j] for j in expected]
    depth = load_depth_map(out, scan.names[2])
    assert depth.shape == (72, 96) and depth.dtype == np.float32
    assert load_confidence_map(out, scan.names[2]).shape == (72, 96)
    assert (out / "depth.json").is_file()
    full_out = tmp_path / "full"
    estimate_depth(scan, full_out, DepthOptions(mode="estm", weights=str(weights), full_resolution=True))
    full = load_depth_map(full_out, scan.names[2])
    assert full.shape == (90, 120)  # on request, the scan's own grid
    # The stored grid keeps what the network said: the full-resolution map brought down to it agrees.
    assert np.abs(cv2.resize(full, (96, 72), interpolation=cv2.INTER_AREA) - depth).mean() < 0.01 * depth.mean()
    size = sum(p.stat().st_size for p in out.glob("*.png"))
    assert size < 0.8 * sum(p.stat().st_size for p in full_out.glob("*.png"))  # 96x72 of 120x90 pixels: 0.64
    ps = estimate_depth(scan, tmp_path / "ps", DepthOptions(mode="planesweep"))
    assert ps["mode"] == "planesweep" and len(ps["frames"]) == 5
    gt = scan.depth(2)
    pred = load_depth_map(tmp_path / "ps", scan.names[2])
    valid = pred > 0
    assert valid.mean() > 0.4
    assert np.mean(np.abs(pred[valid] - gt[valid]) / gt[valid]) < 0.1


def test_bad_input_is_refused(tmp_path, estimator, scan):
    with pytest.raises(ReconError, match="depth weights file not found"):
        estimate_depth(scan, tmp_path / "x", DepthOptions(mode="estm", weights=str(tmp_path / "none.pt")))
    with pytest.raises(ReconError, match="unknown depth mode"):
        estimate_depth(scan, tmp_path / "x", DepthOptions(mode="magic"))
    bad_pose = dataclasses.replace(scan, frames=[dataclasses.replace(f) for f in scan.frames])
    bad_pose.frames[3].camera_to_world = np.full((4, 4), np.nan)
    with pytest.raises(ReconError, match="NaN"):
        _run(estimator, bad_pose)
    with pytest.raises(ReconError, match="at least 3 frames"):
        _run(estimator, scan.subset([0, 1]))
    for mode in ("hybrid", "planesweep"):  # refused before the stage writes anything
        with pytest.raises(ReconError, match="at least 3 frames"):
            estimate_depth(scan.subset([0, 1]), tmp_path / mode, DepthOptions(mode=mode))
        assert not (tmp_path / mode).exists()
    static = dataclasses.replace(scan, frames=[dataclasses.replace(f, camera_to_world=np.eye(4))
                                               for f in scan.frames])
    with pytest.raises(ReconError, match="usable source"):
        _run(estimator, static)
    empty = dataclasses.replace(scan, frames=[dataclasses.replace(f, image_array=np.zeros((0, 0, 3), np.uint8))
                                              for f in scan.frames])
    with pytest.raises(ReconError):
        _run(estimator, empty)
    no_range = dataclasses.replace(scan, metadata=dataclasses.replace(scan.metadata, depth_range=None))
    with pytest.raises(ReconError, match="depth range"):
        _run(estimator, no_range)
    with pytest.raises(ReconError, match="invalid depth range"):
        _run(estimator, scan, depth_range=(3.0, 1.0))
    weights = save_checkpoint(tmp_path / "tiny.pt", ESTNet(TINY), TINY)
    with pytest.raises(ReconError, match="expected 'compact'"):
        DepthEstimator.from_weights(weights, "cpu", config="compact")


def test_source_selection_prefers_useful_baseline():
    poses = lateral_path(16, step=0.03, yaw_per_frame=0.0)
    offline = select_sources(poses)
    for i, srcs in offline.items():
        assert len(srcs) == 2 and i not in srcs
        # 0.03 m steps: the sources sit about 0.15 m (5 frames) away, never at the nearest neighbours.
        assert all(abs(np.linalg.norm(poses[i, :3, 3] - poses[j, :3, 3]) - 0.15) < 0.04 for j in srcs)
    online = select_sources(poses, SourceConfig(window="online"))
    assert all(j < i for i, srcs in online.items() for j in srcs)
    assert online[0] == [] and len(online[6]) == 2
    # Frames closer than min_baseline are dropped rather than used as a fallback.
    crawl = lateral_path(8, step=0.002, yaw_per_frame=0.0)
    crawl[:, 1, 3] = 0.0
    assert all(srcs == [] for srcs in select_sources(crawl, SourceConfig(source_window=3)).values())
    keys = select_keyframes(poses, KeyframeConfig(0.1))
    assert keys[0] == 0 and all(pose_distance(poses[a], poses[b])[0] >= 0.1 for a, b in zip(keys, keys[1:]))
    assert all(pose_distance(poses[a], poses[j])[0] < 0.1 for a, b in zip(keys, keys[1:]) for j in range(a + 1, b))


def test_resume_reuses_finished_frames_only_with_same_settings(tmp_path, scan):
    out = tmp_path / "ps"
    opts = DepthOptions(mode="planesweep")

    def stop_after_two(i, n):
        if i == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        estimate_depth(scan, out, opts, progress=stop_after_two)
    assert not (out / "depth.json").exists() and (out / "000001.png").is_file()
    computed = []
    summary = estimate_depth(scan, out, opts, resume=True, progress=lambda i, n: computed.append(i))
    assert computed == [3, 4, 5]
    assert [f.get("reused", False) for f in summary["frames"]] == [True, True, False, False, False]
    computed.clear()
    again = estimate_depth(scan, out, opts, resume=True, progress=lambda i, n: computed.append(i))
    assert computed == [] and again == summary
    other = DepthOptions(mode="planesweep", depth_range=(1.0, 6.0))
    estimate_depth(scan, out, other, resume=True, progress=lambda i, n: computed.append(i))
    assert computed == [1, 2, 3, 4, 5]


def test_bf16_precision_stays_close_to_fp32(estimator, scan):
    fp32 = _run(estimator, scan, mode="estm", precision="fp32")
    bf16 = []
    for r in estimator.run(scan, DepthOptions(mode="estm", precision="bf16")):
        assert not torch.is_autocast_enabled("cpu")  # autocast does not leak out of the generator
        bf16.append(r)
    for a, b in zip(fp32, bf16):
        rel = np.abs(a.depth - b.depth) / a.depth
        assert b.depth.dtype == np.float32 and rel.mean() < 0.01 and rel.max() < 0.1
    assert any(np.abs(a.depth - b.depth).max() > 0 for a, b in zip(fp32, bf16))  # it did run in bf16
    with pytest.raises(ReconError, match="precision"):
        _run(estimator, scan, precision="fp8")


def test_auto_precision_runs_what_the_hardware_computes_and_says_so(estimator, scan, tmp_path):
    from depth.device import computes_bf16

    expected = "bf16" if computes_bf16(torch.device("cpu")) else "fp32"
    summary = estimate_depth(scan, tmp_path / "auto", DepthOptions(mode="estm", precision="auto"), estimator=estimator)
    assert summary["precision"] == expected  # depth.json names the arithmetic that ran, not "auto"
    auto = [load_depth_map(tmp_path / "auto", name) for name in scan.names]
    same = estimate_depth(scan, tmp_path / expected, DepthOptions(mode="estm", precision=expected), estimator=estimator)
    assert same["precision"] == expected
    assert all(np.array_equal(a, load_depth_map(tmp_path / expected, name)) for a, name in zip(auto, scan.names))


def test_the_mirrored_camera_sees_the_mirrored_image():
    K = np.array([[300.0, 0, 140.3], [0, 310.0, 101.7], [0, 0, 1]])  # principal point off centre
    width = 320
    camera_to_world = lateral_path(3, step=0.2, yaw_per_frame=0.3)[2]
    points = np.random.default_rng(0).uniform([-1, -1, 2], [1, 1, 4], (20, 3))
    u, v = project(transform_points(invert_pose(camera_to_world), points), K)[0].T
    mirrored = mirror_pose(camera_to_world)
    mu, mv = project(transform_points(invert_pose(mirrored), points * [-1, 1, 1]), mirror_intrinsics(K, width))[0].T
    assert np.allclose(mu, width - 1 - u) and np.allclose(mv, v)
    assert np.isclose(np.linalg.det(mirrored[:3, :3]), 1.0)  # still a rotation


def test_mirror_pass_keeps_the_more_confident_of_two_accurate_passes():
    estimator = DepthEstimator.from_weights("compact", "cpu")
    scan = plane_scan(4, 160, 128, step=0.15)
    opts = DepthOptions(mode="estm", depth_range=(1.0, 5.0))
    plain = list(estimator.run(scan, opts))
    both = list(estimator.run(scan, dataclasses.replace(opts, mirror_pass=True)))
    mirrored = _Pass(estimator, scan, opts, mirrored=True)
    memory = TemporalMemory(2)
    with torch.no_grad():
        alone = [mirrored.result(i, *mirrored.maps(estimator._step(mirrored, memory, i, "estm")))
                 for i in mirrored.sources]
    for p, b, m, i in zip(plain, both, alone, mirrored.sources):
        gt = scan.depth(i)
        gt = cv2.resize(gt, p.depth.shape[::-1], interpolation=cv2.INTER_NEAREST)
        err = {k: float(np.mean(np.abs(r.depth - gt) / gt)) for k, r in (("plain", p), ("both", b), ("mirrored", m))}
        assert err["mirrored"] < 1.5 * err["plain"] + 0.02, err  # the mirrored geometry is right
        assert np.all(b.confidence >= np.maximum(p.confidence, m.confidence) - 1e-3)
        from_mirror = b.confidence > p.confidence + 1e-3
        assert 0.02 < from_mirror.mean() < 0.98  # each pass wins somewhere
        same = np.isclose(b.depth, p.depth, atol=1e-3)  # where the plain pass won (but at the seams: resampled)
        assert same[~from_mirror].mean() > 0.8 and same[from_mirror].mean() < 0.5
    with pytest.raises(ReconError, match="mirror-pass"):
        DepthOptions(mode="joint", mirror_pass=True).validate()


def test_crop_fit_keeps_square_pixels_and_maps_back_to_the_window():
    wide = plane_scan(3, 192, 96)  # 2:1 frames into a 5:4 network input
    stretched = network_view(wide, 80, 64, "stretch").intrinsics
    cropped = network_view(wide, 80, 64, "crop").intrinsics
    assert abs(stretched.fx / stretched.fy - 1) > 0.3  # stretching makes pixels non-square ...
    assert cropped.size == (80, 64) and cropped.fx == pytest.approx(cropped.fy)  # ... cropping does not
    assert cropped.cx == pytest.approx((80 - 1) / 2) and cropped.cy == pytest.approx((64 - 1) / 2)
    # A map equal to each network pixel's scan x coordinate comes back as the scan's x inside the
    # window, and 0 in the cropped-off borders.
    view = network_view(wide, 80, 64, "crop")
    cover_w = view.output_size[0]
    left = view.crop[0]
    net_x = (torch.arange(80, dtype=torch.float32) + left + 0.5) * (192 / cover_w) - 0.5
    back = to_scan_pixels(net_x.expand(1, 1, 64, 80).clone(), view, (192, 96))[0, 0]
    assert torch.allclose(back[:, 40:152], torch.arange(40, 152, dtype=torch.float32).expand(96, -1), atol=1e-3)
    kept = int(round(80 * 192 / cover_w))
    assert (back[:, :(192 - kept) // 2 - 1] == 0).all() and (back[:, -((192 - kept) // 2 - 1):] == 0).all()
    # "stretch" is plain bilinear resampling of the whole frame.
    x = torch.rand(1, 2, 64, 80)
    ref = torch.nn.functional.interpolate(x, (96, 192), mode="bilinear", align_corners=False)
    assert torch.allclose(to_scan_pixels(x, network_view(wide, 80, 64, "stretch"), (192, 96)), ref, atol=1e-5)


def test_crop_fit_gives_no_depth_outside_the_window(estimator):
    wide = plane_scan(4, 200, 80, step=0.08)
    full = _run(estimator, wide, mode="estm", full_resolution=True)
    crop = _run(estimator, wide, mode="estm", fit="crop", full_resolution=True)
    for f, c in zip(full, crop):
        assert c.depth.shape == f.depth.shape == (80, 200)
        assert (f.depth > 0).all()
        assert (c.depth[:, :5] == 0).all() and (c.confidence[:, :5] == 0).all()
        assert (c.depth[:, 60:140] > 0).all()
    with pytest.raises(ReconError, match="unknown depth fit"):
        _run(estimator, wide, fit="pad")


@pytest.mark.slow
def test_compiled_network_gives_the_same_depth(estimator, scan):
    eager = _run(estimator, scan, mode="estm", precision="fp32")
    compiled = _run(estimator, scan, mode="estm", precision="fp32", compile=True)
    assert estimator.network_calls(True) is estimator.network_calls(True)  # compiled once, then reused
    for a, b in zip(eager, compiled):
        assert np.allclose(a.depth, b.depth, rtol=1e-4, atol=1e-4)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_graphs_give_the_same_depth(scan):
    """On CUDA `compile` replays CUDA graphs and copies their outputs out: the features and memory entries a
    pass keeps over frames must not be overwritten by the next replay."""
    torch.manual_seed(0)
    cuda = DepthEstimator(ESTNet(TINY), "cuda")
    eager = _run(cuda, scan, mode="estm", device="cuda", precision="fp32")
    graphed = _run(cuda, scan, mode="estm", device="cuda", precision="fp32", compile=True)
    for a, b in zip(eager, graphed):
        assert np.allclose(a.depth, b.depth, rtol=1e-3, atol=1e-3)


def test_graph_outputs_are_copied():
    """What a replay returns is copied (tensors inside dataclasses, tuples and lists), not the graph's buffers."""
    from depth.estimator import _graph_replay
    from depth.model import MemoryEntry

    key, value = torch.ones(2), torch.zeros(2)
    entry = MemoryEntry(key, value, torch.eye(4), "f0")
    out = _graph_replay(lambda: (entry, [key]))()
    assert out[0].name == "f0" and torch.equal(out[0].key, key) and torch.equal(out[1][0], key)
    key.add_(1)  # the next replay writing into its buffers
    assert torch.equal(out[0].key, torch.ones(2)) and torch.equal(out[1][0], torch.ones(2))
    assert out[0].value.data_ptr() != value.data_ptr()


def test_hybrid_mode_is_estm_refined_where_the_images_match_and_resumes(tmp_path, scan):
    torch.manual_seed(0)
    weights = str(save_checkpoint(tmp_path / "tiny.pt", ESTNet(TINY), TINY, {"note": "random"}))
    runs = {mode: tmp_path / mode for mode in ("estm", "hybrid")}
    for mode, out in runs.items():
        summary = estimate_depth(scan, out, DepthOptions(mode=mode, weights=weights, depth_range=(1.0, 5.0)))
    assert summary["mode"] == "hybrid" and summary["planesweep"]["refine_band"] == 0.5 and summary["weights_digest"]
    band = summary["planesweep"]["refine_band"]
    gains = []
    for i, name in enumerate(scan.names):
        estm, hybrid, gt = load_depth_map(runs["estm"], name), load_depth_map(runs["hybrid"], name), scan.depth(i)
        gt = cv2.resize(gt, estm.shape[::-1], interpolation=cv2.INTER_NEAREST)
        moved = hybrid != estm
        ratio = hybrid[moved] / estm[moved]
        assert (ratio > 1 / (1 + band) - 1e-3).all() and (ratio < 1 + band + 1e-3).all()
        ok = moved & (gt > 0)
        if ok.mean() > 0.2:  # untrained weights: refined pixels sit on the surface, the network's do not
            gains.append((np.abs(estm[ok] - gt[ok]) / gt[ok]).mean() - (np.abs(hybrid[ok] - gt[ok]) / gt[ok]).mean())
    assert gains and min(gains) > 0.02
    # interrupted after two frames, it resumes ESTM's memory and writes the same maps
    resumed = tmp_path / "resumed"
    opts = DepthOptions(mode="hybrid", weights=weights, depth_range=(1.0, 5.0))

    def stop_after_two(i, n):
        if i == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        estimate_depth(scan, resumed, opts, progress=stop_after_two)
    computed = []
    estimate_depth(scan, resumed, opts, resume=True, progress=lambda i, n: computed.append(i))
    assert computed == [3, 4, 5]
    for name in scan.names:
        assert np.allclose(load_depth_map(resumed, name), load_depth_map(runs["hybrid"], name), atol=2e-3)


def test_mirror_pass_resumes_with_both_memories(tmp_path, scan):
    """A resumed ESTM run stores only the first pass's memory; the mirrored pass rebuilds its own, so the
    maps match an uninterrupted run's."""
    torch.manual_seed(0)
    weights = str(save_checkpoint(tmp_path / "tiny.pt", ESTNet(TINY), TINY, {"note": "random"}))
    opts = DepthOptions(mode="estm", weights=weights, depth_range=(1.0, 5.0), mirror_pass=True)
    whole = estimate_depth(scan, tmp_path / "whole", opts)
    assert whole["mirror_pass"] is True

    def stop_after_three(i, n):
        if i == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        estimate_depth(scan, tmp_path / "resumed", opts, progress=stop_after_three)
    computed = []
    estimate_depth(scan, tmp_path / "resumed", opts, resume=True, progress=lambda i, n: computed.append(i))
    assert computed == [4, 5]
    for name in scan.names:
        assert np.allclose(load_depth_map(tmp_path / "resumed", name), load_depth_map(tmp_path / "whole", name),
                           atol=2e-3)
