"""The `recon` command: help, the foundation's done-when commands, and bad input (exit 2, one line)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from apps.cli import main
from recon.scan import save_scan

from fixtures.box_room import box_room_scan
from fixtures.format_writers import WRITERS

ROOT = Path(__file__).resolve().parents[1]


def recon(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "apps.cli", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)


def test_help_lists_commands():
    out = recon("--help")
    assert out.returncode == 0
    for cmd in ("fuse", "eval", "bench", "info", "convert"):
        assert cmd in out.stdout
    assert recon("fuse", "--help").returncode == 0 and "--voxel-size" in recon("fuse", "--help").stdout


@pytest.fixture(scope="module")
def scan_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("room")
    save_scan(box_room_scan(24, 96, 72), d / "scan")
    return d / "scan"


def test_fuse_eval_convert_info(scan_dir, tmp_path, capsys):
    mesh = tmp_path / "room.ply"
    assert main(["fuse", str(scan_dir), "--depth", "gt", "--out", str(mesh), "--depth-max", "6", "--stride", "2"]) == 0
    assert mesh.is_file()
    capsys.readouterr()
    assert main(["eval", "mesh", str(mesh), str(mesh), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["fscore"] == 1.0 and result["acc"] == 0.0
    assert main(["convert", str(scan_dir), "--out", str(tmp_path / "small"), "--size", "48x36", "--max-frames", "3"]) == 0
    capsys.readouterr()
    assert main(["info", str(tmp_path / "small"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == 3 and info["intrinsics"]["width"] == 48 and info["has_depth"]


def test_info_describes_a_video_and_a_photo_folder(tmp_path, capsys):
    """`recon info` takes what `recon run` takes: a phone video and a folder of photos too (what SfM will get)."""
    import cv2

    from recon.io import write_image

    writer = cv2.VideoWriter(str(tmp_path / "clip.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 24.0, (64, 48))
    rng = np.random.default_rng(0)
    for _ in range(36):
        writer.write(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    writer.release()
    assert main(["info", str(tmp_path / "clip.mp4"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["kind"], info["frames"], info["size"], info["video_fps"], info["duration_s"]) == (
        "video", 36, [64, 48], 24.0, 1.5)
    (tmp_path / "photos").mkdir()
    for i, shape in enumerate([(30, 40, 3)] * 3 + [(40, 30, 3)]):  # the last one a portrait shot
        write_image(tmp_path / "photos" / f"IMG_{i}.jpg", rng.integers(0, 255, shape, dtype=np.uint8),
                    focal_35mm=26 if i else None)
    assert main(["info", str(tmp_path / "photos"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["kind"], info["frames"], info["size"], info["photos_with_exif_focal"], info["other_orientation"]) == (
        "photos", 4, [40, 30], 3, 1)
    assert info["focal_px"] == pytest.approx(26 / np.hypot(36, 24) * 50, abs=0.01)
    (tmp_path / "empty").mkdir()
    one_line_error(recon("info", str(tmp_path / "empty")), "no readable images")


def test_eval_depth_and_poses(scan_dir, tmp_path, capsys):
    from recon.readers import open_scan
    from recon.io import save_depth_map

    scan = open_scan(scan_dir)
    for i, f in enumerate(scan.frames):
        save_depth_map(tmp_path / "pred", f.name, scan.depth(i) * 1.05)
    assert main(["eval", "depth", "--pred", str(tmp_path / "pred"), "--scan", str(scan_dir), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    for key in ("abs_rel", "abs", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3", "frames", "mae_mean", "mae_std",
                "flicker"):
        assert key in r
    assert r["abs_rel"] == pytest.approx(0.05, rel=1e-3) and r["frames"] == 24
    assert main(["eval", "poses", "--pred", str(scan_dir), "--gt", str(scan_dir), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["ate_rmse"] < 1e-9 and r["registered"] == 1.0


def one_line_error(proc: subprocess.CompletedProcess, *fragments: str) -> None:
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    errors = [ln for ln in proc.stderr.strip().splitlines() if ln.startswith("recon: error:")]
    assert len(errors) == 1 and proc.stderr.strip().endswith(errors[0]), proc.stderr  # progress lines may precede
    for frag in fragments:
        assert frag in errors[0]


def test_bad_input_gives_one_line_and_exit_2(tmp_path):
    one_line_error(recon("fuse", str(tmp_path / "missing"), "--out", str(tmp_path / "m.ply")), "no such file")
    (tmp_path / "empty").mkdir()
    one_line_error(recon("info", str(tmp_path / "empty")), "not a known scan format")
    ref = box_room_scan(4, 32, 24)
    WRITERS["7scenes"](ref, tmp_path / "bad")
    np.savetxt(tmp_path / "bad/frame-000001.pose.txt", np.ones((4, 4)))
    one_line_error(recon("fuse", str(tmp_path / "bad"), "--out", str(tmp_path / "m.ply")), "000001", "rigid")
    (tmp_path / "bad/frame-000001.pose.txt").write_text("1 2 3\n")
    one_line_error(recon("info", str(tmp_path / "bad")), "frame-000001.pose.txt")
    WRITERS["7scenes"](ref, tmp_path / "ok")
    one_line_error(recon("fuse", str(tmp_path / "ok"), "--out", str(tmp_path / "m.xyz")), "unsupported mesh format")
    (tmp_path / "ok/frame-000002.color.png").write_bytes(b"garbage")
    proc = recon("fuse", str(tmp_path / "ok"), "--out", str(tmp_path / "m.ply"))
    one_line_error(proc, "frame-000002.color.png", "unreadable image")
    assert not (tmp_path / "m.ply").exists()  # nothing half-written
    one_line_error(recon("eval", "mesh", str(tmp_path / "m.ply"), str(tmp_path / "m.ply")), "not found")
    one_line_error(recon("info", str(tmp_path / "ok"), "--stride", "0"), "invalid frame selection")


def test_debug_shows_traceback(tmp_path):
    proc = recon("--debug", "info", str(tmp_path / "missing"))
    assert proc.returncode != 0 and "Traceback" in proc.stderr


@pytest.mark.data
def test_done_when_kitchen_fuse_and_self_eval(sevenscenes, tmp_path):
    """The foundation's done-when: fuse the 7-Scenes kitchen from GT depth, score the mesh against itself."""
    mesh = tmp_path / "m.ply"
    proc = recon("fuse", str(sevenscenes), "--depth", "gt", "--out", str(mesh))
    assert proc.returncode == 0, proc.stderr
    import trimesh

    m = trimesh.load(mesh)
    extent = m.bounds[1] - m.bounds[0]
    assert len(m.faces) > 20_000 and np.all(extent > 1.0) and np.all(extent < 8.0)  # a kitchen, metres
    proc = recon("eval", "mesh", str(mesh), str(mesh), "--json")
    assert proc.returncode == 0 and json.loads(proc.stdout)["fscore"] == 1.0


