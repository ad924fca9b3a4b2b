"""File I/O shared by every stage: images, depth maps, atomic writes.

Images are uint8 RGB in memory (OpenCV's BGR is converted here, at the edge).
Depth is float32 metres in memory, 0 = invalid; on disk a 16-bit PNG in
millimetres, with a float32 `.npy` beside it where precision matters.
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from .errors import ReconError

MM_PER_M = 1000.0
_UMASK = os.umask(0)
os.umask(_UMASK)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read a color image as uint8 RGB (H, W, 3)."""
    path = Path(path)
    if not path.is_file():
        raise ReconError(f"{path}: image file not found")
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ReconError(f"{path}: unreadable image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def write_image(path: str | os.PathLike, rgb: np.ndarray, jpeg_quality: int = 95) -> None:
    """Write a uint8 RGB image atomically (format from the suffix)."""
    path = Path(path)
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if path.suffix.lower() in (".jpg", ".jpeg") else []
    ok, buf = cv2.imencode(path.suffix, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
    if not ok:
        raise ReconError(f"{path}: could not encode image")
    write_bytes_atomic(path, buf.tobytes())


def read_depth_png(path: str | os.PathLike, units_per_metre: float = MM_PER_M) -> np.ndarray:
    """Read a 16-bit depth PNG as float32 metres (0 = invalid)."""
    path = Path(path)
    if not path.is_file():
        raise ReconError(f"{path}: depth file not found")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ReconError(f"{path}: unreadable depth image")
    if raw.ndim != 2:
        raise ReconError(f"{path}: depth image has {raw.shape[2]} channels, expected one")
    if raw.dtype not in (np.uint16, np.uint8, np.int32, np.float32):
        raise ReconError(f"{path}: unsupported depth image type {raw.dtype}")
    return (raw.astype(np.float32) / np.float32(units_per_metre)).astype(np.float32)


def depth_to_png_array(depth_m: np.ndarray) -> np.ndarray:
    """float metres -> uint16 millimetres (clipped to 65.535 m, invalid stays 0)."""
    mm = np.nan_to_num(depth_m.astype(np.float64) * MM_PER_M, nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.round(mm), 0, 65535).astype(np.uint16)


def write_depth_png(path: str | os.PathLike, depth_m: np.ndarray) -> None:
    """Write float32 metres as a 16-bit millimetre PNG, atomically."""
    ok, buf = cv2.imencode(".png", depth_to_png_array(depth_m))
    if not ok:
        raise ReconError(f"{path}: could not encode depth")
    write_bytes_atomic(Path(path), buf.tobytes())


def save_depth_map(folder: str | os.PathLike, name: str, depth_m: np.ndarray,
                   confidence: np.ndarray | None = None) -> None:
    """Store one predicted depth map as `<name>.npy` (float32 m) + `<name>.png` (mm) [+ `<name>.conf.npy`]."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    save_npy_atomic(folder / f"{name}.npy", depth_m.astype(np.float32))
    write_depth_png(folder / f"{name}.png", depth_m)
    if confidence is not None:
        save_npy_atomic(folder / f"{name}.conf.npy", confidence.astype(np.float32))


def load_depth_map(folder: str | os.PathLike, name: str) -> np.ndarray:
    """Read a depth map written by `save_depth_map` (prefers the exact `.npy`)."""
    folder = Path(folder)
    npy = folder / f"{name}.npy"
    if npy.is_file():
        try:
            depth = np.load(npy)
        except Exception as exc:  # corrupt or truncated file
            raise ReconError(f"{npy}: unreadable depth array ({exc})") from None
        if depth.ndim != 2:
            raise ReconError(f"{npy}: depth array has shape {depth.shape}, expected (H, W)")
        return depth.astype(np.float32)
    png = folder / f"{name}.png"
    if png.is_file():
        return read_depth_png(png)
    raise ReconError(f"{folder}: no depth map for frame {name} ({name}.npy or {name}.png)")


def load_confidence_map(folder: str | os.PathLike, name: str) -> np.ndarray | None:
    """The confidence map stored beside a depth map, or None."""
    path = Path(folder) / f"{name}.conf.npy"
    return np.load(path).astype(np.float32) if path.is_file() else None


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write a file through a temporary sibling and a rename, so readers never see half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def save_npy_atomic(path: Path, array: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, array)


def write_json_atomic(path: str | os.PathLike, obj) -> None:
    write_bytes_atomic(Path(path), (json.dumps(obj, indent=2) + "\n").encode())


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success rename it over `path`, on failure delete it.

    The temporary keeps the suffix so libraries that pick a format from it (Open3D, trimesh) work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.fchmod(fd, 0o666 & ~_UMASK)  # mkstemp makes private files; outputs get the usual permissions
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Build a folder under a temporary name and move it into place only when complete.

    An existing folder at `path` is replaced only after the new one is finished.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ReconError(f"{path}: exists and is not a folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_UMASK)
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if path.exists():
        old = path.with_name(f".{path.name}.old-{os.getpid()}")
        os.replace(path, old)
    os.replace(tmp, path)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def working_size(width: int, height: int, max_size: int) -> tuple[int, int]:
    """(w, h) with the long side at most `max_size`, aspect kept, even dimensions."""
    scale = min(1.0, max_size / max(width, height))
    return max(2, int(round(width * scale / 2)) * 2), max(2, int(round(height * scale / 2)) * 2)


def remove_path(path: str | os.PathLike) -> None:
    """Delete a file or folder without ever following a link: a link is removed itself, never its target."""
    path = Path(path)
    if path.is_symlink() or path.is_file():
        path.unlink(missing_ok=True)
    elif path.is_dir():
        shutil.rmtree(path)  # rmtree unlinks links inside the tree and does not descend into them
