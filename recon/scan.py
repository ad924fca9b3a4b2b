"""The canonical scan: frames with camera-to-world poses, shared intrinsics, optional GT depth.

Every stage reads and writes this one type. A `Scan` is lazy: it holds file
paths (or in-memory arrays) and loads an image or depth map when asked, at the
scan's output size, so slicing and resizing cost nothing until pixels are read.

On disk (`save_scan` / `load_scan`) a scan is a folder:

    scan.json            intrinsics, metadata, per-frame pose and file names
    images/<name>.jpg    uint8 RGB
    depth/<name>.png     optional GT depth, uint16 millimetres (0 = invalid)
"""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from . import io as rio
from .errors import ReconError, ScanFormatError, naming
from .geometry import check_pose, intrinsic_matrix

SCAN_FILE = "scan.json"
SCAN_VERSION = 1


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of images `width` x `height` pixels (pixel centres at integer coordinates)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self):
        for name in ("fx", "fy", "cx", "cy"):  # plain floats, so JSON and reprs stay clean
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("width", "height"):
            object.__setattr__(self, name, int(getattr(self, name)))
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(np.isfinite(v) for v in vals) or self.fx <= 0 or self.fy <= 0:
            raise ReconError(f"invalid intrinsics: focal lengths must be positive and finite ({self})")
        if self.width <= 0 or self.height <= 0:
            raise ReconError(f"invalid intrinsics: image size {self.width}x{self.height}")

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return intrinsic_matrix(self.fx, self.fy, self.cx, self.cy)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)."""
        return self.width, self.height

    def resized(self, width: int, height: int) -> "Intrinsics":
        """Intrinsics of the same camera after resizing the image to width x height."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                          (self.cy + 0.5) * sy - 0.5, int(width), int(height))

    def cropped(self, left: int, top: int, width: int, height: int) -> "Intrinsics":
        """Intrinsics after cropping the window [left, left+width) x [top, top+height)."""
        if left < 0 or top < 0 or left + width > self.width or top + height > self.height:
            raise ReconError(f"crop {width}x{height}+{left}+{top} outside image {self.width}x{self.height}")
        return Intrinsics(self.fx, self.fy, self.cx - left, self.cy - top, int(width), int(height))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Intrinsics":
        try:
            return cls(float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]),
                       int(d["width"]), int(d["height"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ReconError(f"invalid intrinsics entry {d!r}: {exc}") from None

    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int) -> "Intrinsics":
        K = np.asarray(K, dtype=np.float64)
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], int(width), int(height))


@dataclass
class Frame:
    """One frame: where its pixels are and where its camera was.

    `name` is a stable id (kept through slicing) that names the frame's files in
    every stage's output. Pixels come from a file path or from an in-memory array.
    """

    name: str
    camera_to_world: np.ndarray
    image_path: Path | None = None
    depth_path: Path | None = None
    depth_units_per_metre: float = rio.MM_PER_M
    timestamp: float | None = None
    source_index: int | None = None
    image_array: np.ndarray | None = field(default=None, repr=False)
    depth_array: np.ndarray | None = field(default=None, repr=False)

    @property
    def has_depth(self) -> bool:
        return self.depth_path is not None or self.depth_array is not None


@dataclass
class ScanMetadata:
    """What a scan is and how far its numbers can be trusted."""

    metric_scale: bool = True  # False for SfM from plain video: units are arbitrary
    source: str = ""  # where it came from (path, generator, ...)
    source_format: str = ""  # reader that produced it
    depth_range: tuple[float, float] | None = None  # metres (or scan units) the scene spans
    gt_mesh: str | None = None  # path of a ground-truth mesh, relative to the scan folder when stored
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["depth_range"] = list(self.depth_range) if self.depth_range else None
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ScanMetadata":
        dr = d.get("depth_range")
        return cls(bool(d.get("metric_scale", True)), str(d.get("source", "")), str(d.get("source_format", "")),
                   tuple(float(x) for x in dr) if dr else None, d.get("gt_mesh"), dict(d.get("extra", {})))


