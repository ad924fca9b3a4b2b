"""Scale for SfM scans: normalisation, --scale, --known-distance, Sim(3) to a reference; depth ranges."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from poses.scale import ScaleConfig, frame_depth_ranges, resolve_scale, transform_scan
from recon.errors import ReconError
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

RNG = np.random.default_rng(3)


def make_scan(n: int = 8, metric: bool = False) -> Scan:
    frames = []
    for i in range(n):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_euler("y", 5 * i, degrees=True).as_matrix()
        pose[:3, 3] = [0.3 * i, 0.05 * np.sin(i), 0.1 * i]
        frames.append(Frame(name=f"{i:06d}", camera_to_world=pose))
    return Scan(Intrinsics(500, 500, 319.5, 239.5, 640, 480), frames, ScanMetadata(metric_scale=metric))


def depths_for(scan: Scan, median: float) -> dict[str, np.ndarray]:
    return {name: RNG.uniform(0.5, 1.5, 200) * median for name in scan.names}


def test_default_normalisation_puts_median_depth_at_target_and_is_not_metric():
    scan = make_scan()
    depths = depths_for(scan, median=7.0)
    out, result = resolve_scale(scan, depths, ScaleConfig(target_median_depth=2.0))
    all_depths = np.concatenate(list(depths.values()))
    assert result.method == "normalised" and not result.metric and not out.metadata.metric_scale
    assert result.factor == pytest.approx(2.0 / np.median(all_depths))
    np.testing.assert_allclose(out.camera_to_world[:, :3, 3], scan.camera_to_world[:, :3, 3] * result.factor)
    np.testing.assert_allclose(out.camera_to_world[:, :3, :3], scan.camera_to_world[:, :3, :3])
    near, far = out.metadata.depth_range
    assert near < 2.0 < far and far < 4.0  # depths span 0.5-1.5 x median, plus the margin
    assert set(out.metadata.extra["frame_depth_ranges"]) == set(scan.names)
    assert out.metadata.extra["scale"]["method"] == "normalised"
    # The input scan is untouched.
    assert not scan.metadata.extra


def test_factor_and_known_distance_are_metric():
    scan = make_scan()
    depths = depths_for(scan, 1.0)
    out, result = resolve_scale(scan, depths, ScaleConfig(factor=0.25))
    assert result.metric and out.metadata.metric_scale
    np.testing.assert_allclose(out.frames[3].camera_to_world[:3, 3], 0.25 * scan.frames[3].camera_to_world[:3, 3])
    units = np.linalg.norm(scan.frames[5].camera_to_world[:3, 3] - scan.frames[1].camera_to_world[:3, 3])
    out, result = resolve_scale(scan, depths, ScaleConfig(known_distance=("000001", "000005", 2.0)))
    assert result.factor == pytest.approx(2.0 / units)
    got = np.linalg.norm(out.frames[5].camera_to_world[:3, 3] - out.frames[1].camera_to_world[:3, 3])
    assert got == pytest.approx(2.0)


def test_reference_alignment_recovers_a_known_similarity():
    truth = make_scan(metric=True)
    s, rot = 0.37, Rotation.from_euler("xyz", [10, -40, 75], degrees=True).as_matrix()
    t = np.array([1.0, -2.0, 0.5])
    # The "SfM" scan is the truth seen through an unknown similarity, as COLMAP's would be.
    sfm = transform_scan(truth, s, rot, t)
    out, result = resolve_scale(sfm, depths_for(sfm, 1.0), reference=truth)
    assert result.method == "reference" and result.metric and result.matched_frames == len(truth)
    assert result.factor == pytest.approx(1 / s)
    assert result.alignment_rmse < 1e-9
    np.testing.assert_allclose(out.camera_to_world, truth.camera_to_world, atol=1e-9)


def test_bad_scale_requests():
    scan = make_scan()
    depths = depths_for(scan, 1.0)
    with pytest.raises(ReconError, match="one way"):
        resolve_scale(scan, depths, ScaleConfig(factor=2.0, known_distance=("000001", "000002", 1.0)))
    with pytest.raises(ReconError, match="positive"):
        resolve_scale(scan, depths, ScaleConfig(factor=-1.0))
    with pytest.raises(ReconError, match="not among"):
        resolve_scale(scan, depths, ScaleConfig(known_distance=("000001", "nope", 1.0)))
    other = make_scan()
    for f in other.frames:
        f.name = "x" + f.name
    with pytest.raises(ReconError, match="shares only 0"):
        resolve_scale(scan, depths, reference=other)
    with pytest.raises(ReconError, match="no triangulated points"):
        resolve_scale(scan, {n: np.zeros(0) for n in scan.names})


def test_frame_depth_ranges_use_percentiles_with_margin_and_fall_back_when_sparse():
    depths = {"a": np.linspace(1.0, 3.0, 1001), "b": np.array([2.0, 2.5])}
    cfg = ScaleConfig(depth_percentiles=(10.0, 90.0), depth_margin=0.25, min_points=20)
    ranges, overall = frame_depth_ranges(depths, cfg)
    assert ranges["a"] == pytest.approx([1.2 / 1.25, 2.8 * 1.25])
    assert ranges["b"] == pytest.approx(list(overall))  # two points are not enough to trust
