"""Camera geometry on numpy arrays, in the project's conventions.

Poses are 4x4 float64 camera-to-world matrices with OpenCV camera axes (x right,
y down, z forward); depth is float32 metres with 0 meaning invalid. The torch
counterparts used by the network live in `depth.geometry`.
"""
from __future__ import annotations

import numpy as np

from .errors import ReconError

# Flips y and z: converts between OpenGL camera axes (x right, y up, z back) and OpenCV's.
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def intrinsic_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """3x3 pinhole matrix K."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


FULL_FRAME_DIAGONAL_MM = float(np.hypot(36.0, 24.0))  # 35 mm film, the frame an "equivalent" focal length refers to


def focal_px_from_equivalent(focal_35mm: float, width: int, height: int) -> float:
    """Focal length in pixels of a `width` x `height` image from its 35 mm-equivalent focal length in mm
    (EXIF FocalLengthIn35mmFilm): the same field of view across the diagonal."""
    return focal_35mm / FULL_FRAME_DIAGONAL_MM * float(np.hypot(width, height))


def equivalent_focal_mm(focal_px: float, width: int, height: int) -> float:
    """The inverse of `focal_px_from_equivalent`."""
    return focal_px * FULL_FRAME_DIAGONAL_MM / float(np.hypot(width, height))


def invert_pose(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (R^T, -R^T t), exact for rotations.

    pose: (..., 4, 4) -> (..., 4, 4)
    """
    rot = pose[..., :3, :3]
    trans = pose[..., :3, 3:]
    out = np.zeros_like(pose)
    rot_t = np.swapaxes(rot, -1, -2)
    out[..., :3, :3] = rot_t
    out[..., :3, 3:] = -rot_t @ trans
    out[..., 3, 3] = 1.0
    return out


def rigidity_error(pose: np.ndarray) -> float:
    """How far a 4x4 matrix is from a rigid transform (0 for an exact one)."""
    pose = np.asarray(pose, dtype=np.float64)
    rot = pose[:3, :3]
    orth = np.abs(rot.T @ rot - np.eye(3)).max()
    det = abs(np.linalg.det(rot) - 1.0)
    bottom = np.abs(pose[3] - np.array([0.0, 0.0, 0.0, 1.0])).max()
    return float(max(orth, det, bottom))


def check_pose(pose: np.ndarray, where: str, tol: float = 1e-3) -> np.ndarray:
    """Validate a camera-to-world pose; returns it as float64 4x4 or raises ReconError naming `where`."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ReconError(f"{where}: pose has shape {pose.shape}, expected 4x4")
    if not np.all(np.isfinite(pose)):
        raise ReconError(f"{where}: pose contains NaN or inf")
    err = rigidity_error(pose)
    if err > tol:
        raise ReconError(f"{where}: pose is not a rigid transform (rotation error {err:.3g})")
    return pose


def opengl_to_opencv(camera_to_world_gl: np.ndarray) -> np.ndarray:
    """Camera-to-world with OpenGL camera axes -> OpenCV camera axes. (..., 4, 4)"""
    return camera_to_world_gl @ OPENGL_TO_OPENCV


def opencv_to_opengl(camera_to_world: np.ndarray) -> np.ndarray:
    """Inverse of `opengl_to_opencv` (the axis flip is its own inverse). (..., 4, 4)"""
    return camera_to_world @ OPENGL_TO_OPENCV


def quaternion_to_rotation(qw: float, qx: float, qy: float, qz: float) -> np.ndarray:
    """Unit quaternion (Hamilton, scalar first) -> 3x3 rotation matrix."""
    q = np.array([qw, qx, qy, qz], dtype=np.float64)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm < 1e-12:
        raise ReconError("quaternion has zero or invalid norm")
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def world_to_camera_to_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """COLMAP-style world-to-camera (R, t) -> camera-to-world 4x4."""
    w2c = np.eye(4)
    w2c[:3, :3] = rotation
    w2c[:3, 3] = np.asarray(translation).reshape(3)
    return invert_pose(w2c)


def backproject_pixels(u: np.ndarray, v: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels at depths -> camera-frame points: the one ray back-projection everything uses.

    u, v, z: (...) pixel coordinates (integer = pixel centre) and z-depth; K: (3, 3) -> (..., 3).
    """
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, np.broadcast_to(z, np.shape(u))], -1)


