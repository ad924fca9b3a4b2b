"""COLMAP sparse model (cameras/images in .bin or .txt, read through pycolmap) with its image folder.

COLMAP stores world-to-camera poses and puts pixel centres at +0.5; both are converted
here (camera-to-world, centres at integer coordinates). Distorted camera models keep
their OpenCV coefficients on the Scan, which undistorts images when they are read.
The scale of a COLMAP model is arbitrary, so the scan says `metric_scale = False`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.errors import ScanFormatError, naming
from recon.geometry import world_to_camera_to_pose
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata

NAME = "colmap"
MODEL_PLACES = (".", "0", "sparse/0", "sparse", "colmap/sparse/0")


def _has_model(folder: Path) -> bool:
    return any((folder / f"cameras{ext}").is_file() and (folder / f"images{ext}").is_file() for ext in (".bin", ".txt"))


def find_model(path: Path) -> Path | None:
    return next((path / p for p in MODEL_PLACES if _has_model(path / p)), None)


def find_image_dir(path: Path, model_dir: Path) -> Path | None:
    for cand in (path / "images", model_dir.parent / "images", model_dir.parent.parent / "images", path / "input"):
        if cand.is_dir():
            return cand
    return None


def detect(path: Path) -> bool:
    return path.is_dir() and find_model(path) is not None


def camera_to_intrinsics(camera) -> tuple[Intrinsics, np.ndarray | None]:
    """pycolmap camera -> (pinhole intrinsics in our pixel convention, OpenCV distortion or None)."""
    p = np.asarray(camera.params, dtype=np.float64)
    model = camera.model_name if hasattr(camera, "model_name") else str(camera.model).split(".")[-1]
    if model == "SIMPLE_PINHOLE":
        fx = fy = p[0]; cx, cy = p[1], p[2]; dist = None
    elif model == "PINHOLE":
        fx, fy, cx, cy = p[:4]; dist = None
    elif model == "SIMPLE_RADIAL":
        fx = fy = p[0]; cx, cy = p[1], p[2]; dist = np.array([p[3], 0.0, 0.0, 0.0])
    elif model == "RADIAL":
        fx = fy = p[0]; cx, cy = p[1], p[2]; dist = np.array([p[3], p[4], 0.0, 0.0])
    elif model == "OPENCV":
        fx, fy, cx, cy = p[:4]; dist = p[4:8].copy()
    elif model == "FULL_OPENCV":
        fx, fy, cx, cy = p[:4]; dist = p[4:12].copy()
    else:
        raise ScanFormatError(f"COLMAP camera model {model} is not supported (use a pinhole or OpenCV-style model, "
                              "or undistort with COLMAP's image_undistorter first)")
    return Intrinsics(fx, fy, cx - 0.5, cy - 0.5, int(camera.width), int(camera.height)), dist


def _cam_from_world(image):
    cfw = image.cam_from_world
    return cfw() if callable(cfw) else cfw


def scan_from_reconstruction(reconstruction, image_dir: Path, source_format: str = NAME) -> Scan:
    """Convert a pycolmap.Reconstruction (registered images only) into a canonical Scan.

    All images must share one camera, as a video's frames do. Frames are ordered by image name.
    """
    image_dir = Path(image_dir).resolve()  # frames live under it; a relative one would be joined twice
    images = sorted((im for im in reconstruction.images.values() if im.has_pose), key=lambda im: im.name)
    if not images:
        raise ScanFormatError(f"{image_dir}: the COLMAP model has no registered images")
    cam_ids = {im.camera_id for im in images}
    if len(cam_ids) > 1:
        raise ScanFormatError(f"{image_dir}: the COLMAP model has {len(cam_ids)} cameras; one shared camera is supported")
    with naming(image_dir):
        intr, dist = camera_to_intrinsics(reconstruction.cameras[cam_ids.pop()])
    frames = []
    for im in images:
        cfw = _cam_from_world(im)
        rot = np.asarray(cfw.rotation.matrix(), dtype=np.float64)
        pose = world_to_camera_to_pose(rot, np.asarray(cfw.translation, dtype=np.float64))
        path = image_dir / im.name
        if not path.is_file():
            raise ScanFormatError(f"{path}: image named in the COLMAP model is missing")
        stem = Path(im.name).with_suffix("").as_posix().replace("/", "_")
        frames.append(Frame(name=stem, camera_to_world=pose, image_path=path, source_index=int(im.image_id)))
    meta = ScanMetadata(metric_scale=False, source_format=source_format,
                        extra={"registered": len(images), "colmap_images": len(reconstruction.images)})
    return Scan(intr, frames, meta, root=image_dir, distortion=dist)


def read(path: Path) -> Scan:
    import pycolmap

    model_dir = find_model(path)
    if model_dir is None:
        raise ScanFormatError(f"{path}: no COLMAP model (cameras/images .bin or .txt) found")
    image_dir = find_image_dir(path, model_dir)
    if image_dir is None:
        raise ScanFormatError(f"{path}: no image folder next to the COLMAP model (expected images/)")
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap raises plain RuntimeError/ValueError on malformed models
        raise ScanFormatError(f"{model_dir}: unreadable COLMAP model ({exc})") from None
    return scan_from_reconstruction(rec, image_dir)
