import json

import numpy as np
import pytest

from recon.errors import ReconError
from recon.geometry import project
from recon.io import atomic_path, load_confidence_map, load_depth_map, save_depth_map
from recon.scan import Intrinsics, load_scan, save_scan

from fixtures.box_room import box_room_scan


def test_intrinsics_resize_keeps_projection_consistent():
    intr = Intrinsics(500, 510, 319.5, 239.5, 640, 480)
    half = intr.resized(320, 240)
    assert (half.fx, half.fy, half.cx, half.cy) == (250, 255, 159.5, 119.5)
    # A point projecting to pixel (u, v) lands on the same fraction of the resized image.
    uv, _ = project(np.array([[0.3, -0.2, 2.0]]), intr.K)
    uv_half, _ = project(np.array([[0.3, -0.2, 2.0]]), half.K)
    assert np.allclose((uv_half + 0.5) / [320, 240], (uv + 0.5) / [640, 480])
    crop = intr.cropped(10, 20, 600, 400)
    assert (crop.cx, crop.cy, crop.width) == (309.5, 219.5, 600)
    with pytest.raises(ReconError):
        intr.cropped(100, 0, 600, 480)
    with pytest.raises(ReconError):
        Intrinsics(0, 1, 1, 1, 10, 10)


def test_cropped_scan_hands_out_the_window_with_matching_intrinsics():
    scan = box_room_scan(3)
    W, H = scan.intrinsics.size
    view = scan.resized(W // 2, H // 2).cropped(5, 3, W // 2 - 10, H // 2 - 6)
    half = scan.resized(W // 2, H // 2)
    assert np.array_equal(view.image(1), half.image(1)[3:3 + H // 2 - 6, 5:5 + W // 2 - 10])
    assert np.array_equal(view.depth(1), half.depth(1)[3:3 + H // 2 - 6, 5:5 + W // 2 - 10])
    assert view.intrinsics == half.intrinsics.cropped(5, 3, W // 2 - 10, H // 2 - 6)
    assert view.image(0).shape[:2] == (view.intrinsics.height, view.intrinsics.width)
    with pytest.raises(ReconError, match="resize first"):
        view.resized(10, 10)
    with pytest.raises(ReconError, match="outside image"):
        half.cropped(0, 0, W, H)


def test_select_keeps_names_and_rejects_empty():
    scan = box_room_scan(10)
    sub = scan.select(start=1, stride=3, max_frames=2)
    assert sub.names == ["000001", "000004"]
    assert len(scan.select(stride=4)) == 3
    with pytest.raises(ReconError, match="no frames"):
        scan.select(start=20)
    with pytest.raises(ReconError):
        scan.select(stride=0)


def test_resized_scan_hands_out_resized_pixels_and_intrinsics():
    scan = box_room_scan(2, 96, 72).resized(48, 36)
    assert scan.image(0).shape == (36, 48, 3)
    assert scan.depth(0).shape == (36, 48)
    assert scan.intrinsics.width == 48 and np.isclose(scan.intrinsics.fx, scan.source_intrinsics.fx / 2)


def test_save_load_round_trip(tmp_path):
    scan = box_room_scan(4)
    scan.metadata.depth_range = (0.5, 4.0)
    save_scan(scan, tmp_path / "s", image_ext=".png")
    back = load_scan(tmp_path / "s")
    assert back.names == scan.names
    assert back.intrinsics == scan.intrinsics
    assert np.allclose(back.camera_to_world, scan.camera_to_world)
    assert back.metadata.depth_range == (0.5, 4.0)
    for i in range(len(scan)):
        assert np.array_equal(back.image(i), scan.image(i))
        assert np.abs(back.depth(i) - scan.depth(i)).max() <= 0.0005 + 1e-6  # millimetre PNG


def test_load_scan_reports_bad_files(tmp_path):
    scan = box_room_scan(2)
    save_scan(scan, tmp_path / "s")
    doc = json.loads((tmp_path / "s/scan.json").read_text())
    doc["frames"][1]["camera_to_world"][0][1] = 0.5  # not a rotation any more
    (tmp_path / "s/scan.json").write_text(json.dumps(doc))
    with pytest.raises(ReconError, match="frame 000001.*rigid"):
        load_scan(tmp_path / "s")
    (tmp_path / "s/scan.json").write_text("{not json")
    with pytest.raises(ReconError, match="invalid JSON"):
        load_scan(tmp_path / "s")
    with pytest.raises(ReconError, match="no scan.json"):
        load_scan(tmp_path)


def test_unreadable_image_names_the_file(tmp_path):
    scan = box_room_scan(2)
    save_scan(scan, tmp_path / "s")
    (tmp_path / "s/images/000001.jpg").write_bytes(b"not a jpeg")
    back = load_scan(tmp_path / "s")
    with pytest.raises(ReconError, match="000001.jpg: unreadable image"):
        back.image(1)


def test_failed_write_leaves_nothing(tmp_path):
    target = tmp_path / "mesh.ply"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("crash mid-write")
    assert list(tmp_path.iterdir()) == []

    class Boom(Exception):
        pass

    scan = box_room_scan(3)
    calls = []

    def progress(i, n):
        calls.append(i)
        if i == 2:
            raise Boom()

    with pytest.raises(Boom):
        save_scan(scan, tmp_path / "scan", progress=progress)
    assert not (tmp_path / "scan").exists() and list(tmp_path.iterdir()) == []


def test_depth_map_files_round_trip(tmp_path):
    depth = np.linspace(0, 5, 12, dtype=np.float32).reshape(3, 4)
    conf = np.linspace(0, 1, 12, dtype=np.float32).reshape(3, 4)
    (tmp_path / "000007.npy").write_bytes(b"an older layout's float map")  # replaced, never preferred
    save_depth_map(tmp_path, "000007", depth, conf)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["000007.conf.png", "000007.png"]
    loaded = load_depth_map(tmp_path, "000007")
    assert loaded.dtype == np.float32 and np.abs(loaded - depth).max() <= 0.0005 + 1e-6  # millimetres
    assert np.abs(load_confidence_map(tmp_path, "000007") - conf).max() <= 0.5 / 255 + 1e-7  # steps of 1/255
    assert load_confidence_map(tmp_path, "000008") is None
    np.save(tmp_path / "000009.npy", depth)  # another tool's float prediction is read as it is
    assert np.array_equal(load_depth_map(tmp_path, "000009"), depth)
    with pytest.raises(ReconError, match="no depth map for frame 000008"):
        load_depth_map(tmp_path, "000008")
