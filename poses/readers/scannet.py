"""ScanNet export layout (the SensReader output): color/, depth/, pose/, intrinsic/.

`pose/N.txt` is camera-to-world; `intrinsic/intrinsic_color.txt` (4x4) describes the
color images; depth is millimetres at its own (smaller) resolution and is resampled
onto the color grid by the Scan. Frames with invalid (inf/NaN) poses are dropped, as
ScanNet marks lost tracking that way.
"""
from pathlib import Path

import numpy as np

from recon.errors import ScanFormatError
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

from ._common import frame_number, image_size, load_matrix, numbered_files, require_dir

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
    frames, dropped = [], 0
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
                            depth_path=depth if depth.is_file() else None, source_index=n))
    if not frames:
        raise ScanFormatError(f"{path}: every pose is invalid")
    meta = ScanMetadata(metric_scale=True, source_format=NAME, extra={"dropped_invalid_poses": dropped})
    return Scan(Intrinsics.from_K(K, w, h), frames, meta, root=path)
