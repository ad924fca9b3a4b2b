"""End to end on exact ground truth: fusing a synthetic scan's GT depth with its GT poses rebuilds gt_mesh.ply."""
import pytest

from fusion.evaluate import MeshEvalConfig, mesh_metrics
from fusion.tsdf import TSDFConfig, fuse_scan
from recon.synthetic import SynthConfig, render_scan


def _fused_metrics(seed: int) -> dict:
    # A 15 s walk sampled at 6 fps (every 5th video frame): the keyframes fusion would use.
    scan, gt_mesh = render_scan(SynthConfig(seed=seed, frames=90, width=320, height=256, fps=6.0))
    # Depth range from the scan, so distant walls of big rooms are fused too. min_weight 0.5 meshes
    # surfaces seen by a single frame: Open3D keeps voxels whose weight is strictly above the threshold.
    config = TSDFConfig(device="cpu", depth_max=float(scan.metadata.depth_range[1]) + 0.1, min_weight=0.5)
    mesh = fuse_scan(scan, depth="gt", config=config)
    # "Observed" = in some camera's view and at most 3 cm behind its (exact) depth. The protocol's
    # default 10 cm margin, meant for noisy depth, also counts never-seen crevices such as the
    # 2 mm gaps between books on a shelf.
    return mesh_metrics(mesh, gt_mesh, scan=scan, config=MeshEvalConfig(occlusion_margin=0.03))


@pytest.mark.parametrize("seed", [1, 3])  # an L-shaped room and two rooms with a doorway
def test_fused_gt_depth_matches_gt_mesh(seed):
    metrics = _fused_metrics(seed)
    assert metrics["gt_points"] > 20000  # the walk saw a good part of the room
    assert metrics["fscore"] >= 0.95
    assert metrics["acc"] < 0.03 and metrics["comp"] < 0.03


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(8))
def test_fused_gt_depth_matches_gt_mesh_many_rooms(seed):
    assert _fused_metrics(seed)["fscore"] >= 0.95
