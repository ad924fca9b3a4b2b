"""DeepVideoMVS / SimpleRecon style: images/, depth/ (optional), poses.txt, K.txt.

`poses.txt` has one row-major 4x4 camera-to-world matrix per line (16 numbers);
`K.txt` the 3x3 intrinsics of the images.
"""
from pathlib import Path

import numpy as np

from recon.errors import ScanFormatError, naming
from recon.scan import Intrinsics, Scan, ScanMetadata

from ._common import image_size, load_matrix, numbered_files, numbered_frames, require_dir, require_same_count

NAME = "simplerecon"


def detect(path: Path) -> bool:
    return path.is_dir() and (path / "poses.txt").is_file() and (path / "K.txt").is_file()


def read(path: Path) -> Scan:
    images = numbered_files(require_dir(path / "images", "images"))
    try:
        rows = np.loadtxt(path / "poses.txt", dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise ScanFormatError(f"{path / 'poses.txt'}: cannot parse ({exc})") from None
    if rows.shape[1] != 16:
        raise ScanFormatError(f"{path / 'poses.txt'}: {rows.shape[1]} numbers per line, expected 16 (row-major 4x4)")
    poses = list(rows.reshape(-1, 4, 4))
    require_same_count(images, poses, "images", "poses", path)
    K = load_matrix(path / "K.txt", (3, 3))
    w, h = image_size(images[0])
    frames = numbered_frames(path, images, poses)
    with naming(path / "K.txt"):
        intr = Intrinsics.from_K(K, w, h)
    return Scan(intr, frames, ScanMetadata(metric_scale=True, source_format=NAME), root=path)
