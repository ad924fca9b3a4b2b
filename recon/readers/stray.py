"""Stray Scanner export (iPhone/iPad LiDAR app): rgb.mp4, odometry.csv, camera_matrix.csv, depth/, confidence/.

Poses are metric ARKit tracking. The app writes them camera-to-world with OpenCV camera
axes already: it multiplies ARKit's camera orientation by a 180 degree turn about x
(its `q_AC`) before writing `x, y, z, qx, qy, qz, qw`, so no axis flip is needed here.
`odometry.csv` has a header `timestamp, frame, x, y, z, qx, qy, qz, qw` (early app
versions wrote the last seven columns only, one row per video frame). `camera_matrix.csv`
is K for the video's resolution. `depth/NNNNNN.png` are 256x192 uint16 millimetres
(resampled onto the color grid when read); `confidence/` (0, 1, 2) is recorded in the
metadata for filtering downstream.

The video is decoded once, at most `DECODE_MAX_SIZE` pixels on the long side, into a
cache folder (`$RECON_CACHE_DIR`, default `~/.cache/recon`) keyed by the video's path,
size and modification time, so re-reading an export costs nothing.
"""
from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path

import cv2
import numpy as np

from recon import io as rio
from recon.io import working_size
from recon.errors import ScanFormatError, naming
from recon.geometry import quaternion_to_rotation
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

from ._common import depth_size

NAME = "stray"
DECODE_MAX_SIZE = 960
log = logging.getLogger(__name__)


def detect(path: Path) -> bool:
    return path.is_dir() and (path / "rgb.mp4").is_file() and (path / "odometry.csv").is_file()


def read_odometry(path: Path) -> list[tuple[int, float | None, np.ndarray]]:
    """(video frame index, timestamp or None, camera-to-world 4x4) per row of odometry.csv."""
    lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]
    if not lines:
        raise ScanFormatError(f"{path}: empty odometry file")
    header = [h.strip() for h in lines[0].split(",")]
    has_header = "qw" in header
    cols = header if has_header else ["x", "y", "z", "qx", "qy", "qz", "qw"]
    rows = lines[1:] if has_header else lines
    out = []
    for k, line in enumerate(rows):
        try:
            values = dict(zip(cols, (float(v) for v in line.split(","))))
            pose = np.eye(4)
            pose[:3, :3] = quaternion_to_rotation(values["qw"], values["qx"], values["qy"], values["qz"])
            pose[:3, 3] = [values["x"], values["y"], values["z"]]
        except (ValueError, KeyError) as exc:
            raise ScanFormatError(f"{path}: line {k + 1 + has_header} is malformed ({exc})") from None
        out.append((int(values.get("frame", k)), values.get("timestamp"), pose))
    return out


def _cache_dir(video: Path) -> Path:
    st = video.stat()
    key = hashlib.sha1(f"{video.resolve()}|{st.st_size}|{st.st_mtime_ns}|{DECODE_MAX_SIZE}".encode()).hexdigest()[:16]
    root = Path(os.environ.get("RECON_CACHE_DIR", Path.home() / ".cache" / "recon"))
    return root / "stray" / key


def decode_video(video: Path) -> tuple[Path, int, tuple[int, int], tuple[int, int]]:
    """Decode every frame once into the cache: (folder, frame count, video size, decoded size)."""

    cap = rio.open_video(video)
    width, height = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    folder = _cache_dir(video)
    done = folder / "frames.done"
    if done.is_file():
        cap.release()
        count, w, h = (int(v) for v in done.read_text().split())
        return folder, count, (width, height), (w, h)
    log.info("stray: decoding %s into %s (once)", video, folder)
    count, size = 0, None
    try:
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            if size is None:
                width, height = bgr.shape[1], bgr.shape[0]
                size = working_size(width, height, DECODE_MAX_SIZE)
            small = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
            rio.write_image(folder / f"{count:06d}.jpg", cv2.cvtColor(small, cv2.COLOR_BGR2RGB))
            count += 1
    finally:
        cap.release()
    if size is None:
        raise ScanFormatError(f"{video}: the video has no decodable frames")
    rio.write_bytes_atomic(done, f"{count} {size[0]} {size[1]}\n".encode())
    return folder, count, (width, height), size


def read(path: Path) -> Scan:
    kfile = path / "camera_matrix.csv"
    if not kfile.is_file():
        raise ScanFormatError(f"{path}: missing camera_matrix.csv")
    try:
        K = np.loadtxt(kfile, delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise ScanFormatError(f"{kfile}: cannot parse ({exc})") from None
    if K.shape != (3, 3):
        raise ScanFormatError(f"{kfile}: expected a 3x3 matrix, got shape {K.shape}")
    odometry = read_odometry(path / "odometry.csv")
    folder, count, video_size, size = decode_video(path / "rgb.mp4")
    with naming(kfile):
        intr = Intrinsics.from_K(K, *video_size).resized(*size)
    frames = []
    has_depth = (path / "depth").is_dir() and any((path / "depth").glob("*.png"))  # then every frame needs its map
    for index, timestamp, pose in odometry:
        if index >= count:
            log.warning("%s: odometry frame %d is past the video's %d frames; ignored", path, index, count)
            continue
        depth = path / "depth" / f"{index:06d}.png"
        frames.append(Frame(name=f"{index:06d}", camera_to_world=pose, image_path=folder / f"{index:06d}.jpg",
                            depth_path=depth if has_depth else None, timestamp=timestamp,
                            source_index=index))
    if not frames:
        raise ScanFormatError(f"{path}: odometry.csv names no frame of rgb.mp4")
    extra = {"confidence_dir": str(path / "confidence")} if (path / "confidence").is_dir() else {}
    first_depth = next((f.depth_path for f in frames if f.depth_path is not None and f.depth_path.is_file()), None)
    # ARKit depth is the colour camera's view at a lower resolution: the same camera, rescaled.
    depth_intr = intr.resized(*depth_size(first_depth)) if first_depth is not None else None
    return Scan(intr, frames, ScanMetadata(metric_scale=True, source_format=NAME, extra=extra), root=path,
                depth_intrinsics=None if depth_intr == intr else depth_intr)
