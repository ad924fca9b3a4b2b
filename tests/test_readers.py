"""Every reader returns the same canonical scan from its own layout, and real sequences reproject."""
import json

import cv2
import numpy as np
import pytest

from recon.readers import detect_format, open_scan
from recon.errors import ReconError
from recon.geometry import reprojection_disagreement

from fixtures.box_room import box_room_scan
from fixtures.format_writers import WRITERS

LOSSY = {"scannet"}  # writes JPEG


@pytest.fixture(scope="module")
def reference():
    return box_room_scan(16, 64, 48)


@pytest.mark.parametrize("fmt", sorted(WRITERS))
def test_reader_round_trip(fmt, reference, tmp_path):
    WRITERS[fmt](reference, tmp_path)
    assert detect_format(tmp_path) == fmt
    scan = open_scan(tmp_path)
    assert len(scan) == len(reference)
    assert scan.metadata.source_format == fmt
    assert scan.metadata.metric_scale == (fmt != "colmap")
    for a, b in zip(("fx", "fy", "cx", "cy", "width", "height"), ("fx", "fy", "cx", "cy", "width", "height")):
        assert getattr(scan.intrinsics, a) == pytest.approx(getattr(reference.intrinsics, b), abs=1e-6), a
    assert np.allclose(scan.camera_to_world, reference.camera_to_world, atol=1e-6)
    for i in range(len(scan)):
        img = scan.image(i).astype(int)
        tol = 8 if fmt in LOSSY else 0
        assert np.abs(img - reference.image(i)).mean() <= tol
        if fmt != "colmap":
            assert np.abs(scan.depth(i) - reference.depth(i)).max() < 1e-3


@pytest.mark.parametrize("fmt", sorted(set(WRITERS) - {"colmap"}))
def test_reader_poses_reproject_depth(fmt, reference, tmp_path):
    """Conventions check: depth of frame i seen from frame i+1 through the read poses agrees."""
    WRITERS[fmt](reference, tmp_path)
    scan = open_scan(tmp_path)
    for i in range(len(scan) - 1):
        rel = reprojection_disagreement(scan.depth(i), scan.depth(i + 1), scan.intrinsics.K,
                                        scan.frames[i].camera_to_world, scan.frames[i + 1].camera_to_world)
        assert len(rel) > 100 and np.median(rel) < 0.01


def test_colmap_text_model_and_distortion(reference, tmp_path):
    WRITERS["colmap"](reference, tmp_path, binary=False)
    scan = open_scan(tmp_path / "sparse/0/..")
    assert np.allclose(scan.camera_to_world, reference.camera_to_world, atol=1e-6)


def test_colmap_model_with_a_relative_image_folder_reads_its_images(reference, tmp_path, monkeypatch):
    """SfM hands its model over with the image folder as given (relative to the working directory):
    the frames must not be resolved against that folder a second time (recon bench poses --keep runs/x)."""
    import pycolmap

    from recon.readers.colmap import find_model, scan_from_reconstruction

    WRITERS["colmap"](reference, tmp_path)
    monkeypatch.chdir(tmp_path)
    model = find_model(tmp_path).relative_to(tmp_path)
    scan = scan_from_reconstruction(pycolmap.Reconstruction(str(model)), tmp_path.relative_to(tmp_path) / "images")
    assert np.abs(scan.image(0).astype(int) - reference.image(0)).mean() == 0


