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


def _voxels(integrator):
    """(voxel keys sorted, tsdf, weight, color) of every allocated voxel, in a canonical order."""
    xyz, index = integrator.grid.voxel_coordinates_and_flattened_indices()
    index = index.numpy().ravel()
    keys = np.round(xyz.numpy() / integrator.config.voxel_size).astype(np.int64)
    order = np.lexsort(keys.T)
    attrs = [integrator.grid.attribute(n).numpy().reshape(-1, c)[index][order] for n, c in
             (("tsdf", 1), ("weight", 1), ("color", 3))]
    return keys[order], *attrs


def test_per_pixel_weights_of_one_reproduce_open3d_integration(room):
    """The weighted update is Open3D's own with the weight 1 replaced: same voxels, distances and colours."""
    config = TSDFConfig(depth_max=6.0, device="cpu")
    native, weighted = TSDFIntegrator(config), TSDFIntegrator(config)
    for i in range(0, len(room), 3):
        args = (room.depth(i), room.image(i), room.intrinsics, room.frames[i].camera_to_world)
        native.integrate(*args)
        weighted.integrate(*args, weight=np.ones_like(room.depth(i)))
    (ka, ta, wa, ca), (kb, tb, wb, cb) = _voxels(native), _voxels(weighted)
    assert np.array_equal(ka, kb) and wa.sum() > 10_000
    assert np.mean(wa == wb) > 0.9999  # a voxel on a pixel boundary may fall either way in float32
    seen = ((wa > 0) & (wb > 0)).ravel()
    assert np.mean(np.abs(ta - tb).ravel()[seen] < 1e-4) > 0.999
    assert np.mean(np.abs(ca - cb).max(1)[seen] < 1e-2) > 0.999
    assert len(native.extract_mesh().faces) == len(weighted.extract_mesh().faces)


def test_per_pixel_weights_scale_what_a_view_contributes(room):
    one = room.subset([0])
    config = TSDFConfig(depth_max=6.0, device="cpu")
    full = TSDFIntegrator(config)
    full.integrate(one.depth(0), one.image(0), one.intrinsics, one.frames[0].camera_to_world, weight=None)
    half = TSDFIntegrator(config)
    weight = np.full(one.depth(0).shape, 2.0, np.float32)
    weight[:, : weight.shape[1] // 2] = 0.0  # the left half counts nothing
    half.integrate(one.depth(0), one.image(0), one.intrinsics, one.frames[0].camera_to_world, weight=weight)
    wf, wh = _voxels(full)[2], _voxels(half)[2]
    assert set(np.unique(wh)) <= {0.0, 2.0} and 0.3 < (wh > 0).sum() / (wf > 0).sum() < 0.7
    assert 0.3 * full.extract_mesh().area < half.extract_mesh().area < 0.7 * full.extract_mesh().area