def test_batch_help_states_exit_status():
    text = " ".join(recon("batch", "--help").stdout.split())  # argparse wraps the description
    assert "1 when any scan failed" in text and "2 for bad options" in text


def test_error_line_is_one_line_naming_the_file():
    from apps.cli import error_line
    from recon.errors import ReconError

    assert error_line(PermissionError(13, "Permission denied", "/data/run")) == "/data/run: permission denied"
    moved = OSError(18, "Invalid cross-device link", "/a", None, "/b")
    assert error_line(moved) == "/a -> /b: invalid cross-device link"
    spilled = ReconError("x.png: unreadable image (libpng error:\nIDAT)")
    assert error_line(spilled) == "x.png: unreadable image (libpng error: IDAT)"


def test_log_lines_print_above_the_live_bars_in_a_terminal(tmp_path):
    """In a terminal a log record goes through rich to the console the bar draws on, so it starts a cleared
    line of its own (a plain handler wrote it after the bar: `... eta 0:00:02depth: 40 frames in 75.8 s`)."""
    import os
    import pty
    import re
    import select
    import time

    from recon.plane_scene import plane_scan

    scan = save_scan(plane_scan(3, 64, 48, step=0.08), tmp_path / "scan")
    leader, follower = pty.openpty()
    env = dict(os.environ, TERM="xterm-256color", COLUMNS="100", LINES="30")
    proc = subprocess.Popen([sys.executable, "-m", "apps.cli", "depth", str(scan), "--out", str(tmp_path / "d"),
                             "--mode", "planesweep", "--keyframe-distance", "0"],
                            cwd=ROOT, stdin=follower, stdout=follower, stderr=follower, env=env)
    os.close(follower)
    chunks, deadline = [], time.monotonic() + 300
    while time.monotonic() < deadline:
        if not select.select([leader], [], [], 1.0)[0]:
            continue
        try:
            data = os.read(leader, 65536)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(leader)
    assert proc.wait(timeout=300) == 0
    text = re.sub(r"\x1b\[[0-9;]*m", "", b"".join(chunks).decode(errors="replace"))  # colours only
    assert "━" in text, text[-2000:]  # a live rich bar was drawn
    hits = [m.start() for m in re.finditer(r"depth: 3 frames in", text)]
    assert hits, text[-2000:]
    for at in hits:  # each at the start of a line the console cleared or began
        assert text[:at].endswith(("\x1b[2K", "\r", "\n")), repr(text[max(0, at - 80):at + 40])
