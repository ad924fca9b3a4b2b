"""nerfstudio / NeRF `transforms.json` (Polycam, Record3D and other exporters write it too).

Poses are camera-to-world with OpenGL camera axes, converted here to OpenCV axes; the
principal point follows COLMAP's convention (pixel centres at +0.5) and is shifted by -0.5.
Intrinsics are shared (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`, or instant-ngp's
`camera_angle_x`) or per frame; per-frame values must agree within 1 % (ARKit
exporters jitter them slightly) and their median is used. OpenCV distortion
(`k1 k2 p1 p2 k3`) is kept and undone when images are read; fisheye is refused.
Optional `depth_file_path` PNGs are read as millimetres (`depth_unit_scale_factor`
overrides: metres per stored unit).

Scale: NeRF-style poses have no unit (instant-ngp and nerfstudio rescale scenes freely),
so a scan is metric only when the file says `"metric_scale": true` (our writer and
`recon synth` do); otherwise SfM-style normalisation rules apply downstream. Frames whose
image file is missing (exports often list more than they copy) are skipped with one
warning and counted in `metadata.extra["missing_images"]` (`recon info` shows it).
"""
from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np

from recon.errors import ScanFormatError, naming
from recon.geometry import opengl_to_opencv
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

from ._common import image_size

log = logging.getLogger(__name__)

NAME = "nerfstudio"
FILE = "transforms.json"
INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")


def detect(path: Path) -> bool:
    return (path.is_dir() and (path / FILE).is_file()) or (path.is_file() and path.suffix == ".json"
                                                          and path.name.startswith("transforms"))


def _frame_intrinsics(doc: dict, frame: dict, first_image: Path) -> tuple[float, ...]:
    src = {**doc, **{k: frame[k] for k in frame if k in INTRINSIC_KEYS or k == "camera_angle_x"}}
    w, h = src.get("w"), src.get("h")
    if w is None or h is None:
        w, h = image_size(first_image)
    if "fl_x" in src:
        fx = float(src["fl_x"])
        fy = float(src.get("fl_y", fx))
    elif "camera_angle_x" in src:
        fx = fy = 0.5 * float(w) / math.tan(0.5 * float(src["camera_angle_x"]))
    else:
        raise ScanFormatError(f"{FILE}: no focal length (fl_x or camera_angle_x)")
    cx = float(src.get("cx", float(w) / 2)) - 0.5
    cy = float(src.get("cy", float(h) / 2)) - 0.5
    return fx, fy, cx, cy, float(w), float(h)


def read(path: Path) -> Scan:
    jpath = path / FILE if path.is_dir() else path
    root = jpath.parent
    try:
        doc = json.loads(jpath.read_text())
        frames_doc = doc["frames"]
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ScanFormatError(f"{jpath}: invalid JSON ({exc})") from None
    except KeyError:
        raise ScanFormatError(f"{jpath}: no 'frames' list") from None
    if not frames_doc:
        raise ScanFormatError(f"{jpath}: 'frames' is empty")
    if str(doc.get("camera_model", "OPENCV")).upper() not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise ScanFormatError(f"{jpath}: camera_model {doc['camera_model']} is not supported (pinhole/OpenCV only)")
    depth_scale = float(doc.get("depth_unit_scale_factor", 1e-3))
    frames, intr_rows, missing = [], [], []
    for i, fd in enumerate(frames_doc):
        try:
            img = root / fd["file_path"]
            gl = np.array(fd["transform_matrix"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise ScanFormatError(f"{jpath}: frame {i}: {exc!r}") from None
        if gl.shape == (3, 4):
            gl = np.vstack([gl, [0, 0, 0, 1]])
        if gl.shape != (4, 4):
            raise ScanFormatError(f"{jpath}: frame {i}: transform_matrix has shape {gl.shape}, expected 4x4")
        if img.suffix == "":  # the original NeRF synthetic sets omit the extension
            img = next((img.with_suffix(s) for s in (".png", ".jpg") if img.with_suffix(s).is_file()), img)
        if not img.is_file():
            missing.append(fd["file_path"])
            continue
        intr_rows.append(_frame_intrinsics(doc, fd, img))
        depth = root / fd["depth_file_path"] if fd.get("depth_file_path") else None
        frames.append(Frame(name=img.stem, camera_to_world=opengl_to_opencv(gl), image_path=img, depth_path=depth,
                            depth_units_per_metre=1.0 / depth_scale, source_index=i,
                            timestamp=fd.get("timestamp")))
    if not frames:
        raise ScanFormatError(f"{jpath}: none of the {len(missing)} listed images exists (first: {missing[0]})")
    if missing:
        log.warning("%s: %d of %d listed images are missing and skipped (first: %s)", jpath, len(missing),
                    len(frames_doc), missing[0])
    rows = np.array(intr_rows)
    if np.any(rows[:, 4:] != rows[0, 4:]):
        raise ScanFormatError(f"{jpath}: frames have different image sizes; one size per scan is supported")
    med = np.median(rows, axis=0)
    if np.any(np.abs(rows[:, :4] - med[:4]) > 0.01 * med[0]):
        raise ScanFormatError(f"{jpath}: per-frame intrinsics differ by more than 1 %; one camera per scan is supported")
    dist = np.array([float(doc.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")])
    with naming(jpath):
        intr = Intrinsics(med[0], med[1], med[2], med[3], int(med[4]), int(med[5]))
    meta = ScanMetadata(metric_scale=doc.get("metric_scale") is True, source_format=NAME,
                        extra={"missing_images": len(missing)} if missing else {})
    return Scan(intr, frames, meta, root=root, distortion=dist if np.any(dist) else None)
