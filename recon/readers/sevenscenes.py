"""Microsoft 7-Scenes / tsdf-fusion layout: frame-NNNNNN.color.(jpg|png), .depth.png, .pose.txt.

Poses are camera-to-world (OpenCV axes); depth is millimetres. The Kinect that recorded
7-Scenes has two cameras: `camera-intrinsics.txt` (585/585/320/240 when absent) describes the
depth sensor, while the colour camera has a 525 px focal length (the dataset's own note;
self-calibrating SfM on the colour images finds 528 px, and multi-view colour matching is
25-50 % off in depth with 585). The colour intrinsics come from `color-intrinsics.txt` when
present, else 525/525/320/240, and depth is resampled onto the colour camera (the two are
taken to share their optical centre: a few pixels of misalignment remain at depth edges).
"""
from pathlib import Path

import numpy as np

from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

from recon.errors import ScanFormatError, naming

from ._common import depth_size, image_size, load_matrix, require_same_count

NAME = "7scenes"
DEFAULT_DEPTH_K = np.array([[585.0, 0, 320.0], [0, 585.0, 240.0], [0, 0, 1]])
DEFAULT_COLOR_K = np.array([[525.0, 0, 320.0], [0, 525.0, 240.0], [0, 0, 1]])


def detect(path: Path) -> bool:
    return path.is_dir() and any(path.glob("frame-*.pose.txt"))


def read(path: Path) -> Scan:
    poses = sorted(path.glob("frame-*.pose.txt"))
    stems = {p.name[: -len(".pose.txt")] for p in poses}
    unposed = sorted(c for ext in (".jpg", ".png") for c in path.glob(f"frame-*.color{ext}")
                     if c.name.split(".color.")[0] not in stems)
    if unposed:  # dropping it would leave a hole in the sequence that nobody was told about
        raise ScanFormatError(f"{unposed[0]}: no pose file ({unposed[0].name.split('.color.')[0]}.pose.txt) for this "
                              "frame (add the pose, or remove the frame)")
    colors = [_color_file(path, p.name[: -len(".pose.txt")]) for p in poses]
    require_same_count(colors, poses, "color images", "pose files", path)
    has_depth = any(path.glob("frame-*.depth.png"))  # then every frame must have its map (Scan.validate)
    depth_file, color_file = path / "camera-intrinsics.txt", path / "color-intrinsics.txt"
    depth_K = load_matrix(depth_file, (3, 3)) if depth_file.is_file() else DEFAULT_DEPTH_K
    color_K = load_matrix(color_file, (3, 3)) if color_file.is_file() else DEFAULT_COLOR_K
    w, h = image_size(colors[0])
    frames = []
    for i, (p, c) in enumerate(zip(poses, colors)):
        stem = p.name[: -len(".pose.txt")]
        depth = path / f"{stem}.depth.png"
        name = stem.split("-")[-1]
        frames.append(Frame(name=name, camera_to_world=load_matrix(p, (4, 4)), image_path=c,
                            depth_path=depth if has_depth else None, source_index=int(name) if name.isdigit() else i))
    first_depth = next((f.depth_path for f in frames if f.depth_path is not None and f.depth_path.is_file()), None)
    dw, dh = depth_size(first_depth) if first_depth is not None else (w, h)
    with naming(color_file if color_file.is_file() else path):
        color = Intrinsics.from_K(color_K, w, h)
    with naming(depth_file if depth_file.is_file() else path):
        depth = Intrinsics.from_K(depth_K, dw, dh)
    return Scan(color, frames, ScanMetadata(metric_scale=True, source_format=NAME), root=path,
                depth_intrinsics=None if depth == color else depth)


def _color_file(folder: Path, stem: str) -> Path:
    for ext in (".jpg", ".png"):
        c = folder / f"{stem}.color{ext}"
        if c.is_file():
            return c
    raise ScanFormatError(f"{folder / stem}.pose.txt: no matching color image ({stem}.color.jpg|png)")