@dataclass
class Scan:
    """Frames + shared intrinsics + metadata, with optional distortion and output size.

    `source_intrinsics` describe the stored images; `intrinsics` (a property) the
    images this scan hands out, after undistortion and any `resized` call.
    """

    source_intrinsics: Intrinsics
    frames: list[Frame]
    metadata: ScanMetadata = field(default_factory=ScanMetadata)
    root: Path | None = None
    distortion: np.ndarray | None = None  # OpenCV (k1, k2, p1, p2[, k3...]) of the stored images
    output_size: tuple[int, int] | None = None  # (width, height) handed out; None = stored size
    crop: tuple[int, int, int, int] | None = None  # (left, top, width, height) of the output-size image handed out
    # Camera of the stored depth maps when it is not the colour camera (Kinect-style sensors): same optical
    # centre and orientation, other focal length / principal point / size. Depth is resampled onto the colour camera.
    depth_intrinsics: Intrinsics | None = None

    # -- shape -------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.frames)

    @property
    def intrinsics(self) -> Intrinsics:
        intr = self.source_intrinsics if self.output_size is None else self.source_intrinsics.resized(*self.output_size)
        return intr if self.crop is None else intr.cropped(*self.crop)

    @property
    def names(self) -> list[str]:
        return [f.name for f in self.frames]

    @property
    def camera_to_world(self) -> np.ndarray:
        """All poses, (N, 4, 4) float64."""
        return np.stack([f.camera_to_world for f in self.frames]) if self.frames else np.zeros((0, 4, 4))

    @property
    def has_depth(self) -> bool:
        return bool(self.frames) and all(f.has_depth for f in self.frames)

    def index_of(self, name: str) -> int:
        for i, f in enumerate(self.frames):
            if f.name == name:
                return i
        raise KeyError(name)

    # -- views -------------------------------------------------------------------------------
    def select(self, start: int = 0, stride: int = 1, max_frames: int | None = None) -> "Scan":
        """Frames start, start+stride, ... (at most max_frames of them). Names are kept."""
        if start < 0 or stride < 1 or (max_frames is not None and max_frames < 1):
            raise ReconError(f"invalid frame selection: start={start} stride={stride} max_frames={max_frames}")
        frames = self.frames[start::stride]
        if max_frames is not None:
            frames = frames[:max_frames]
        if not frames:
            raise ReconError(f"frame selection start={start} stride={stride} leaves no frames of {len(self)}")
        return dataclasses.replace(self, frames=list(frames))

    def subset(self, indices) -> "Scan":
        return dataclasses.replace(self, frames=[self.frames[i] for i in indices])

    def resized(self, width: int, height: int) -> "Scan":
        """The same scan handing out images of width x height (intrinsics follow)."""
        if width <= 0 or height <= 0:
            raise ReconError(f"invalid image size {width}x{height}")
        if self.crop is not None:
            raise ReconError("a cropped scan cannot be resized again: resize first, then crop")
        return dataclasses.replace(self, output_size=(int(width), int(height)))

    def cropped(self, left: int, top: int, width: int, height: int) -> "Scan":
        """The same scan handing out the window [left, left+width) x [top, top+height) of its images."""
        self.intrinsics.cropped(left, top, width, height)  # validates the window
        return dataclasses.replace(self, crop=(int(left), int(top), int(width), int(height)))

    # -- pixels ------------------------------------------------------------------------------
    def image(self, i: int) -> np.ndarray:
        """uint8 RGB (H, W, 3) of frame i at the output size."""
        f = self.frames[i]
        img = f.image_array if f.image_array is not None else rio.read_image(self._path(f.image_path, f.name))
        src = self.source_intrinsics
        if img.shape[:2] != (src.height, src.width):
            raise ReconError(f"{self.image_file(i) if f.image_path else f.name}: image is "
                             f"{img.shape[1]}x{img.shape[0]}, "
                             f"scan intrinsics say {src.width}x{src.height}")
        img = self._undistort(img, cv2.INTER_LINEAR)
        return self._resize(img, cv2.INTER_AREA)

    def image_file(self, i: int) -> Path:
        """The file frame i's image is read from (before any undistortion, resizing or crop)."""
        return self._path(self.frames[i].image_path, self.frames[i].name)

    def depth(self, i: int) -> np.ndarray | None:
        """float32 metres (H, W) of frame i at the output size, or None without GT depth."""
        f = self.frames[i]
        if f.depth_array is not None:
            d = f.depth_array.astype(np.float32)
        elif f.depth_path is not None:
            d = rio.read_depth_png(self._path(f.depth_path, f.name), f.depth_units_per_metre)
        else:
            return None
        src = self.source_intrinsics
        if self.depth_intrinsics is not None:
            d = resample_depth(d, self.depth_intrinsics, src)
        elif d.shape != (src.height, src.width):
            raise ReconError(f"{self._path(f.depth_path, f.name) if f.depth_path else f.name}: depth is "
                             f"{d.shape[1]}x{d.shape[0]} but images are "
                             f"{src.width}x{src.height}, and the scan gives no depth camera intrinsics")
        d = self._undistort(d, cv2.INTER_NEAREST)
        return self._resize(d, cv2.INTER_NEAREST)

    def _path(self, p: Path | None, name: str) -> Path:
        if p is None:
            raise ReconError(f"frame {name}: no image file")
        p = Path(p)
        return p if p.is_absolute() or self.root is None else self.root / p

    def _undistort(self, img: np.ndarray, interp: int) -> np.ndarray:
        if self.distortion is None or not np.any(self.distortion):
            return img
        K = self.source_intrinsics.K
        h, w = img.shape[:2]
        map1, map2 = cv2.initUndistortRectifyMap(K, np.asarray(self.distortion, np.float64), None, K,
                                                 (w, h), cv2.CV_32FC1)
        return cv2.remap(img, map1, map2, interp)

    def _resize(self, img: np.ndarray, interp: int) -> np.ndarray:
        if self.output_size is not None and self.output_size != (img.shape[1], img.shape[0]):
            if interp == cv2.INTER_AREA and (self.output_size[0] > img.shape[1]):
                interp = cv2.INTER_LINEAR
            img = cv2.resize(img, self.output_size, interpolation=interp)
        if self.crop is not None:
            left, top, w, h = self.crop
            img = np.ascontiguousarray(img[top:top + h, left:left + w])
        return img

    def validate(self) -> "Scan":
        """Check poses (shape, finite, rigid), names (unique, usable as file names) and that ground-truth
        depth is all or nothing (one missing map would silently turn off depth scoring); returns self.

        Every reader's scan passes here, so this is the one place frame names are checked before
        stages name their output files by them."""
        where = self.root or "scan"
        if not self.frames:
            raise ReconError(f"{where}: scan has no frames")
        seen = set()
        for f in self.frames:
            check_pose(f.camera_to_world, f"{where} frame {f.name}")
            rio.check_file_name(f.name, f"{where}: frame name")
            if f.name in seen:
                raise ReconError(f"{where}: duplicate frame name {f.name}")
            seen.add(f.name)
        self._check_depth_files()
        return self

    def _check_depth_files(self) -> None:
        with_depth = [f for f in self.frames if f.has_depth]
        if with_depth and len(with_depth) < len(self.frames):
            lacking = next(f for f in self.frames if not f.has_depth)
            raise ReconError(f"{self.root or 'scan'}: frame {lacking.name} has no depth map while {len(with_depth)} "
                             f"of {len(self.frames)} frames do (add it, or leave the frame out)")
        for f in with_depth:
            if f.depth_array is None and not self._path(f.depth_path, f.name).is_file():
                raise ReconError(f"{self._path(f.depth_path, f.name)}: depth map of frame {f.name} is missing")


