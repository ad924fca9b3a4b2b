import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon.errors import ReconError
from recon.geometry import (backproject, check_pose, invert_pose, mark_neighbour_pairs, opencv_to_opengl,
                            opengl_to_opencv, project,
                            quaternion_to_rotation, reproject_depth, transform_points, world_to_camera_to_pose)

from fixtures.box_room import box_room_scan, look_at, room_depth


def random_pose(rng):
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    pose[:3, 3] = rng.normal(size=3)
    return pose


def test_invert_pose_is_exact_inverse():
    rng = np.random.default_rng(0)
    pose = random_pose(rng)
    assert np.allclose(invert_pose(pose) @ pose, np.eye(4), atol=1e-12)
    batch = np.stack([random_pose(rng) for _ in range(5)])
    assert np.allclose(invert_pose(batch) @ batch, np.eye(4), atol=1e-12)


def test_opengl_round_trip_and_axes():
    rng = np.random.default_rng(1)
    pose = random_pose(rng)
    assert np.allclose(opencv_to_opengl(opengl_to_opencv(pose)), pose)
    # An OpenGL camera looks down its -z; in OpenCV axes the same camera looks down +z.
    gl = np.eye(4)
    cv = opengl_to_opencv(gl)
    assert np.allclose(cv[:3, 2], [0, 0, -1]) and np.allclose(cv[:3, 1], [0, -1, 0])


def test_world_to_camera_conversion_matches_projection():
    rng = np.random.default_rng(2)
    R = Rotation.random(random_state=3).as_matrix()
    t = rng.normal(size=3)
    c2w = world_to_camera_to_pose(R, t)
    world_pt = rng.normal(size=3)
    # COLMAP: x_cam = R x_world + t; our pose maps camera points back to the world.
    cam_pt = R @ world_pt + t
    assert np.allclose(transform_points(c2w, cam_pt[None])[0], world_pt)


def test_quaternion_matches_scipy():
    q = Rotation.random(random_state=4).as_quat()  # x, y, z, w
    assert np.allclose(quaternion_to_rotation(q[3], q[0], q[1], q[2]), Rotation.from_quat(q).as_matrix())


def test_check_pose_rejects_bad_matrices():
    with pytest.raises(ReconError, match="shape"):
        check_pose(np.eye(3), "f")
    bad = np.eye(4)
    bad[0, 0] = np.nan
    with pytest.raises(ReconError, match="NaN"):
        check_pose(bad, "f")
    sheared = np.eye(4)
    sheared[0, 1] = 0.3
    with pytest.raises(ReconError, match="rigid"):
        check_pose(sheared, "f")


def test_backproject_project_round_trip():
    scan = box_room_scan(1)
    K = scan.intrinsics.K
    depth = scan.depth(0)
    uv, z = project(backproject(depth, K), K)
    v, u = np.mgrid[: depth.shape[0], : depth.shape[1]]
    assert np.allclose(uv[..., 0], u) and np.allclose(uv[..., 1], v) and np.allclose(z, depth)


def test_reproject_depth_agrees_with_exact_depth_of_other_view():
    scan = box_room_scan(2, 128, 96)
    intr = scan.intrinsics
    a = look_at([0, 0, 0], [0.2, 0.1, 1])
    b = look_at([0.3, -0.1, 0.2], [0.1, 0.0, 1.5])
    warped = reproject_depth(room_depth(intr, a), intr.K, a, b)
    exact = room_depth(intr, b)
    both = warped > 0
    assert both.mean() > 0.5
    rel = np.abs(warped[both] - exact[both]) / exact[both]
    assert np.median(rel) < 1e-3


def test_mark_neighbour_pairs_marks_both_pixels_of_each_flagged_pair():
    values = np.zeros((4, 5))
    values[2, 3] = 1.0  # differs from its four neighbours only
    marked = mark_neighbour_pairs(lambda lo, hi: values[lo] != values[hi], values.shape)
    expected = np.zeros((4, 5), bool)
    expected[2, 3] = expected[1, 3] = expected[3, 3] = expected[2, 2] = expected[2, 4] = True
    assert np.array_equal(marked, expected)
    assert not mark_neighbour_pairs(lambda lo, hi: values[lo] > 5, values.shape).any()
