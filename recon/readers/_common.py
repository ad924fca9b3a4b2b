"""Small parsing helpers shared by the readers."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from recon.errors import ScanFormatError
from recon.io import read_depth_png, read_image
from recon.scan import Frame

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


def numbered_files(folder: Path, suffixes=IMAGE_SUFFIXES) -> list[Path]:
    """Files in `folder` with one of `suffixes`, sorted by the last number in the name (then by name)."""
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes]

    def key(p: Path):
        nums = re.findall(r"\d+", p.stem)
        return (int(nums[-1]) if nums else -1, p.name)

    return sorted(files, key=key)


def frame_number(path: Path) -> int | None:
    nums = re.findall(r"\d+", path.stem)
    return int(nums[-1]) if nums else None


def load_matrix(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """Whitespace-separated numbers of exactly `shape`; extra leading rows/cols are not accepted."""
    try:
        mat = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except (ValueError, OSError) as exc:
        raise ScanFormatError(f"{path}: cannot parse matrix ({exc})") from None
    if mat.size == shape[0] * shape[1] and mat.shape != shape:
        mat = mat.reshape(shape)
    if mat.shape != shape:
        raise ScanFormatError(f"{path}: matrix has shape {mat.shape}, expected {shape[0]}x{shape[1]}")
    return mat


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file."""
    img = read_image(path)
    return img.shape[1], img.shape[0]


def depth_size(path: Path) -> tuple[int, int]:
    """(width, height) of a depth image file."""
    depth = read_depth_png(path)
    return depth.shape[1], depth.shape[0]


def require_dir(path: Path, what: str) -> Path:
    if not path.is_dir():
        raise ScanFormatError(f"{path}: missing {what} folder")
    return path


def require_same_count(a: list, b: list, what_a: str, what_b: str, where: Path) -> None:
    if len(a) != len(b):
        raise ScanFormatError(f"{where}: {len(a)} {what_a} but {len(b)} {what_b}")
    if not a:
        raise ScanFormatError(f"{where}: no {what_a} found")


def numbered_frames(folder: Path, images: list[Path], poses: list[np.ndarray]) -> list[Frame]:
    """Frames from parallel lists of images and poses, with `depth/` PNGs matched by order when present.

    Names come from the number in each image's file name (zero-padded), so outputs line up with the input.
    """
    depth_dir = folder / "depth"
    depths = numbered_files(depth_dir, (".png",)) if depth_dir.is_dir() else []
    if depths and len(depths) != len(images):
        raise ScanFormatError(f"{folder}: {len(images)} images but {len(depths)} depth maps")
    return [Frame(name=f"{frame_number(img) if frame_number(img) is not None else i:06d}", camera_to_world=pose,
                  image_path=img, depth_path=depths[i] if depths else None, source_index=i)
            for i, (img, pose) in enumerate(zip(images, poses))]
