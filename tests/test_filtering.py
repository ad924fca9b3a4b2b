"""The depth filter before fusion (issue 13): consistency across views, flying pixels, range, the consistency
score as a confidence, and `recon fuse` / `recon run` using it."""
import json

import numpy as np
import pytest

from apps.cli import main
from fusion.evaluate import MeshEvalConfig, mesh_metrics
from fusion.filtering import DepthFilter, FilterConfig, edge_mask, filtered_depth, nearest_views, parse_checks
from fusion.tsdf import DepthMap, TSDFConfig, fuse_scan
from recon.errors import ReconError
from recon.io import save_depth_map
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata, save_scan

from fixtures.box_room import box_room_mesh, box_room_scan

CORRUPTED = 5


@pytest.fixture(scope="module")
def room():
    return box_room_scan(24, 128, 96)


def _served(depth_filter: DepthFilter, n: int) -> list[DepthMap]:
    return [depth_filter(i) for i in range(n)]


def test_frame_with_offset_depth_is_removed_and_the_others_kept(room):
    """One frame's depth pushed back by twice the filter's tolerance at its farthest pixel: no other view agrees
    with it, so none of it survives."""
    offset = np.float32(2 * FilterConfig().max_rel_diff * room.depth(CORRUPTED).max())

    def source(i):
        depth = room.depth(i)
        return DepthMap(depth + offset if i == CORRUPTED else depth)

    flt = DepthFilter(room, source, FilterConfig(), (0.1, 6.0))
    kept = np.array([(m.depth_m > 0).mean() for m in _served(flt, len(room))])
    assert kept[CORRUPTED] < 0.01
    others = np.delete(kept, CORRUPTED)
    assert others.min() > 0.5 and others.mean() > 0.85, kept
    stats = flt.stats.as_dict()
    assert stats["frames"] == len(room) and stats["dropped"]["consistency"] > 0.9 * 128 * 96
    assert stats["dropped"]["edges"] == 0 and stats["dropped"]["range"] == 0  # a box room has no depth edges
    assert stats["kept_share"] == pytest.approx(stats["kept_pixels"] / stats["valid_pixels"])
    # Each frame is checked against its nearest views by pose distance: never itself, consecutive frames first.
    near = nearest_views(room.camera_to_world, 4)
    assert all(i not in v and len(v) == 4 for i, v in enumerate(near)) and set(near[10][:2]) == {9, 11}


def _save_with_floating_frames(room, folder) -> None:
    """Every 4th frame's depth 30 cm short of the walls: sheets floating in front of them."""
    for i, f in enumerate(room.frames):
        save_depth_map(folder, f.name, room.depth(i) - np.float32(0.3 if i % 4 == 1 else 0.0))


def test_filtered_fusion_drops_floating_sheets(room, tmp_path):
    _save_with_floating_frames(room, tmp_path)
    config = TSDFConfig(depth_max=6.0)
    scores = {}
    for checks in ((), ("consistency",)):
        source = filtered_depth(room, tmp_path, FilterConfig(checks=checks), config)
        mesh = fuse_scan(room, source, config)
        scores[checks] = mesh_metrics(mesh, box_room_mesh(), scan=room, config=MeshEvalConfig(n_points=50_000))
    raw, filtered = scores[()], scores[("consistency",)]
    assert raw["prec"] < 0.9 and filtered["prec"] > 0.98 and filtered["acc"] < 0.6 * raw["acc"], scores


def _one_view_scan(depth: np.ndarray, f: float = 100.0) -> Scan:
    h, w = depth.shape
    intr = Intrinsics(f, f, (w - 1) / 2, (h - 1) / 2, w, h)
    frame = Frame(name="000000", camera_to_world=np.eye(4), image_array=np.full((h, w, 3), 128, np.uint8),
                  depth_array=depth)
    return Scan(intr, [frame], ScanMetadata(metric_scale=True))


def _edges_only(depth: np.ndarray, f: float = 100.0) -> np.ndarray:
    scan = _one_view_scan(depth, f)
    return DepthFilter(scan, lambda i: DepthMap(depth), FilterConfig(checks=("edges",)), (0.1, 10.0))(0).depth_m


def test_flying_pixels_at_a_depth_edge_are_removed():
    """A box 1.5 m away in front of a wall at 3 m, with the smeared ramp a network draws between them."""
    h, w = 96, 128
    depth = np.full((h, w), 3.0, np.float32)
    depth[30:70, 30:70] = 1.5
    ramp = np.linspace(1.5, 3.0, 6)[1:-1].astype(np.float32)  # four flying pixels per row
    depth[30:70, 70:74] = ramp
    out = _edges_only(depth)
    assert not out[30:70, 70:74].any()  # every planted flying pixel is gone
    away = np.ones((h, w), bool)
    away[27:73, 27:77] = False  # more than 2 pixels from the box and its ramp
    assert (out[away] > 0).mean() >= 0.99 and (out[35:65, 35:65] > 0).all()


