"""Scans in the exchange formats other tools read: the inverse of what `recon.readers` undoes.

nerfstudio's transforms.json takes camera-to-world poses in OpenGL camera axes and pixel
centres at +0.5; a COLMAP model takes world-to-camera poses and the same +0.5 centres. The
scan's own convention (OpenCV axes, integer centres) is converted here, once, so reading a
written file back with `recon.readers` gives the scan's poses and intrinsics again.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .geometry import invert_pose, opencv_to_opengl
from .scan import Scan

PIXEL_CENTRE = 0.5  # where nerfstudio and COLMAP put the centre of pixel (0, 0)


def nerfstudio_transforms(scan: Scan, file_paths: list[str]) -> dict:
    """transforms.json content: one pinhole camera, and a frame per scan frame pointing at `file_paths`."""
    intr = scan.intrinsics
    frames = [{"file_path": path, "transform_matrix": opencv_to_opengl(f.camera_to_world).tolist()}
              for path, f in zip(file_paths, scan.frames, strict=True)]
    return {"camera_model": "OPENCV", "fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx + PIXEL_CENTRE,
            "cy": intr.cy + PIXEL_CENTRE, "w": intr.width, "h": intr.height, "k1": 0.0, "k2": 0.0, "p1": 0.0,
            "p2": 0.0, "metric_scale": bool(scan.metadata.metric_scale), "frames": frames}


def write_colmap_text(scan: Scan, folder: str | os.PathLike, image_names: list[str],
                      points: np.ndarray | None = None, colors: np.ndarray | None = None) -> Path:
    """A COLMAP text model of the scan's cameras in `folder` (cameras.txt, images.txt, points3D.txt, ...).

    One shared PINHOLE camera; image i is named `image_names[i]`. `points` (N, 3) with uint8 `colors`
    (N, 3) become 3D points without tracks (a starting cloud for tools that want one).
    """
    import pycolmap

    intr = scan.intrinsics
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(
        model="PINHOLE", width=intr.width, height=intr.height, camera_id=1,
        params=[intr.fx, intr.fy, intr.cx + PIXEL_CENTRE, intr.cy + PIXEL_CENTRE]))
    for i, (name, frame) in enumerate(zip(image_names, scan.frames, strict=True)):
        world_to_camera = invert_pose(frame.camera_to_world)
        cam_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(world_to_camera[:3, :3]), world_to_camera[:3, 3])
        rec.add_image_with_trivial_frame(pycolmap.Image(image_id=i + 1, name=name, camera_id=1), cam_from_world)
    if points is not None:
        colors = np.full((len(points), 3), 200, np.uint8) if colors is None else colors
        for xyz, rgb in zip(np.asarray(points, np.float64), np.asarray(colors, np.uint8)):
            rec.add_point3D(xyz, pycolmap.Track(), rgb)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rec.write_text(str(folder))
    return folder
