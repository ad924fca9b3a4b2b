"""ScanNet export layout (the SensReader output): color/, depth/, pose/, intrinsic/.

`pose/N.txt` is camera-to-world; `intrinsic/intrinsic_color.txt` (4x4) describes the
color images and `intrinsic/intrinsic_depth.txt` the depth maps (millimetres, at their own
smaller resolution), which the Scan resamples onto the color camera. Frames with invalid (inf/NaN) poses are dropped, as
ScanNet marks lost tracking that way.
"""
from pathlib import Path

import numpy as np

from recon.errors import ScanFormatError, naming
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

from ._common import depth_size, frame_number, image_size, load_matrix, numbered_files, require_dir

NAME = "scannet"


def detect(path: Path) -> bool:
    return path.is_dir() and (path / "color").is_dir() and (path / "pose").is_dir() and (path / "intrinsic").is_dir()


def read(path: Path) -> Scan:
    colors = numbered_files(require_dir(path / "color", "color"))
    if not colors:
        raise ScanFormatError(f"{path / 'color'}: no images")
    kfile = path / "intrinsic" / "intrinsic_color.txt"
    if not kfile.is_file():
        raise ScanFormatError(f"{kfile}: missing color intrinsics")
    K = load_matrix(kfile, (4, 4))[:3, :3]
    w, h = image_size(colors[0])
    depth_K_file = path / "intrinsic" / "intrinsic_depth.txt"
    depth_intr = None
    frames, dropped = [], 0
    has_depth = (path / "depth").is_dir() and any((path / "depth").glob("*.png"))  # then every frame needs its map
    for c in colors:
        n = frame_number(c)
        pfile = path / "pose" / f"{n}.txt"
        if not pfile.is_file():
            raise ScanFormatError(f"{pfile}: missing pose for {c.name}")
        pose = load_matrix(pfile, (4, 4))
        if not np.all(np.isfinite(pose)):
            dropped += 1
            continue
        depth = path / "depth" / f"{n}.png"
        frames.append(Frame(name=f"{n:06d}", camera_to_world=pose, image_path=c,
                            depth_path=depth if has_depth else None, source_index=n))
    if not frames:
        raise ScanFormatError(f"{path}: every pose is invalid")
    first_depth = next((f.depth_path for f in frames if f.depth_path is not None and f.depth_path.is_file()), None)
    if first_depth is not None:
        dw, dh = depth_size(first_depth)
        if depth_K_file.is_file():
            with naming(depth_K_file):
                depth_intr = Intrinsics.from_K(load_matrix(depth_K_file, (4, 4))[:3, :3], dw, dh)
        elif (dw, dh) != (w, h):
            raise ScanFormatError(f"{depth_K_file}: missing, and depth ({dw}x{dh}) differs from color ({w}x{h})")
    meta = ScanMetadata(metric_scale=True, source_format=NAME, extra={"dropped_invalid_poses": dropped})
    with naming(kfile):
        color = Intrinsics.from_K(K, w, h)
    return Scan(color, frames, meta, root=path, depth_intrinsics=None if depth_intr in (None, color) else depth_intr)