@pytest.mark.parametrize("tilt_deg", [0.0, 30.0, 55.0])
def test_a_clean_plane_keeps_its_pixels(tilt_deg):
    """A plane turned by up to 55 degrees (so its far side is seen 77 degrees from its normal: the half field of
    view is 22 degrees) is no edge: >= 99 % of it stays."""
    h, w, f = 96, 128, 160.0
    u, v = np.meshgrid(np.arange(w) - (w - 1) / 2, np.arange(h) - (h - 1) / 2)
    # Plane through (0, 0, 2) with normal tilted about the y axis: n . X = n . (0, 0, 2).
    n = np.array([np.sin(np.radians(tilt_deg)), 0.0, -np.cos(np.radians(tilt_deg))])
    rays = np.stack([u / f, v / f, np.ones_like(u)], -1)
    depth = ((n @ [0.0, 0.0, 2.0]) / (rays @ n)).astype(np.float32)
    assert np.all(depth > 0)
    out = _edges_only(depth, f)
    assert (out > 0).mean() >= 0.99
    assert not edge_mask(depth, _one_view_scan(depth, f).intrinsics.K, 80.0).any()


def test_range_is_applied_and_counted(room):
    flt = DepthFilter(room, lambda i: DepthMap(room.depth(i)), FilterConfig(checks=()), (0.1, 2.0))
    out = flt(0).depth_m
    raw = room.depth(0)
    assert np.array_equal(out > 0, (raw >= 0.1) & (raw <= 2.0))
    stats = flt.stats.as_dict()
    assert stats["dropped"]["range"] == int((raw > 2.0).sum()) > 0
    assert stats["kept_share"] == pytest.approx(float(((raw > 0) & (raw <= 2.0)).mean()))


def test_consistency_score_trades_precision_for_recall_monotonically(room):
    """Depth wrong by 5-30 % in 40 % of its 8x8 patches, independently per frame (as a network errs): the higher
    the threshold on the consistency score, the more of the kept pixels are right and the fewer are kept."""
    rng = np.random.default_rng(0)

    def patch_errors():
        wrong = rng.random((12, 16)) < 0.4
        error = rng.uniform(0.05, 0.3, (12, 16)) * rng.choice([-1, 1], (12, 16))
        return np.where(wrong, error, 0.0).repeat(8, 0).repeat(8, 1)

    noise = {i: patch_errors() for i in range(len(room))}

    def source(i):
        return DepthMap((room.depth(i) * (1 + noise[i])).astype(np.float32))

    flt = DepthFilter(room, source, FilterConfig(min_views=1), (0.1, 6.0))
    served = _served(flt, len(room))
    score = np.concatenate([m.confidence.ravel() for m in served])  # every pixel has one; those dropped too
    right = np.concatenate([noise[i].ravel() == 0 for i in range(len(room))])
    precision, kept = [], []
    for t in (0.0, 0.1, 0.2, 0.3, 0.4, 0.5):
        chosen = score >= t
        precision.append(right[chosen].mean())
        kept.append(chosen.mean())
    assert all(b > a for a, b in zip(precision, precision[1:])), precision
    assert all(b < a for a, b in zip(kept, kept[1:])), kept
    assert precision[-1] > 0.9 > precision[0], precision


def test_depth_with_its_own_confidence_keeps_it_and_the_score_still_weighs(room):
    """A network's depth keeps its confidence through the filter (what --min-confidence reads); the consistency
    score, served as confidence only to depth without one, still sets the TSDF weights."""
    own = {i: np.random.default_rng(i).random(room.depth(i).shape).astype(np.float32) for i in range(len(room))}
    config = FilterConfig(weights=True, near_weight_m=0.0)
    with_own = DepthFilter(room, lambda i: DepthMap(room.depth(i), own[i]), config, (0.1, 6.0))
    without = DepthFilter(room, lambda i: DepthMap(room.depth(i)), config, (0.1, 6.0))
    for i in (0, 11):
        a, b = with_own(i), without(i)
        assert np.array_equal(a.confidence, own[i])
        assert np.array_equal(a.depth_m, b.depth_m) and np.array_equal(a.weight, b.weight)
        assert b.confidence is not None and not np.array_equal(b.confidence, own[i])
        assert np.allclose(b.weight, (1 + config.views * b.confidence) / (1 + config.views))


