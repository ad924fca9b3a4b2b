"""Every metric on a case with a known answer."""
import dataclasses

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from depth.metrics import depth_edges, depth_metrics, edge_counts, edge_scores, evaluate_depth_folder, flicker
from fusion.evaluate import MeshEvalConfig, mesh_metrics
from poses.evaluate import pose_metrics, umeyama
from recon.io import save_depth_map
from recon.scan import Frame, Intrinsics, Scan

from fixtures.box_room import box_room_mesh, box_room_scan, look_at


def plane(size=10.0, z=0.0):
    return trimesh.creation.box(extents=(size, size, 1e-4)).apply_translation((0, 0, z))


# -- mesh --------------------------------------------------------------------------------------

def test_identical_meshes_score_perfectly():
    m = box_room_mesh()
    r = mesh_metrics(m, m)
    assert r["acc"] == 0 and r["comp"] == 0 and r["fscore"] == 1.0 and r["pred_points"] == 200_000


def test_shifted_plane_gives_the_shift_as_accuracy():
    cfg = MeshEvalConfig(n_points=50_000)
    r = mesh_metrics(plane(z=0.03), plane(), config=cfg)
    # The box is two 0.1 mm-apart sheets: every point sits within ~0.1 mm of 3 cm from the other mesh.
    assert r["acc"] == pytest.approx(0.03, abs=0.002) and r["comp"] == pytest.approx(0.03, abs=0.002)
    assert r["fscore"] == 1.0  # under the 5 cm threshold
    far = mesh_metrics(plane(z=0.07), plane(), config=cfg)
    assert far["fscore"] == 0.0 and far["acc"] == pytest.approx(0.07, abs=0.002)
    capped = mesh_metrics(plane(z=3.0), plane(), config=cfg)
    assert capped["acc"] == pytest.approx(1.0)  # distances are capped at 1 m


def test_partial_mesh_lowers_completeness_not_accuracy():
    full = box_room_mesh().subdivide().subdivide().subdivide()
    half = full.submesh([full.triangles_center[:, 0] < 0], append=True)
    r = mesh_metrics(half, full, config=MeshEvalConfig(n_points=50_000))
    assert r["acc"] < 0.03 and r["prec"] > 0.99  # point-to-point: ~2 cm spacing at 50k points
    assert r["recall"] < 0.75 and r["comp"] > 0.1


def test_visibility_culling_ignores_unseen_parts():
    """Cameras that see only some walls: a mesh missing the unseen walls still scores ~1 with the scan."""
    scan = box_room_scan(6, 64, 48)
    full = box_room_mesh()
    cfg = MeshEvalConfig(n_points=50_000)
    seen_by_all = trimesh.Trimesh(*_seen_faces(full, scan))
    assert mesh_metrics(seen_by_all, full, config=cfg)["recall"] < 0.9
    culled = mesh_metrics(seen_by_all, full, scan=scan, config=cfg)
    assert culled["recall"] > 0.97 and culled["gt_points"] < 50_000


def _seen_faces(mesh, scan):
    from fusion.evaluate import visible_mask

    sub = mesh.subdivide().subdivide().subdivide()
    keep = visible_mask(sub.triangles_center, scan, MeshEvalConfig())
    return sub.vertices, sub.faces[keep]


# -- depth -------------------------------------------------------------------------------------

def test_depth_metrics_known_values():
    gt = np.full((4, 4), 2.0, np.float32)
    assert depth_metrics(gt, gt)["abs_rel"] == 0 and depth_metrics(gt, gt)["a1"] == 1
    m = depth_metrics(gt * 1.1, gt)
    assert m["abs_rel"] == pytest.approx(0.1, rel=1e-5) and m["abs"] == pytest.approx(0.2, rel=1e-5)
    assert m["rmse"] == pytest.approx(0.2, rel=1e-5) and m["sq_rel"] == pytest.approx(0.02, rel=1e-5)
    assert m["rmse_log"] == pytest.approx(np.log(1.1), rel=1e-5) and m["a1"] == 1.0
    assert m["median_ratio"] == pytest.approx(1.1, rel=1e-5)
    assert m["within_5cm"] == 0.0  # 20 cm off at 2 m: right by δ<1.25, not for a surface
    near = gt.copy()
    near[:, :1] += 0.04
    near[:, 1:2] -= 0.06
    assert depth_metrics(near, gt)["within_5cm"] == 0.75 and depth_metrics(near, gt)["a1"] == 1.0
    assert depth_metrics(near, gt)["near_5cm"] == 0.25  # the column 6 cm too near; 4 cm too far is within
    assert depth_metrics(gt * 0.9, gt)["near_5cm"] == 1.0 and m["near_5cm"] == 0.0  # 20 cm too near; 20 cm too far
    m = depth_metrics(gt * 1.5, gt)
    assert m["a1"] == 0 and m["a2"] == 1
    pred = gt.copy()
    pred[0] = 0  # a missing prediction is not a free pass
    m = depth_metrics(pred, gt)
    assert m["coverage"] == 0.75 and m["abs_rel"] > 0.2
    assert m["median_ratio"] == 1.0  # the scale bias of the covered pixels only
    gt_far = gt.copy()
    gt_far[:2] = 20.0  # outside the evaluation range: ignored
    assert depth_metrics(gt, gt_far, max_depth=10.0)["abs_rel"] == 0


