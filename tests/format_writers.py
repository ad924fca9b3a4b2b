"""Write an in-memory scan in each supported third-party layout (fixtures for the reader tests)."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from recon.geometry import invert_pose, opencv_to_opengl
from recon.io import write_image
from recon.scan import Scan


def _depth_png(path: Path, depth_m: np.ndarray, units_per_metre: float = 1000.0) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.clip(np.round(depth_m * units_per_metre), 0, 65535).astype(np.uint16))


def _matrix(path: Path, m: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, m)


def write_7scenes(scan: Scan, root: Path) -> None:
    _matrix(root / "camera-intrinsics.txt", scan.intrinsics.K)  # the depth sensor's
    _matrix(root / "color-intrinsics.txt", scan.intrinsics.K)  # here the same camera
    for i, f in enumerate(scan.frames):
        write_image(root / f"frame-{i:06d}.color.png", scan.image(i))
        _depth_png(root / f"frame-{i:06d}.depth.png", scan.depth(i))
        _matrix(root / f"frame-{i:06d}.pose.txt", f.camera_to_world)


def write_scannet(scan: Scan, root: Path) -> None:
    K4 = np.eye(4)
    K4[:3, :3] = scan.intrinsics.K
    _matrix(root / "intrinsic/intrinsic_color.txt", K4)
    for i, f in enumerate(scan.frames):
        write_image(root / f"color/{i}.jpg", scan.image(i), jpeg_quality=100)
        _depth_png(root / f"depth/{i}.png", scan.depth(i))
        _matrix(root / f"pose/{i}.txt", f.camera_to_world)


def write_tum(scan: Scan, root: Path, dt: float = 0.033) -> None:
    """Depth and poses stamped a few ms off the color, as in the real dataset; depth at 5000 units/m."""
    root.mkdir(parents=True, exist_ok=True)
    _matrix(root / "camera-intrinsics.txt", scan.intrinsics.K)
    rgb, dep, gt = ["# color"], ["# depth"], ["# timestamp tx ty tz qx qy qz qw"]
    for i, f in enumerate(scan.frames):
        t = 1000.0 + i * dt
        write_image(root / f"rgb/{t:.6f}.png", scan.image(i))
        _depth_png(root / f"depth/{t + 0.004:.6f}.png", scan.depth(i), 5000.0)
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        dep.append(f"{t + 0.004:.6f} depth/{t + 0.004:.6f}.png")
        q = Rotation.from_matrix(f.camera_to_world[:3, :3]).as_quat()
        gt.append(f"{t - 0.003:.6f} " + " ".join(f"{v:.9f}" for v in (*f.camera_to_world[:3, 3], *q)))
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(dep) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")


def write_open3d(scan: Scan, root: Path) -> None:
    intr = scan.intrinsics
    (root / "image").mkdir(parents=True)
    (root / "camera_intrinsic.json").write_text(json.dumps(
        {"width": intr.width, "height": intr.height, "intrinsic_matrix": intr.K.T.reshape(-1).tolist()}))
    blocks = []
    for i, f in enumerate(scan.frames):
        write_image(root / f"image/{i:05d}.png", scan.image(i))
        _depth_png(root / f"depth/{i:05d}.png", scan.depth(i))
        blocks.append(f"{i} {i} {len(scan)}\n" + "\n".join(" ".join(f"{v:.12f}" for v in row) for row in f.camera_to_world))
    (root / "trajectory.log").write_text("\n".join(blocks) + "\n")


def write_simplerecon(scan: Scan, root: Path) -> None:
    _matrix(root / "K.txt", scan.intrinsics.K)
    rows = []
    for i, f in enumerate(scan.frames):
        write_image(root / f"images/{i:05d}.png", scan.image(i))
        _depth_png(root / f"depth/{i:05d}.png", scan.depth(i))
        rows.append(f.camera_to_world.reshape(-1))
    np.savetxt(root / "poses.txt", np.array(rows))


def write_colmap(scan: Scan, root: Path, binary: bool = True) -> None:
    """A COLMAP model (PINHOLE camera, world-to-camera poses, pixel centres at +0.5) through pycolmap."""
    import pycolmap

    intr = scan.intrinsics
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera(model="PINHOLE", width=intr.width, height=intr.height,
                          params=[intr.fx, intr.fy, intr.cx + 0.5, intr.cy + 0.5], camera_id=1)
    rec.add_camera_with_trivial_rig(cam)
    for i, f in enumerate(scan.frames):
        w2c = invert_pose(f.camera_to_world)
        cam_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        image = pycolmap.Image(image_id=i + 1, name=f"{i:05d}.png", camera_id=1)
        rec.add_image_with_trivial_frame(image, cam_from_world)
        write_image(root / f"images/{i:05d}.png", scan.image(i))
    model = root / "sparse/0"
    model.mkdir(parents=True)
    (rec.write_binary if binary else rec.write_text)(str(model))


def write_nerfstudio(scan: Scan, root: Path) -> None:
    intr = scan.intrinsics
    frames = []
    for i, f in enumerate(scan.frames):
        write_image(root / f"images/frame_{i:05d}.png", scan.image(i))
        _depth_png(root / f"depth/frame_{i:05d}.png", scan.depth(i))
        frames.append({"file_path": f"images/frame_{i:05d}.png", "depth_file_path": f"depth/frame_{i:05d}.png",
                       "transform_matrix": opencv_to_opengl(f.camera_to_world).tolist()})
    doc = {"camera_model": "OPENCV", "fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx + 0.5, "cy": intr.cy + 0.5,
           "w": intr.width, "h": intr.height, "frames": frames}
    (root / "transforms.json").write_text(json.dumps(doc))


WRITERS = {"7scenes": write_7scenes, "scannet": write_scannet, "tum": write_tum, "open3d": write_open3d,
           "simplerecon": write_simplerecon, "colmap": write_colmap, "nerfstudio": write_nerfstudio}
