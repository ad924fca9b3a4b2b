"""Round trips of the pose conventions SfM and phone captures bring in: COLMAP world-to-camera
with pixel centres at +0.5, OpenGL camera axes, and Stray Scanner's ARKit quaternions."""
import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation

from recon.readers import stray
from recon.geometry import (invert_pose, opencv_to_opengl, opengl_to_opencv, project, transform_points,
                            world_to_camera_to_pose)

RNG = np.random.default_rng(7)


def random_pose(rng) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    pose[:3, 3] = rng.uniform(-3, 3, 3)
    return pose


def test_colmap_model_converts_to_poses_that_reproject_like_colmap(tmp_path):
    """Build a model with pycolmap, write it, read it back through the SfM conversion, and check
    that our K and camera-to-world put world points on the same pixels as COLMAP does."""
    from recon.readers.colmap import scan_from_reconstruction

    (tmp_path / "images").mkdir()
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_name(1, "PINHOLE", 500.0, 640, 480)
    cam.params = [510.0, 505.0, 321.3, 238.7]
    rec.add_camera_with_trivial_rig(cam)
    poses = {}
    for image_id in (1, 2, 3):
        cam_from_world = random_pose(RNG)
        rigid = pycolmap.Rigid3d(pycolmap.Rotation3d(cam_from_world[:3, :3]), cam_from_world[:3, 3])
        image = pycolmap.Image(name=f"{image_id:06d}.jpg", camera_id=1, image_id=image_id)
        rec.add_image_with_trivial_frame(image, rigid)
        (tmp_path / "images" / image.name).write_bytes(b"")
        poses[f"{image_id:06d}"] = cam_from_world
    rec.write(tmp_path)
    scan = scan_from_reconstruction(pycolmap.Reconstruction(tmp_path), tmp_path / "images")

    K = scan.intrinsics.K
    assert (scan.intrinsics.cx, scan.intrinsics.cy) == pytest.approx((320.8, 238.2))
    images = {im.name: im for im in pycolmap.Reconstruction(tmp_path).images.values()}
    for frame in scan.frames:
        # World points in front of the camera, placed with COLMAP's own world-to-camera pose.
        in_camera = np.column_stack([RNG.uniform(-1, 1, (50, 2)), RNG.uniform(1, 5, 50)])
        world = transform_points(invert_pose(poses[frame.name]), in_camera)
        ours, depth = project(transform_points(invert_pose(frame.camera_to_world), world), K)
        theirs = np.array([images[f"{frame.name}.jpg"].project_point(p) for p in world])
        np.testing.assert_allclose(depth, in_camera[:, 2], atol=1e-9)
        np.testing.assert_allclose(ours + 0.5, theirs, atol=1e-6)  # COLMAP's pixel centres sit at +0.5


def test_world_to_camera_round_trip():
    for _ in range(10):
        c2w = random_pose(RNG)
        w2c = invert_pose(c2w)
        np.testing.assert_allclose(world_to_camera_to_pose(w2c[:3, :3], w2c[:3, 3]), c2w, atol=1e-12)


def test_opengl_round_trip_and_axes():
    c2w = random_pose(RNG)
    np.testing.assert_allclose(opencv_to_opengl(opengl_to_opencv(c2w)), c2w, atol=1e-12)
    # A point on the OpenGL camera's -z axis (in front) is in front of the OpenCV camera (+z).
    gl = random_pose(RNG)
    ahead = transform_points(gl, np.array([0.0, 0.0, -2.0]))
    assert transform_points(invert_pose(opengl_to_opencv(gl)), ahead)[2] == pytest.approx(2.0)
    # OpenGL +y (up on screen) is OpenCV -y (image rows grow downwards).
    up = transform_points(gl, np.array([0.0, 1.0, -2.0]))
    assert transform_points(invert_pose(opengl_to_opencv(gl)), up)[1] == pytest.approx(-1.0)


def test_stray_odometry_matches_the_apps_arkit_conversion(tmp_path):
    """The app writes q_WA * q_AC (180 degrees about x) for ARKit's OpenGL-style camera: reading it back
    must give the OpenCV camera-to-world that sees ARKit's forward (-z) as +z."""
    arkit = random_pose(RNG)  # ARKit camera-to-world, OpenGL camera axes
    q_wa = Rotation.from_matrix(arkit[:3, :3])
    q = (q_wa * Rotation.from_quat([1.0, 0.0, 0.0, 0.0])).as_quat()  # scipy: x, y, z, w
    x, y, z = arkit[:3, 3]
    (tmp_path / "odometry.csv").write_text(
        "timestamp, frame, x, y, z, qx, qy, qz, qw\n"
        f"0.5, 3, {x}, {y}, {z}, {q[0]}, {q[1]}, {q[2]}, {q[3]}\n")
    [(index, timestamp, pose)] = stray.read_odometry(tmp_path / "odometry.csv")
    assert (index, timestamp) == (3, 0.5)
    np.testing.assert_allclose(pose, opengl_to_opencv(arkit), atol=1e-9)
