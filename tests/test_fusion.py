import numpy as np
import pytest
import trimesh

from fusion.evaluate import MeshEvalConfig, mesh_metrics
from fusion.mesh import MeshCleanup, clean_mesh, load_mesh, save_mesh
from fusion.tsdf import TSDFConfig, TSDFIntegrator, fuse_scan
from recon.errors import ReconError
from recon.io import save_depth_map

from fixtures.box_room import box_room_mesh, box_room_scan


@pytest.fixture(scope="module")
def room():
    return box_room_scan(24, 128, 96)


def test_fused_gt_depth_matches_exact_room(room):
    mesh = fuse_scan(room, "gt", TSDFConfig(voxel_size=0.04, depth_max=6.0))
    r = mesh_metrics(mesh, box_room_mesh(), scan=room, config=MeshEvalConfig(n_points=100_000))
    assert r["fscore"] > 0.95 and r["acc"] < 0.02, r
    # Vertex colors come from the images (the room texture is never pure black or white).
    colors = mesh.visual.vertex_colors[:, :3]
    assert 40 < colors.mean() < 220 and colors.std() > 10


def test_predicted_depth_folder_with_confidence_and_lower_resolution(room, tmp_path):
    for i, f in enumerate(room.frames):
        depth = room.depth(i)[::2, ::2]  # half resolution: fusion resizes color and intrinsics to match
        conf = np.ones_like(depth)
        conf[:, : depth.shape[1] // 2] = 0.1  # the left half is untrusted
        save_depth_map(tmp_path, f.name, depth, conf)
    full = fuse_scan(room, tmp_path, TSDFConfig(depth_max=6.0))
    assert mesh_metrics(full, box_room_mesh(), scan=room, config=MeshEvalConfig(n_points=50_000))["fscore"] > 0.9
    one = room.subset([0])  # a single view: masking its left half must remove about half of what it sees
    whole = fuse_scan(one, tmp_path, TSDFConfig(depth_max=6.0))
    masked = fuse_scan(one, tmp_path, TSDFConfig(depth_max=6.0, min_confidence=0.5))
    assert 0.3 * whole.area < masked.area < 0.7 * whole.area


def test_depth_range_is_respected(room):
    with pytest.raises(ReconError, match="empty mesh"):
        fuse_scan(room, "gt", TSDFConfig(depth_min=0.1, depth_max=0.3))
    with pytest.raises(ReconError, match="invalid depth range"):
        TSDFIntegrator(TSDFConfig(depth_min=2, depth_max=1))


def test_gt_depth_required(room):
    no_depth = room.subset(range(3))
    no_depth.frames = [type(f)(name=f.name, camera_to_world=f.camera_to_world, image_array=f.image_array)
                       for f in no_depth.frames]
    with pytest.raises(ReconError, match="has no ground-truth depth"):
        fuse_scan(no_depth, "gt")


def test_cleanup_drops_small_pieces():
    big = trimesh.creation.box(extents=(2, 2, 2))
    small = trimesh.creation.box(extents=(0.05, 0.05, 0.05)).apply_translation((5, 0, 0))
    cleaned = clean_mesh(trimesh.util.concatenate([big, small]), MeshCleanup(min_component_area=0.05))
    assert len(cleaned.faces) == len(big.faces) and cleaned.bounds[1][0] < 1.5


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".glb"])
def test_export_formats(tmp_path, suffix):
    mesh = trimesh.creation.icosphere()
    path = save_mesh(mesh, tmp_path / f"m{suffix}")
    back = load_mesh(path)
    assert len(back.faces) == len(mesh.faces)
    assert [p.name for p in tmp_path.iterdir()] == [f"m{suffix}"]  # no temporary left behind


def test_bad_mesh_files(tmp_path):
    with pytest.raises(ReconError, match="unsupported mesh format"):
        save_mesh(trimesh.creation.icosphere(), tmp_path / "m.xyz")
    (tmp_path / "empty.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(ReconError):
        load_mesh(tmp_path / "empty.ply")
    with pytest.raises(ReconError, match="not found"):
        load_mesh(tmp_path / "missing.ply")
