"""Open3D reconstruction-system / ICL-NUIM layout: image/, depth/, trajectory.log.

`trajectory.log` holds one block per frame: a header line `i j n` and a 4x4
camera-to-world matrix. It may sit in the folder or in `test_scene/`. Intrinsics come
from Open3D's `camera_intrinsic.json` (column-major `intrinsic_matrix`) when present,
else the PrimeSense default 525/525/319.5/239.5 that ICL-NUIM uses.
"""
import json
from pathlib import Path

import numpy as np

from recon.errors import ScanFormatError, naming
from recon.scan import Intrinsics, Scan, ScanMetadata

from ._common import image_size, numbered_files, numbered_frames, require_same_count

NAME = "open3d"
DEFAULT_K = (525.0, 525.0, 319.5, 239.5)
LOG_PLACES = ("trajectory.log", "test_scene/trajectory.log", "scene/trajectory.log")


def _log_file(path: Path) -> Path | None:
    return next((path / p for p in LOG_PLACES if (path / p).is_file()), None)


def detect(path: Path) -> bool:
    return path.is_dir() and (path / "image").is_dir() and _log_file(path) is not None


def read_trajectory_log(path: Path) -> list[np.ndarray]:
    """Camera-to-world matrices of an Open3D `.log` file, in file order."""
    lines = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
    if len(lines) % 5:
        raise ScanFormatError(f"{path}: {len(lines)} lines, expected blocks of 5 (header + 4x4)")
    poses = []
    for b in range(0, len(lines), 5):
        try:
            mat = np.array([[float(x) for x in row] for row in lines[b + 1: b + 5]])
        except ValueError as exc:
            raise ScanFormatError(f"{path}: block {b // 5}: {exc}") from None
        if mat.shape != (4, 4):
            raise ScanFormatError(f"{path}: block {b // 5} is not a 4x4 matrix")
        poses.append(mat)
    return poses


def _intrinsics(path: Path) -> tuple[float, float, float, float]:
    f = path / "camera_intrinsic.json"
    if not f.is_file():
        return DEFAULT_K
    try:
        K = np.array(json.loads(f.read_text())["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T
    except (KeyError, ValueError, json.JSONDecodeError) as exc:
        raise ScanFormatError(f"{f}: invalid Open3D intrinsics ({exc})") from None
    return K[0, 0], K[1, 1], K[0, 2], K[1, 2]


def read(path: Path) -> Scan:
    images = numbered_files(path / "image")
    log = _log_file(path)
    poses = read_trajectory_log(log)
    require_same_count(images, poses, "images", f"poses in {log.name}", path)
    w, h = image_size(images[0])
    frames = numbered_frames(path, images, poses)
    with naming(path / "camera_intrinsic.json"):  # the defaults cannot fail
        intr = Intrinsics(*_intrinsics(path), w, h)
    return Scan(intr, frames,
                ScanMetadata(metric_scale=True, source_format=NAME), root=path)