def test_nerfstudio_distortion_is_undone(reference, tmp_path):
    """A smooth pattern distorted with k1 reads back close to the pinhole original."""
    import cv2

    WRITERS["nerfstudio"](reference, tmp_path)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    k1 = -0.3
    doc["k1"] = k1
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    K = reference.intrinsics.K
    h, w = reference.intrinsics.height, reference.intrinsics.width
    v, u = np.mgrid[:h, :w].astype(np.float32)
    pattern = 128 + 100 * np.sin(2 * np.pi * u / 17) * np.cos(2 * np.pi * v / 13)
    img = np.repeat(pattern[..., None], 3, -1).astype(np.uint8)
    # Distorted pixel p shows the undistorted image at undistort(p).
    pts = cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], -1)[:, None], K, np.array([k1, 0, 0, 0.0]), P=K)
    distorted = cv2.remap(img, pts[:, 0, 0].reshape(h, w), pts[:, 0, 1].reshape(h, w), cv2.INTER_LINEAR)
    cv2.imwrite(str(tmp_path / doc["frames"][0]["file_path"]), cv2.cvtColor(distorted, cv2.COLOR_RGB2BGR))
    scan = open_scan(tmp_path)
    assert scan.distortion is not None and scan.distortion[0] == k1
    core = (slice(h // 6, 5 * h // 6), slice(w // 6, 5 * w // 6))
    err_fixed = np.abs(scan.image(0)[core].astype(int) - img[core]).mean()
    err_raw = np.abs(distorted[core].astype(int) - img[core]).mean()
    assert err_fixed < 0.3 * err_raw


def test_depth_camera_resampled_onto_color_camera(tmp_path):
    """Kinect-style: depth from a narrower, smaller camera at the same centre lands on the colour grid exactly."""
    from fixtures.box_room import room_depth
    from recon.scan import Intrinsics

    color = Intrinsics(52.5, 52.5, 31.5, 23.5, 64, 48)
    depth_cam = Intrinsics(47.0, 47.0, 25.0, 19.0, 50, 40)
    ref = box_room_scan(16, 64, 48)
    WRITERS["7scenes"](ref, tmp_path)
    np.savetxt(tmp_path / "color-intrinsics.txt", color.K)
    np.savetxt(tmp_path / "camera-intrinsics.txt", depth_cam.K)
    for i, f in enumerate(ref.frames):
        cv2.imwrite(str(tmp_path / f"frame-{i:06d}.depth.png"),
                    np.round(room_depth(depth_cam, f.camera_to_world) * 1000).astype(np.uint16))
    scan = open_scan(tmp_path)
    assert scan.intrinsics == color and scan.depth_intrinsics == depth_cam
    for i in (0, 5):
        got, exact = scan.depth(i), room_depth(color, ref.frames[i].camera_to_world)
        seen = got > 0
        assert 0.5 < seen.mean() < 0.95  # the depth camera sees less than the colour camera
        assert np.median(np.abs(got[seen] - exact[seen]) / exact[seen]) < 0.01


def test_sevenscenes_real_sequence(sevenscenes):
    scan = open_scan(sevenscenes)
    assert len(scan) == 1000 and scan.intrinsics.fx == 525 and scan.depth_intrinsics.fx == 585
    for i in (0, 400, 800):
        rel = reprojection_disagreement(scan.depth(i), scan.depth(i + 5), scan.intrinsics.K,
                                        scan.frames[i].camera_to_world, scan.frames[i + 5].camera_to_world)
        assert np.median(rel) < 0.02


def test_iclnuim_real_sequence(iclnuim):
    scan = open_scan(iclnuim)
    assert len(scan) == 211 and scan.intrinsics.cx == 319.5
    for i in (0, 100, 200):
        rel = reprojection_disagreement(scan.depth(i), scan.depth(i + 5), scan.intrinsics.K,
                                        scan.frames[i].camera_to_world, scan.frames[i + 5].camera_to_world)
        assert np.median(rel) < 0.02


# -- bad input --------------------------------------------------------------------------------

def test_unknown_and_missing(tmp_path):
    with pytest.raises(ReconError, match="no such file"):
        open_scan(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReconError, match="unknown scan format"):
        open_scan(tmp_path / "empty")
    with pytest.raises(ReconError, match="unknown format 'xyz'"):
        open_scan(tmp_path / "empty", "xyz")


def test_wrong_pose_shape(reference, tmp_path):
    WRITERS["7scenes"](reference, tmp_path)
    np.savetxt(tmp_path / "frame-000002.pose.txt", np.eye(3))
    with pytest.raises(ReconError, match=r"frame-000002.pose.txt: matrix has shape \(3, 3\)"):
        open_scan(tmp_path)


def test_non_rigid_pose(reference, tmp_path):
    WRITERS["simplerecon"](reference, tmp_path)
    rows = np.loadtxt(tmp_path / "poses.txt")
    rows[3, 0] = 2.0  # scales x
    np.savetxt(tmp_path / "poses.txt", rows)
    with pytest.raises(ReconError, match="frame 000003.*not a rigid"):
        open_scan(tmp_path)


def test_mismatched_counts(reference, tmp_path):
    WRITERS["open3d"](reference, tmp_path)
    (tmp_path / "image/00015.png").unlink()
    with pytest.raises(ReconError, match="15 images but 16 poses"):
        open_scan(tmp_path)


def test_empty_frames(tmp_path):
    (tmp_path / "transforms.json").write_text(json.dumps({"fl_x": 1, "frames": []}))
    with pytest.raises(ReconError, match="'frames' is empty"):
        open_scan(tmp_path)


ZERO_FOCAL = {  # format -> (intrinsics file, how to write a zero focal length into it)
    "7scenes": ("color-intrinsics.txt", lambda p: np.savetxt(p, np.diag([0.0, 0.0, 1.0]))),
    "scannet": ("intrinsic/intrinsic_color.txt", lambda p: np.savetxt(p, np.diag([0.0, 0.0, 1.0, 1.0]))),
    "tum": ("camera-intrinsics.txt", lambda p: np.savetxt(p, np.diag([0.0, 0.0, 1.0]))),
    "simplerecon": ("K.txt", lambda p: np.savetxt(p, np.diag([0.0, 0.0, 1.0]))),
    "open3d": ("camera_intrinsic.json", lambda p: p.write_text(json.dumps({"intrinsic_matrix": [0.0] * 8 + [1.0]}))),
    "nerfstudio": ("transforms.json", lambda p: p.write_text(p.read_text().replace('"fl_x": ', '"fl_x": 0, "x": '))),
}


@pytest.mark.parametrize("fmt", sorted(ZERO_FOCAL))
def test_zero_focal_length_names_its_file(fmt, tmp_path):
    WRITERS[fmt](box_room_scan(3, 32, 24), tmp_path)
    name, write = ZERO_FOCAL[fmt]
    write(tmp_path / name)
    with pytest.raises(ReconError, match="focal") as err:
        open_scan(tmp_path)
    assert str(tmp_path / name) in str(err.value)


def test_sevenscenes_frame_without_pose_is_refused(tmp_path):
    WRITERS["7scenes"](box_room_scan(4, 32, 24), tmp_path)
    (tmp_path / "frame-000001.pose.txt").unlink()
    with pytest.raises(ReconError, match="frame-000001.color.png: no pose file"):
        open_scan(tmp_path)


@pytest.mark.parametrize("fmt,depth_file", [("7scenes", "frame-000002.depth.png"), ("scannet", "depth/2.png"),
                                            ("nerfstudio", "depth/frame_00002.png")])
def test_one_missing_depth_map_is_refused(fmt, depth_file, tmp_path):
    """One lost depth PNG must not quietly turn off depth and mesh scoring for the whole scan."""
    WRITERS[fmt](box_room_scan(4, 32, 24), tmp_path)
    (tmp_path / depth_file).unlink()
    with pytest.raises(ReconError, match="depth map of frame .* is missing") as err:
        open_scan(tmp_path)
    assert str(tmp_path / depth_file) in str(err.value)


def test_unsafe_frame_names_are_refused(tmp_path):
    """Frame names become file names in every stage's output; Scan.validate, which every reader's scan (and
    save_scan) passes, refuses any that would climb out of a folder."""
    from recon.io import check_file_name
    from recon.scan import save_scan

    for bad in ("../x", "/abs/x", "a/b", "..", "", "a\\b", "tab\there"):
        with pytest.raises(ReconError, match="cannot be a file name"):
            check_file_name(bad)
    assert check_file_name("frame 000001 ü") == "frame 000001 ü"
    scan = box_room_scan(3, 32, 24)
    scan.frames[1].name = "../../escaped"
    with pytest.raises(ReconError, match="escaped"):
        save_scan(scan, tmp_path / "out")
    assert not (tmp_path / "escaped.jpg").exists() and not (tmp_path / "out").exists()
