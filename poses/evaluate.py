"""Pose accuracy: absolute trajectory error after a similarity (Sim(3)) alignment."""
from __future__ import annotations

import numpy as np

from recon.errors import ReconError
from recon.scan import Scan


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (s, R, t) with dst ~ s R src + t (Umeyama 1991). src, dst: (N, 3)."""
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ReconError(f"Sim(3) alignment needs two matching (N>=3, 3) point sets, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        sign[2, 2] = -1
    R = U @ sign @ Vt
    var_s = (xs ** 2).sum() / len(src)
    scale = float(np.trace(np.diag(S) @ sign) / var_s) if with_scale and var_s > 0 else 1.0
    t = mu_d - scale * R @ mu_s
    return scale, R, t


def frames_used(scan: Scan) -> list[str] | None:
    """The frames SfM was given (registered and not), for a scan SfM made; None for any other scan."""
    sfm = scan.metadata.extra.get("sfm")
    return None if not isinstance(sfm, dict) else list(scan.names) + list(sfm.get("unregistered", []))


def pose_metrics(pred: Scan, gt: Scan, with_scale: bool = True) -> dict[str, float]:
    """ATE RMSE (GT units) of the camera centres after Sim(3) alignment, frames matched by name.

    `registered` is the share of the frames used that got a pose: for an SfM scan the frames SfM
    was given (not the ones a stride, a frame limit or the blur filter left out), else every GT frame.
    """
    used = frames_used(pred)
    pool = len(gt) if used is None else len({f.name for f in gt.frames} & set(used))
    gt_index = {f.name: f for f in gt.frames}
    pairs = [(f.camera_to_world[:3, 3], gt_index[f.name].camera_to_world[:3, 3])
             for f in pred.frames if f.name in gt_index]
    if len(pairs) < 3:
        raise ReconError(f"only {len(pairs)} predicted frames match ground-truth frame names; need at least 3")
    src = np.array([p for p, _ in pairs])
    dst = np.array([g for _, g in pairs])
    scale, R, t = umeyama(src, dst, with_scale)
    aligned = scale * src @ R.T + t
    err = np.linalg.norm(aligned - dst, axis=1)
    path_length = float(np.linalg.norm(np.diff(dst, axis=0), axis=1).sum())
    return {"ate_rmse": float(np.sqrt(np.mean(err ** 2))), "ate_median": float(np.median(err)),
            "registered": len(pairs) / max(pool, 1), "frames_matched": len(pairs), "frames_used": pool,
            "scale": scale,
            "trajectory_length": path_length,
            "alignment": {"scale": scale, "rotation": R.tolist(), "translation": t.tolist()}}
