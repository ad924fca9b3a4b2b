"""TUM RGB-D layout: rgb.txt, depth.txt, groundtruth.txt with timestamps.

Color, depth and ground-truth poses are sampled at different times; each color frame
takes the nearest depth and pose within `MAX_DT` seconds, and frames without one are
left out (counted in the metadata). Poses are `tx ty tz qx qy qz qw`, camera-to-world;
depth PNGs store 5000 units per metre. Intrinsics come from `camera-intrinsics.txt` /
`intrinsics.txt` (3x3) when present, else from the Freiburg sensor named in the folder.
"""
from pathlib import Path

import numpy as np

from recon.errors import ScanFormatError, naming
from recon.geometry import quaternion_to_rotation
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

from ._common import image_size, load_matrix

NAME = "tum"
MAX_DT = 0.02
TUM_DEPTH_UNITS_PER_METRE = 5000.0
# Calibrations published with the dataset; the ROS default for unknown sensors.
FREIBURG_K = {"freiburg1": (517.3, 516.5, 318.6, 255.3), "freiburg2": (520.9, 521.0, 325.1, 249.7),
              "freiburg3": (535.4, 539.2, 320.1, 247.6)}
DEFAULT_K = (525.0, 525.0, 319.5, 239.5)


def detect(path: Path) -> bool:
    return path.is_dir() and (path / "rgb.txt").is_file() and (path / "groundtruth.txt").is_file()


def _read_list(path: Path, min_cols: int) -> list[list[str]]:
    if not path.is_file():
        raise ScanFormatError(f"{path}: missing")
    rows = []
    for ln, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        cols = line.split()
        if len(cols) < min_cols:
            raise ScanFormatError(f"{path}:{ln}: expected {min_cols} columns, got {len(cols)}")
        rows.append(cols)
    if not rows:
        raise ScanFormatError(f"{path}: no entries")
    return rows


def _nearest(times: np.ndarray, t: float) -> int | None:
    i = int(np.searchsorted(times, t))
    best = min((j for j in (i - 1, i) if 0 <= j < len(times)), key=lambda j: abs(times[j] - t))
    return best if abs(times[best] - t) <= MAX_DT else None


def _intrinsics(path: Path) -> tuple[tuple[float, float, float, float], Path]:
    """(fx, fy, cx, cy) and where they came from (a file, else the folder whose sensor name decides)."""
    for name in ("camera-intrinsics.txt", "intrinsics.txt"):
        if (path / name).is_file():
            K = load_matrix(path / name, (3, 3))
            return (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), path / name
    for key, k in FREIBURG_K.items():
        if key in path.resolve().name:
            return k, path
    return DEFAULT_K, path


def read(path: Path) -> Scan:
    rgb = _read_list(path / "rgb.txt", 2)
    depth_rows = _read_list(path / "depth.txt", 2) if (path / "depth.txt").is_file() else []
    gt = _read_list(path / "groundtruth.txt", 8)
    try:
        gt_t = np.array([float(r[0]) for r in gt])
        gt_v = np.array([[float(x) for x in r[1:8]] for r in gt])
        d_t = np.array([float(r[0]) for r in depth_rows])
        rgb_t = [float(r[0]) for r in rgb]
    except ValueError as exc:
        raise ScanFormatError(f"{path}: non-numeric timestamp or pose ({exc})") from None
    order = np.argsort(gt_t)
    gt_t, gt_v = gt_t[order], gt_v[order]
    d_order = np.argsort(d_t)
    frames, unmatched = [], 0
    for i, (t, row) in enumerate(zip(rgb_t, rgb)):
        g = _nearest(gt_t, t)
        d = _nearest(d_t[d_order], t) if len(d_t) else None
        if g is None or (depth_rows and d is None):
            unmatched += 1
            continue
        tx, ty, tz, qx, qy, qz, qw = gt_v[g]
        pose = np.eye(4)
        pose[:3, :3] = quaternion_to_rotation(qw, qx, qy, qz)
        pose[:3, 3] = (tx, ty, tz)
        depth_path = path / depth_rows[d_order[d]][1] if d is not None else None
        frames.append(Frame(name=f"{i:06d}", camera_to_world=pose, image_path=path / row[1], depth_path=depth_path,
                            depth_units_per_metre=TUM_DEPTH_UNITS_PER_METRE, timestamp=t, source_index=i))
    if not frames:
        raise ScanFormatError(f"{path}: no color frame has a ground-truth pose within {MAX_DT} s")
    w, h = image_size(frames[0].image_path)
    (fx, fy, cx, cy), source = _intrinsics(path)
    meta = ScanMetadata(metric_scale=True, source_format=NAME, extra={"frames_without_pose_or_depth": unmatched})
    with naming(source):
        intr = Intrinsics(fx, fy, cx, cy, w, h)
    return Scan(intr, frames, meta, root=path)