def test_flicker_zero_for_consistent_depth_and_positive_otherwise():
    scan = box_room_scan(16, 64, 48)
    K = scan.intrinsics.K
    a, b = scan.depth(0), scan.depth(1)
    pa, pb = scan.frames[0].camera_to_world, scan.frames[1].camera_to_world
    assert flicker(a, b, K, pa, pb, a, b) < 0.005
    noisy = b * np.float32(1.05)
    assert flicker(a, noisy, K, pa, pb, a, b) == pytest.approx(0.05 / 1.05, rel=0.15)


def test_evaluate_depth_folder(tmp_path):
    scan = box_room_scan(8, 64, 48)
    for i, f in enumerate(scan.frames):
        save_depth_map(tmp_path, f.name, scan.depth(i) * (1.2 if i % 2 else 1.0))
    r = evaluate_depth_folder(tmp_path, scan)
    assert r["frames"] == 8 and r["abs_rel"] == pytest.approx(0.1, rel=1e-3)
    assert r["mae_std"] > 0 and r["flicker"] > 0.1
    assert np.isnan(r["edge_f"])  # a bare box room has no occluding edge: no score, not a perfect one
    r = evaluate_depth_folder(tmp_path, scan, align="median")
    assert r["abs_rel"] < 1e-3


def _step(columns=40, at=20, near=1.0, far=2.0):
    d = np.full((30, columns), far, np.float32)
    d[:, :at] = near  # a box in front of a wall: one occluding edge
    return d


def test_edges_found_at_the_jump_not_on_a_slant():
    valid = np.ones((30, 40), bool)
    edges = depth_edges(_step(), valid)
    assert edges.sum() == 60 and edges[:, 19].all() and edges[:, 20].all()
    slant = np.tile(np.linspace(1.0, 2.0, 40, dtype=np.float32), (30, 1))  # 1.8 % per pixel: a wall seen obliquely
    assert not depth_edges(slant, valid).any()
    hidden = valid.copy()
    hidden[:, 20] = False
    assert not depth_edges(_step(), hidden).any()  # no valid pair straddles the jump


def test_edge_scores_reward_sharp_and_close_edges_only():
    gt, valid = _step(), np.ones((30, 40), bool)
    assert edge_scores([edge_counts(gt, gt, valid)])["edge_f"] == pytest.approx(1.0)
    assert edge_scores([edge_counts(_step(at=21), gt, valid)])["edge_f"] == pytest.approx(1.0)  # 1 px off: found
    far = edge_scores([edge_counts(_step(at=26), gt, valid)])
    assert far["edge_precision"] == 0 and far["edge_f"] == 0  # 6 px off: a wrong edge
    blurred = gt.copy()
    blurred[:, 14:26] = np.linspace(1.0, 2.0, 12)  # the same jump spread over 12 px: no edge at all
    blob = edge_scores([edge_counts(blurred, gt, valid)])
    assert blob["edge_recall"] == 0 and np.isnan(blob["edge_precision"])


# -- poses -------------------------------------------------------------------------------------

def _traj(n=20, seed=0):
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        eye = np.array([np.cos(i / 5), 0.1 * i, np.sin(i / 3)]) + rng.normal(scale=0.01, size=3)
        frames.append(Frame(name=f"{i:06d}", camera_to_world=look_at(eye, eye + [0, 0, 1])))
    return Scan(Intrinsics(100, 100, 50, 50, 100, 100), frames)


def test_similarity_transformed_trajectory_has_zero_ate():
    gt = _traj()
    R = Rotation.from_euler("xyz", [0.3, -1.0, 2.0]).as_matrix()
    pred_frames = []
    for f in gt.frames:
        pose = np.eye(4)
        pose[:3, :3] = R @ f.camera_to_world[:3, :3]
        pose[:3, 3] = 0.37 * R @ f.camera_to_world[:3, 3] + [5, -2, 1]
        pred_frames.append(Frame(name=f.name, camera_to_world=pose))
    pred = Scan(gt.source_intrinsics, pred_frames)
    r = pose_metrics(pred, gt)
    assert r["ate_rmse"] < 1e-9 and r["registered"] == 1.0
    assert r["scale"] == pytest.approx(1 / 0.37)
    rigid = pose_metrics(pred, gt, with_scale=False)
    assert rigid["ate_rmse"] > 0.1


def test_partial_registration_and_known_error():
    gt = _traj()
    pred = gt.subset(range(0, 20, 2))
    moved = pred.frames[0].camera_to_world.copy()
    moved[0, 3] += 0.5
    pred.frames[0] = dataclasses.replace(pred.frames[0], camera_to_world=moved)
    r = pose_metrics(pred, gt)
    assert r["registered"] == 0.5 and 0.05 < r["ate_rmse"] < 0.5


def test_umeyama_recovers_similarity():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(50, 3))
    R = Rotation.random(random_state=5).as_matrix()
    s, R2, t = umeyama(src, 2.5 * src @ R.T + [1, 2, 3])
    assert s == pytest.approx(2.5) and np.allclose(R2, R) and np.allclose(t, [1, 2, 3])


def test_sampling_ignores_face_and_corner_order():
    """Open3D may store the same surface in another order; the protocol's points must not change."""
    from fusion.evaluate import sample_points

    mesh = box_room_mesh().subdivide().subdivide()
    faces = np.roll(mesh.faces[np.random.default_rng(0).permutation(len(mesh.faces))], 1, axis=1)
    shuffled = trimesh.Trimesh(mesh.vertices, faces, process=False)
    assert np.array_equal(sample_points(mesh, 5000, 3), sample_points(shuffled, 5000, 3))
    assert not np.array_equal(sample_points(mesh, 5000, 3), sample_points(mesh, 5000, 4))
