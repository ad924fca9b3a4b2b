"""Stray Scanner exports: metric ARKit poses, K for the video, LiDAR depth, frames decoded once into a cache."""
import cv2
import numpy as np
import pytest

from recon.readers import detect_format, open_scan
from recon.readers import stray
from recon.errors import ScanFormatError

VW, VH = 1280, 960  # decoded at most 960 px on the long side -> 960x720


def make_export(folder, n_video=6, odometry_frames=(0, 2, 4)):
    folder.mkdir()
    writer = cv2.VideoWriter(str(folder / "rgb.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (VW, VH))
    for i in range(n_video):
        writer.write(np.full((VH, VW, 3), 30 + 40 * i, np.uint8))  # brightness identifies the frame
    writer.release()
    np.savetxt(folder / "camera_matrix.csv", [[1000.0, 0, 640.0], [0, 1000.0, 480.0], [0, 0, 1]], delimiter=",")
    rows = ["timestamp, frame, x, y, z, qx, qy, qz, qw"]
    for k, i in enumerate(odometry_frames):
        rows.append(f"{0.1 * i:.3f}, {i:06d}, {0.1 * k}, 0.0, {-0.2 * k}, 0.0, 0.0, 0.0, 1.0")
    (folder / "odometry.csv").write_text("\n".join(rows) + "\n")
    (folder / "depth").mkdir()
    (folder / "confidence").mkdir()
    for i in odometry_frames:
        depth = np.full((192, 256), 1500 + 100 * i, np.uint16)
        cv2.imwrite(str(folder / "depth" / f"{i:06d}.png"), depth)
        cv2.imwrite(str(folder / "confidence" / f"{i:06d}.png"), np.full((192, 256), 2, np.uint8))
    return folder


def test_stray_export_reads_as_metric_scan(tmp_path, monkeypatch):
    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path / "cache"))
    export = make_export(tmp_path / "export")
    assert detect_format(export) == "stray"
    scan = open_scan(export)
    assert scan.metadata.metric_scale and scan.metadata.source_format == "stray"
    assert scan.names == ["000000", "000002", "000004"]
    assert [f.timestamp for f in scan.frames] == pytest.approx([0.0, 0.2, 0.4])
    intr = scan.intrinsics
    assert (intr.width, intr.height) == (960, 720)
    assert (intr.fx, intr.fy) == pytest.approx((750.0, 750.0))
    assert (intr.cx, intr.cy) == pytest.approx(((640 + 0.5) * 0.75 - 0.5, (480 + 0.5) * 0.75 - 0.5))
    np.testing.assert_allclose(scan.frames[2].camera_to_world[:3, 3], [0.2, 0.0, -0.4])
    image = scan.image(1)  # video frame 2
    assert image.shape == (720, 960, 3) and abs(float(image.mean()) - 110) < 6
    depth = scan.depth(2)  # LiDAR 256x192 sampled onto the colour grid
    assert depth.shape == (720, 960) and np.allclose(depth, 1.9)
    assert scan.metadata.extra["confidence_dir"].endswith("confidence")
    # The decoded frames are reused: a second read does not decode again.
    cache = next((tmp_path / "cache" / "stray").iterdir())
    stamp = (cache / "000002.jpg").stat().st_mtime_ns
    open_scan(export)
    assert (cache / "000002.jpg").stat().st_mtime_ns == stamp


def test_stray_old_headerless_odometry_and_bad_files(tmp_path, monkeypatch):
    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path / "cache"))
    export = make_export(tmp_path / "export", odometry_frames=(0, 1))
    (export / "odometry.csv").write_text("0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0\n0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0\n")
    scan = stray.read(export)
    assert scan.names == ["000000", "000001"] and scan.frames[1].camera_to_world[0, 3] == 0.5
    (export / "odometry.csv").write_text("timestamp, frame, x, y, z, qx, qy, qz, qw\n0.0, 0, 1, 2\n")
    with pytest.raises(ScanFormatError, match="line 2 is malformed"):
        stray.read(export)
    (export / "camera_matrix.csv").write_text("1, 2\n3, 4\n")
    with pytest.raises(ScanFormatError, match="3x3"):
        stray.read(export)