def resample_depth(depth_m: np.ndarray, depth_camera: Intrinsics, color_camera: Intrinsics) -> np.ndarray:
    """Depth seen by `depth_camera` -> the same depth on `color_camera`'s pixel grid.

    Both cameras share optical centre and orientation, so a colour pixel's ray meets the depth image at
    a scaled position and z is unchanged; nearest sampling keeps invalid (0) pixels from blending in.
    (H_d, W_d) -> (H_c, W_c); colour pixels outside the depth camera's view get 0.
    """
    if depth_m.shape != (depth_camera.height, depth_camera.width):
        raise ReconError(f"depth map is {depth_m.shape[1]}x{depth_m.shape[0]}, its camera says "
                         f"{depth_camera.width}x{depth_camera.height}")
    u = np.arange(color_camera.width, dtype=np.float32)
    v = np.arange(color_camera.height, dtype=np.float32)
    map_u = (u - color_camera.cx) * np.float32(depth_camera.fx / color_camera.fx) + np.float32(depth_camera.cx)
    map_v = (v - color_camera.cy) * np.float32(depth_camera.fy / color_camera.fy) + np.float32(depth_camera.cy)
    map_u, map_v = np.meshgrid(map_u, map_v)
    return cv2.remap(depth_m, map_u, map_v, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


# -- canonical folder ------------------------------------------------------------------------

def save_scan(scan: Scan, out_dir: str | os.PathLike, image_ext: str = ".jpg",
              gt_mesh_src: str | os.PathLike | None = None, progress=None) -> Path:
    """Write `scan` as a canonical folder (atomically: the folder appears only when complete).

    Pixels are written at the scan's output size, undistorted; depth as millimetre PNG.
    `progress(i, n)` is called after each frame when given.
    """
    out_dir = Path(out_dir)
    scan.validate()  # frame names become file names below
    intr = scan.intrinsics
    with rio.atomic_dir(out_dir) as tmp:
        frames_json = []
        for i, f in enumerate(scan.frames):
            img_rel = f"images/{f.name}{image_ext}"
            rio.write_image(tmp / img_rel, scan.image(i))
            entry: dict[str, Any] = {"name": f.name, "image": img_rel,
                                     "camera_to_world": f.camera_to_world.tolist()}
            d = scan.depth(i)
            if d is not None:
                entry["depth"] = f"depth/{f.name}.png"
                rio.write_depth_png(tmp / entry["depth"], d)
            if f.timestamp is not None:
                entry["timestamp"] = f.timestamp
            if f.source_index is not None:
                entry["source_index"] = f.source_index
            frames_json.append(entry)
            if progress:
                progress(i + 1, len(scan))
        meta = dataclasses.replace(scan.metadata)
        mesh_src = gt_mesh_src or (scan._path(Path(meta.gt_mesh), "gt_mesh") if meta.gt_mesh else None)
        if mesh_src is not None:
            mesh_src = Path(mesh_src)
            target = tmp / ("gt_mesh" + mesh_src.suffix)
            target.write_bytes(mesh_src.read_bytes())
            meta.gt_mesh = target.name
        doc = {"version": SCAN_VERSION, "intrinsics": intr.to_dict(), "metadata": meta.to_dict(),
               "frames": frames_json}
        rio.write_json_atomic(tmp / SCAN_FILE, doc)
    return out_dir


def load_scan(path: str | os.PathLike) -> Scan:
    """Read a canonical scan folder (or its scan.json)."""
    path = Path(path)
    jpath = path if path.name == SCAN_FILE else path / SCAN_FILE
    if not jpath.is_file():
        raise ScanFormatError(f"{path}: no {SCAN_FILE} (not a canonical scan folder)")
    try:
        doc = json.loads(jpath.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ScanFormatError(f"{jpath}: invalid JSON ({exc})") from None
    root = jpath.parent
    if not isinstance(doc, dict) or doc.get("version") != SCAN_VERSION:
        version = doc.get("version") if isinstance(doc, dict) else None
        raise ScanFormatError(f"{jpath}: unsupported scan version {version!r}")
    try:
        with naming(jpath):
            intr = Intrinsics.from_dict(doc["intrinsics"])
        frames = []
        for k, e in enumerate(doc["frames"]):
            pose = check_pose(np.array(e["camera_to_world"], dtype=np.float64), f"{jpath} frame {e.get('name', k)}")
            frames.append(Frame(
                name=str(e["name"]), camera_to_world=pose, image_path=Path(e["image"]),
                depth_path=Path(e["depth"]) if e.get("depth") else None,
                timestamp=e.get("timestamp"), source_index=e.get("source_index")))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ScanFormatError(f"{jpath}: malformed entry ({exc!r})") from None
    meta = ScanMetadata.from_dict(doc.get("metadata", {}))
    return Scan(intr, frames, meta, root=root).validate()


def gt_mesh_path(scan: Scan) -> Path | None:
    """Absolute path of the scan's ground-truth mesh, if it names one that exists."""
    if not scan.metadata.gt_mesh:
        return None
    p = scan._path(Path(scan.metadata.gt_mesh), "gt_mesh")
    return p if p.is_file() else None
