"""File I/O shared by every stage: images, depth maps, atomic writes.

Images are uint8 RGB in memory (OpenCV's BGR is converted here, at the edge).
Depth is float32 metres in memory, 0 = invalid; on disk a 16-bit PNG in
millimetres (predicted maps with an 8-bit confidence PNG beside them).
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from .errors import ReconError

MM_PER_M = 1000.0
DEPTH_SUFFIX, CONFIDENCE_SUFFIX = ".png", ".conf.png"  # a stored prediction: `<frame name><suffix>`
CONFIDENCE_STEPS = 255  # a stored confidence map's levels (uint8)
# zlib level of stored predictions: 11 % smaller than OpenCV's fast default for ~30 ms a map, nothing
# beside seconds of inference (scan depth, written by the thousand on convert, keeps the fast level)
PREDICTION_PNG_LEVEL = 6
log = logging.getLogger(__name__)
_UMASK = os.umask(0)
os.umask(_UMASK)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read a color image as uint8 RGB (H, W, 3)."""
    bgr = _decode(Path(path), cv2.IMREAD_COLOR, "image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _decode(path: Path, flags: int, what: str) -> np.ndarray:
    """cv2.imread with one error of ours for a missing, empty or broken file.

    libpng and libjpeg print their complaints straight to the process's stderr; they are caught
    here and folded into the one message (or, when the file still decodes, one warning)."""
    if not path.is_file():
        raise ReconError(f"{path}: {what} file not found")
    if path.stat().st_size == 0:
        raise ReconError(f"{path}: empty {what} file (0 bytes)")
    with captured_stderr() as complaints:
        array = cv2.imread(str(path), flags)
    if array is None and not complaints and _truncated_png(path):
        complaints = ["truncated: the PNG has no end chunk"]
    said = f" ({'; '.join(complaints)})" if complaints else ""
    if array is None:
        raise ReconError(f"{path}: unreadable {what}{said}")
    if complaints:
        log.warning("%s: damaged %s%s", path, what, said)
    return array


def open_video(path: str | os.PathLike, advice: str = "") -> cv2.VideoCapture:
    """An opened cv2.VideoCapture, or one ReconError (with what FFmpeg said, which it would print raw)."""
    with captured_stderr() as complaints:
        cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        said = "; ".join(c.split("] ", 1)[-1] for c in complaints) or "empty, damaged or unsupported codec"
        raise ReconError(f"{path}: cannot be opened as a video ({said}){advice}")
    return cap


def _truncated_png(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(8)
        fh.seek(max(0, path.stat().st_size - 12))
        return head == b"\x89PNG\r\n\x1a\n" and b"IEND" not in fh.read()


@contextlib.contextmanager
def captured_stderr() -> Iterator[list[str]]:
    """Collect what native libraries (libpng, libjpeg, FFmpeg) write to file descriptor 2 meanwhile.

    Their raw lines would break the one-line error contract of the CLI; callers put them into their
    own message. Yields a list that holds the non-empty lines once the block ends."""
    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
            try:
                yield lines
            finally:
                os.dup2(saved, 2)
                sink.seek(0)
                text = sink.read().decode(errors="replace")
                lines.extend(ln.strip() for ln in text.splitlines() if ln.strip())
    finally:
        os.close(saved)


EXIF_ORIENTATION_TAG = 0x0112
EXIF_IFD, FOCAL_35MM_TAG = 0x8769, 0xA405  # EXIF's sub-IFD and its FocalLengthIn35mmFilm tag


def write_image(path: str | os.PathLike, rgb: np.ndarray, jpeg_quality: int = 95,
                focal_35mm: int | None = None) -> None:
    """Write a uint8 RGB image atomically (format from the suffix); a JPEG with `focal_35mm` carries it as
    EXIF FocalLengthIn35mmFilm, as a phone's photo does."""
    path = Path(path)
    jpeg = path.suffix.lower() in (".jpg", ".jpeg")
    if jpeg and focal_35mm is not None:
        from PIL import Image

        exif = Image.Exif()
        exif.get_ifd(EXIF_IFD)[FOCAL_35MM_TAG] = int(focal_35mm)
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="JPEG", quality=jpeg_quality, exif=exif)
        write_bytes_atomic(path, buf.getvalue())
        return
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if jpeg else []
    ok, buf = cv2.imencode(path.suffix, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
    if not ok:
        raise ReconError(f"{path}: could not encode image")
    write_bytes_atomic(path, buf.tobytes())


def image_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """(width, height) as `read_image` returns the image (EXIF orientation applied), from its header only;
    None when it cannot be read."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            width, height = image.size
            turned = image.getexif().get(EXIF_ORIENTATION_TAG, 1) in (5, 6, 7, 8)  # a quarter turn
    except (OSError, UnidentifiedImageError):
        return None
    return (height, width) if turned else (width, height)


def read_exif_focal_35mm(path: str | os.PathLike) -> float | None:
    """A photo's 35 mm-equivalent focal length in mm (EXIF FocalLengthIn35mmFilm, which phones write), or None."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            value = float(image.getexif().get_ifd(EXIF_IFD).get(FOCAL_35MM_TAG, 0))
    except (OSError, UnidentifiedImageError, ValueError, TypeError):  # unreadable, or a tag that is not a number
        return None
    return value if np.isfinite(value) and value > 0 else None


def read_depth_png(path: str | os.PathLike, units_per_metre: float = MM_PER_M) -> np.ndarray:
    """Read a 16-bit depth PNG as float32 metres (0 = invalid)."""
    path = Path(path)
    raw = _decode(path, cv2.IMREAD_UNCHANGED, "depth image")
    if raw.ndim != 2:
        raise ReconError(f"{path}: depth image has {raw.shape[2]} channels, expected one")
    if raw.dtype not in (np.uint16, np.uint8, np.int32, np.float32):
        raise ReconError(f"{path}: unsupported depth image type {raw.dtype}")
    return (raw.astype(np.float32) / np.float32(units_per_metre)).astype(np.float32)


def depth_to_png_array(depth_m: np.ndarray) -> np.ndarray:
    """float metres -> uint16 millimetres (clipped to 65.535 m, invalid stays 0)."""
    mm = np.nan_to_num(depth_m.astype(np.float64) * MM_PER_M, nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.round(mm), 0, 65535).astype(np.uint16)


def write_depth_png(path: str | os.PathLike, depth_m: np.ndarray, compression: int = 1) -> None:
    """Write float32 metres as a 16-bit millimetre PNG, atomically (`compression`: zlib level 0-9)."""
    _write_png(Path(path), depth_to_png_array(depth_m), compression, "depth")


def _write_png(path: Path, array: np.ndarray, compression: int, what: str) -> None:
    ok, buf = cv2.imencode(".png", array, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise ReconError(f"{path}: could not encode {what}")
    write_bytes_atomic(path, buf.tobytes())


def save_depth_map(folder: str | os.PathLike, name: str, depth_m: np.ndarray,
                   confidence: np.ndarray | None = None) -> None:
    """Store one predicted depth map as `<name>.png` (uint16 millimetres) [+ `<name>.conf.png`: confidence in
    [0, 1] in steps of 1/255, written last], the ScanNet / 7-Scenes convention any tool reads.

    A prediction holds nothing below a millimetre, and one losslessly compressed map on the stored grid is
    about the size of the input frame (float arrays beside it were 20-50 times that). Files of the older
    float layout are removed, so that readers never prefer them over the new map.
    """
    folder = Path(folder)
    check_file_name(name)  # a scan built in memory has not been through Scan.validate
    folder.mkdir(parents=True, exist_ok=True)
    for stale in (f"{name}.npy", f"{name}.conf.npy"):
        remove_path(folder / stale)
    write_depth_png(folder / f"{name}{DEPTH_SUFFIX}", depth_m, PREDICTION_PNG_LEVEL)
    if confidence is not None:
        steps = np.round(np.clip(np.nan_to_num(confidence), 0.0, 1.0) * CONFIDENCE_STEPS).astype(np.uint8)
        _write_png(folder / f"{name}{CONFIDENCE_SUFFIX}", steps, PREDICTION_PNG_LEVEL, "confidence")


def load_depth_map(folder: str | os.PathLike, name: str) -> np.ndarray:
    """Read a depth map as float32 metres: `<name>.npy` (float, as other tools write predictions) or `.png` (mm)."""
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
    png = folder / f"{name}{DEPTH_SUFFIX}"
    if png.is_file():
        return read_depth_png(png)
    raise ReconError(f"{folder}: no depth map for frame {name} ({name}.npy or {name}.png)")


def load_confidence_map(folder: str | os.PathLike, name: str) -> np.ndarray | None:
    """The confidence map (float32 in [0, 1]) stored beside a depth map (`.conf.png`, or a float `.conf.npy`)."""
    folder = Path(folder)
    png, npy = folder / f"{name}{CONFIDENCE_SUFFIX}", folder / f"{name}.conf.npy"
    if png.is_file():
        return _decode(png, cv2.IMREAD_UNCHANGED, "confidence image").astype(np.float32) / CONFIDENCE_STEPS
    return np.load(npy).astype(np.float32) if npy.is_file() else None


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write a file through a temporary sibling and a rename, so readers never see half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


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

    An existing folder at `path` is replaced only after the new one is finished. The temporary
    names carry the process id, so what a killed process left behind is removed by the next one.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ReconError(f"{path}: exists and is not a folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_temporaries(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-{os.getpid()}-", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_UMASK)
    try:
        yield tmp
    except BaseException:
        remove_path(tmp)
        raise
    replace_dir(tmp, path)


def replace_dir(new: Path, path: Path) -> None:
    """Move the finished folder `new` to `path`, removing what was there (a link itself, never its target)."""
    old = None
    if path.exists() or path.is_symlink():
        old = path.with_name(f".{path.name}.old-{os.getpid()}-")
        os.replace(path, old)
    os.replace(new, path)
    if old is not None:
        remove_path(old)


def _remove_stale_temporaries(path: Path) -> None:
    """Delete the temporary and replaced folders of `path` whose process is gone (killed mid-write)."""
    for kind in ("tmp", "old"):
        prefix = f".{path.name}.{kind}-"
        for entry in path.parent.iterdir():
            pid = entry.name[len(prefix):].split("-")[0] if entry.name.startswith(prefix) else ""
            if pid.isdigit() and not _process_alive(int(pid)):
                log.info("removing %s, left by an interrupted run", entry)
                remove_path(entry)


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


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


def check_file_name(name: str, what: str = "frame name") -> str:
    """`name` if it can name one file inside an output folder, else a ReconError.

    Frame names become file names in every stage's output; a separator, `..`, an absolute
    path or a control character would let a scan's metadata write outside the run folder."""
    text = str(name)
    if (not text or text in (".", "..") or "/" in text or "\\" in text or any(ord(c) < 32 for c in text)
            or len(text.encode()) > 200):
        raise ReconError(f"{what} {text!r} cannot be a file name (no path separators, '..', control "
                         "characters, at most 200 bytes)")
    return text


def own_folder(path: str | os.PathLike) -> Path:
    """`path` as a real folder: a link there is removed (never its target) and the folder made.

    For folders a stage empties and refills: cleaning through a planted link would delete the
    files it points to."""
    path = Path(path)
    if path.is_symlink():
        log.warning("%s: was a link (to %s); replaced by a folder of its own", path, os.readlink(path))
        path.unlink()
    path.mkdir(parents=True, exist_ok=True)
    return path


METADATA_SUFFIXES = (".json", ".txt", ".csv", ".log", ".bin", ".yaml", ".yml")
METADATA_HASH_LIMIT = 64 << 20  # larger metadata files (a COLMAP points3D.bin) count by size and time alone


def fingerprint_input(path: str | os.PathLike, exclude: str | os.PathLike | None = None) -> dict:
    """What a cached result read from `path` depends on: the resolved absolute path, every file's size and
    modification time, and the content of its metadata files (poses, intrinsics, scan.json).

    A replaced image or an edited pose changes it; a relative and an absolute path to the same input do not.
    Files under `exclude` (a run folder kept inside its input) are left out."""
    root = Path(path).resolve()
    skip = Path(exclude).resolve() if exclude is not None else None
    if root.is_file():
        files = [root]
    elif root.is_dir():
        files = sorted(p for p in root.rglob("*") if p.is_file() and not (skip and p.is_relative_to(skip)))
    else:
        raise ReconError(f"{path}: no such file or folder")
    digest = hashlib.sha1()
    for p in files:
        st = p.stat()
        digest.update(f"{p.relative_to(root) if p != root else p.name}|{st.st_size}|{st.st_mtime_ns}\n".encode())
        if p.suffix.lower() in METADATA_SUFFIXES and st.st_size <= METADATA_HASH_LIMIT:
            digest.update(hashlib.sha1(p.read_bytes()).digest())
    return {"path": str(root), "files": len(files), "digest": digest.hexdigest()[:16]}