def test_weights_from_the_consistency_score_reach_the_tsdf(room, tmp_path):
    for i, f in enumerate(room.frames):
        save_depth_map(tmp_path, f.name, room.depth(i))
    config = TSDFConfig(depth_max=6.0)
    weighted = filtered_depth(room, tmp_path, FilterConfig(weights=True, near_weight_m=0.0), config)
    frame = weighted(0)
    views = FilterConfig().views
    assert frame.weight is not None and np.allclose(frame.weight, (1 + views * frame.confidence) / (1 + views))
    kept = frame.depth_m > 0
    assert 1 / (1 + views) <= frame.weight[kept].min() and frame.weight.max() <= 1
    assert frame.weight[kept].mean() > 0.5  # exact depth: confirmed by most views (pixel rounding costs some)
    mesh = fuse_scan(room, filtered_depth(room, tmp_path, FilterConfig(weights=True), config), config)
    assert mesh_metrics(mesh, box_room_mesh(), scan=room, config=MeshEvalConfig(n_points=50_000))["fscore"] > 0.9
    assert filtered_depth(room, tmp_path, FilterConfig(near_weight_m=0.0), config)(0).weight is None


def test_predicted_depth_weighs_near_over_depth_and_a_scans_own_depth_does_not(room, tmp_path):
    for i, f in enumerate(room.frames):
        save_depth_map(tmp_path, f.name, room.depth(i))
    config = TSDFConfig(depth_max=6.0)
    frame = filtered_depth(room, tmp_path, FilterConfig(), config)(3)
    kept = frame.depth_m > 0
    assert np.allclose(frame.weight[kept], 2.0 / frame.depth_m[kept]) and not frame.weight[~kept].any()
    both = filtered_depth(room, tmp_path, FilterConfig(weights=True), config)(3)
    score_only = filtered_depth(room, tmp_path, FilterConfig(weights=True, near_weight_m=0.0), config)(3)
    assert np.allclose(both.weight, score_only.weight * frame.weight)
    assert filtered_depth(room, "gt", FilterConfig(), config)(3).weight is None
    assert filtered_depth(room, "gt", FilterConfig(checks=("edges",)), config)(3).weight is None
    with pytest.raises(ReconError, match="near-weight-m"):
        FilterConfig(near_weight_m=-1.0).validate()


def test_near_views_move_the_fused_surface_more_than_far_ones():
    """A wall 1 m in front of one camera and 3 m in front of another, which sees it 8 cm too far: weighed by
    nearness, the fused wall lies about three times nearer the near camera's reading than the far one's;
    unweighted, halfway (the TSDF averages the two readings)."""
    K = Intrinsics(fx=160.0, fy=160.0, cx=63.5, cy=47.5, width=128, height=96)
    frames = []
    for name, distance, reading in (("near", 1.0, 1.0), ("far", 3.0, 3.08)):
        pose = np.eye(4)
        pose[2, 3] = 1.0 - distance  # both look down +z at the wall z = 1
        frames.append(Frame(name=name, camera_to_world=pose, image_array=np.full((96, 128, 3), 128, np.uint8),
                            depth_array=np.full((96, 128), reading, np.float32)))
    scan = Scan(K, frames, ScanMetadata())
    config = TSDFConfig(voxel_size=0.02, trunc_voxels=6, depth_max=4.0)  # a 12 cm band holds both readings

    def wall_z(near_weight_m: float) -> float:
        source = DepthFilter(scan, lambda i: DepthMap(scan.depth(i)), FilterConfig(checks=(), near_weight_m=near_weight_m),
                             (config.depth_min, config.depth_max))
        mesh = fuse_scan(scan, source, config, cleanup=None)
        centre = np.abs(mesh.vertices[:, :2]).max(axis=1) < 0.2
        return float(np.median(mesh.vertices[centre, 2]))

    assert wall_z(0.0) == pytest.approx(1.04, abs=0.003)
    assert wall_z(2.0) == pytest.approx(1.0196, abs=0.003)  # weights 2 / 1 and 2 / 3.08


def test_config_checks():
    assert parse_checks("none") == () and parse_checks("consistency, edges") == ("consistency", "edges")
    with pytest.raises(ReconError, match="unknown depth filter check"):
        FilterConfig(checks=("bogus",)).validate()
    with pytest.raises(ReconError, match="photometric"):
        FilterConfig(checks=("photometric",)).validate()
    with pytest.raises(ReconError, match="min views"):
        FilterConfig(views=2, min_views=3).validate()