def pixel_rays(K: np.ndarray, width: int, height: int, dtype=np.float64) -> np.ndarray:
    """Camera-frame ray through every pixel centre, scaled to z = 1: (H, W, 3)."""
    v, u = np.mgrid[0:height, 0:width].astype(dtype)
    return backproject_pixels(u, v, np.ones((), dtype), np.asarray(K, dtype))


NEIGHBOUR_PAIRS = (((slice(0, -1), slice(None)), (slice(1, None), slice(None))),   # vertical pairs
                   ((slice(None), slice(0, -1)), (slice(None), slice(1, None))))  # horizontal pairs


def mark_neighbour_pairs(pair_test, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: both pixels of every vertical or horizontal neighbour pair that `pair_test` flags.

    pair_test(lo, hi) takes the index tuples of the pairs' first and second pixels (use them on any
    (H, W, ...) array) and returns a bool array of the pairs' shape: one test serves every pixel-pair rule
    (depth jumps, grazing surfaces)."""
    marked = np.zeros(shape, bool)
    for lo, hi in NEIGHBOUR_PAIRS:
        flagged = pair_test(lo, hi)
        marked[lo] |= flagged
        marked[hi] |= flagged
    return marked


def backproject(depth_m: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Depth map -> camera-frame points. depth_m: (H, W) metres; K: (3, 3) -> (H, W, 3), z = depth."""
    h, w = depth_m.shape
    return pixel_rays(K, w, h) * depth_m.astype(np.float64)[..., None]


def transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (..., 3) points.

    einsum, not `@`: a (N, 3) x (3, 3) product through multi-threaded BLAS is 5-10x slower on a loaded machine.
    """
    return np.einsum("...j,ij->...i", points, transform[:3, :3]) + transform[:3, 3]


def project(points_cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (..., 3) -> pixel coordinates (..., 2) and depth z (...)."""
    z = points_cam[..., 2]
    safe = np.where(np.abs(z) < 1e-12, 1e-12, z)
    u = K[0, 0] * points_cam[..., 0] / safe + K[0, 2]
    v = K[1, 1] * points_cam[..., 1] / safe + K[1, 2]
    return np.stack([u, v], axis=-1), z


def reproject_depth(
    depth_src: np.ndarray, K: np.ndarray, src_to_world: np.ndarray, dst_to_world: np.ndarray,
    dst_shape: tuple[int, int] | None = None,
) -> np.ndarray:
    """Forward-warp a depth map into another camera (z-buffered, nearest pixel).

    Returns the (H, W) depth the destination camera would see of the source's
    points (0 where nothing lands). Used to compare depth maps across views.
    """
    h, w = dst_shape or depth_src.shape
    valid = depth_src > 0
    pts = backproject(depth_src, K)[valid]
    pts_dst = transform_points(invert_pose(dst_to_world) @ src_to_world, pts)
    uv, z = project(pts_dst, K)
    ui = np.round(uv[:, 0]).astype(np.int64)
    vi = np.round(uv[:, 1]).astype(np.int64)
    keep = (z > 1e-6) & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    ui, vi, z = ui[keep], vi[keep], z[keep]
    out = np.full(h * w, np.inf)
    np.minimum.at(out, vi * w + ui, z)
    out[~np.isfinite(out)] = 0.0
    return out.reshape(h, w).astype(np.float32)


def reprojection_disagreement(
    depth_src: np.ndarray, depth_dst: np.ndarray, K: np.ndarray,
    src_to_world: np.ndarray, dst_to_world: np.ndarray, max_rel: float = 0.1,
) -> np.ndarray:
    """Relative depth differences |warped - dst| / dst where both views see the same surface.

    Pixels whose difference exceeds `max_rel` are treated as occlusions and dropped,
    so the result measures agreement on shared surfaces (1-D array).
    """
    warped = reproject_depth(depth_src, K, src_to_world, dst_to_world, depth_dst.shape)
    both = (warped > 0) & (depth_dst > 0)
    rel = np.abs(warped[both] - depth_dst[both]) / depth_dst[both]
    return rel[rel < max_rel]
