"""Microsoft 7-Scenes / tsdf-fusion layout: frame-NNNNNN.color.(jpg|png), .depth.png, .pose.txt.

Poses are camera-to-world (OpenCV axes); depth is millimetres; `camera-intrinsics.txt`
holds K (7-Scenes' usual 585/585/320/240 when the file is absent).
"""
from pathlib import Path

import numpy as np

from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

from recon.errors import ScanFormatError

from ._common import image_size, load_matrix, require_same_count

NAME = "7scenes"
DEFAULT_K = np.array([[585.0, 0, 320.0], [0, 585.0, 240.0], [0, 0, 1]])


def detect(path: Path) -> bool:
    return path.is_dir() and any(path.glob("frame-*.pose.txt"))


def read(path: Path) -> Scan:
    poses = sorted(path.glob("frame-*.pose.txt"))
    colors = [_color_file(path, p.name[: -len(".pose.txt")]) for p in poses]
    require_same_count(colors, poses, "color images", "pose files", path)
    kfile = path / "camera-intrinsics.txt"
    K = load_matrix(kfile, (3, 3)) if kfile.is_file() else DEFAULT_K
    w, h = image_size(colors[0])
    frames = []
    for i, (p, c) in enumerate(zip(poses, colors)):
        stem = p.name[: -len(".pose.txt")]
        depth = path / f"{stem}.depth.png"
        name = stem.split("-")[-1]
        frames.append(Frame(name=name, camera_to_world=load_matrix(p, (4, 4)), image_path=c,
                            depth_path=depth if depth.is_file() else None, source_index=int(name) if name.isdigit() else i))
    return Scan(Intrinsics.from_K(K, w, h), frames, ScanMetadata(metric_scale=True, source_format=NAME), root=path)


def _color_file(folder: Path, stem: str) -> Path:
    for ext in (".jpg", ".png"):
        c = folder / f"{stem}.color{ext}"
        if c.is_file():
            return c
    raise ScanFormatError(f"{folder / stem}.pose.txt: no matching color image ({stem}.color.jpg|png)")