def test_photometric_check_drops_views_that_see_another_colour(room):
    """Right geometry, but one frame's image is inverted: with the photometric check its views stop agreeing."""
    frames = list(room.frames)
    frames[CORRUPTED] = Frame(name=frames[CORRUPTED].name, camera_to_world=frames[CORRUPTED].camera_to_world,
                              image_array=255 - room.image(CORRUPTED), depth_array=room.depth(CORRUPTED))
    scan = Scan(room.intrinsics, frames, room.metadata)
    source = lambda i: DepthMap(scan.depth(i))  # noqa: E731
    plain = DepthFilter(scan, source, FilterConfig(), (0.1, 6.0))(CORRUPTED)
    photo = DepthFilter(scan, source, FilterConfig(checks=("consistency", "photometric"), max_color_diff=0.3),
                        (0.1, 6.0))(CORRUPTED)
    assert (plain.depth_m > 0).mean() > 0.9 and (photo.depth_m > 0).mean() < 0.5


def test_recon_fuse_filters_predicted_depth_by_default(room, tmp_path, capsys):
    scan_dir = tmp_path / "scan"
    save_scan(room, scan_dir)
    pred = tmp_path / "pred"
    _save_with_floating_frames(room, pred)
    common = [str(scan_dir), "--depth", str(pred), "--depth-max", "6", "--quiet"]
    assert main(["fuse", *common, "--out", str(tmp_path / "filtered.ply")]) == 0
    assert "filter consistency,edges kept" in capsys.readouterr().out
    assert main(["fuse", *common, "--out", str(tmp_path / "raw.ply"), "--filter", "none"]) == 0
    assert "filter none kept 100.0%" in capsys.readouterr().out
    assert main(["fuse", str(scan_dir), "--depth", "gt", "--depth-max", "6", "--out", str(tmp_path / "gt.ply")]) == 0
    assert "filter none" in capsys.readouterr().out  # auto: a scan's own depth is not filtered
    cfg = MeshEvalConfig(n_points=50_000)
    filtered, raw = (mesh_metrics(tmp_path / f"{n}.ply", box_room_mesh(), scan=room, config=cfg)
                     for n in ("filtered", "raw"))
    assert filtered["prec"] > raw["prec"] + 0.1
    assert main(["fuse", *common, "--out", str(tmp_path / "x.ply"), "--filter", "edges,bogus"]) == 2
    assert "unknown depth filter check 'bogus'" in capsys.readouterr().err
    assert not (tmp_path / "x.ply").exists()


def test_auto_filters_network_depth_only(tmp_path):
    """--filter auto: the network's (or a user's) depth is filtered; the plane sweep's, already checked against
    its sources, and a scan's own are not; checks given are kept."""
    import json as _json

    auto = FilterConfig()
    assert auto.checks is None and parse_checks("auto") is None
    for mode, checks in (("planesweep", ()), ("hybrid", ()), ("estm", ("consistency", "edges"))):
        (tmp_path / mode).mkdir()
        (tmp_path / mode / "depth.json").write_text(_json.dumps({"mode": mode}))
        assert auto.for_depth(tmp_path / mode).checks == checks
    assert auto.for_depth(tmp_path).checks == ("consistency", "edges")  # a folder of the user's own
    assert auto.for_depth("gt").checks == ()
    assert FilterConfig(checks=("edges",)).for_depth(tmp_path / "planesweep").checks == ("edges",)


def test_run_reports_the_filter(tmp_path):
    """`recon run` filters the network's depth by default and report.json says how much it kept and how long
    it took."""
    from apps.pipeline import InputConfig, Pipeline, RunConfig
    from recon.synthetic import SynthConfig, write_synthetic_scan

    room = write_synthetic_scan(SynthConfig(seed=3, frames=10, width=64, height=48, fps=4.0), tmp_path / "room")
    pipeline = Pipeline(RunConfig(InputConfig(str(room)), str(tmp_path / "run"), fusion=TSDFConfig(device="cpu")))
    pipeline.run(until="fusion")
    report = pipeline.summary()  # what the report stage writes to report.json
    flt = report["filter"]
    assert flt["checks"] == ["consistency", "edges"] and flt["frames"] == report["stages"]["scan"]["keyframes"]
    assert flt["near_weight_m"] == 2.0  # the network's depth is weighed by nearness
    assert 0 < flt["kept_share"] < 1 and flt["kept_pixels"] < flt["valid_pixels"] and flt["seconds"] > 0
    assert sum(flt["dropped"].values()) == flt["valid_pixels"] - flt["kept_pixels"]
    from apps.report import summary_cards

    cards = {c["label"]: c["value"] for c in summary_cards(report, 10, flt["frames"], True, None)}
    assert cards["depth filter (consistency, edges)"].startswith(f"kept {flt['kept_share']:.0%} of the pixels in ")
    state = json.loads((tmp_path / "run" / "run.json").read_text())
    assert state["config"]["depth_filter"]["checks"] is None  # auto, settled by the depth source
