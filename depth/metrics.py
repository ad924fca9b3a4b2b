"""Depth accuracy (Eigen et al.) and temporal coherence of predicted depth maps.

Numpy only, so the trainer can use it for validation. Per-frame metrics are computed
on pixels whose ground truth lies inside [min_depth, max_depth]; predictions are
clamped to that range (a missing prediction counts as the nearest bound, never as a
free pass) and `coverage` says which share of those pixels had a prediction. `median_ratio`
(median of prediction / GT over the covered pixels) is the scale bias: 1 for a metric network
whose depth is neither too near nor too far overall. `within_5cm` is the share of pixels whose
depth is within the mesh score's 5 cm: δ<1.25 calls a 40 cm error at 2 m right, a fused surface
does not, so two networks can rank one way on Abs Rel and δ and the other way on the mesh. `near_5cm` is the
share more than 5 cm too near: fused, those pixels make surfaces in front of the true ones, which a visibility-culled
mesh score charges while it drops surfaces behind them, so of two maps with the same `within_5cm` the one whose
misses lean near has the less precise mesh (docs/depth.md, "Same depth error, different mesh").
`edge_precision`, `edge_recall` and `edge_f` say whether the depth follows the scene's occluding edges:
a map that blurs a chair into the wall behind it scores well on Abs Rel and near zero here.
"""
from __future__ import annotations

import numpy as np

from recon.geometry import mark_neighbour_pairs, reproject_depth

DEPTH_KEYS = ("abs_rel", "abs", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3", "within_5cm", "near_5cm")
SURFACE_TOLERANCE = 0.05  # metres: the mesh F-score's threshold, so `within_5cm` reads as the depth the mesh can use
EDGE_JUMP = 1.1  # a depth ratio above this between 4-neighbours is an occluding edge (a slanted wall: a few %)
EDGE_TOLERANCE_PX = 2  # an edge found within this many pixels of the true one counts as found


def depth_metrics(pred_m: np.ndarray, gt_m: np.ndarray, min_depth: float = 1e-3, max_depth: float = 10.0
                  ) -> dict[str, float] | None:
    """Metrics of one frame (None when it has no valid GT pixel). pred_m, gt_m: (H, W) metres."""
    if pred_m.shape != gt_m.shape:
        raise ValueError(f"prediction {pred_m.shape} and ground truth {gt_m.shape} differ in size")
    valid = np.isfinite(gt_m) & (gt_m > min_depth) & (gt_m < max_depth)
    if not valid.any():
        return None
    gt = gt_m[valid].astype(np.float64)
    raw = pred_m[valid].astype(np.float64)
    covered = np.isfinite(raw) & (raw > 0)
    pred = np.clip(np.where(covered, raw, min_depth), min_depth, max_depth)
    diff = pred - gt
    ratio = np.maximum(pred / gt, gt / pred)
    return {
        "abs_rel": float(np.mean(np.abs(diff) / gt)),
        "abs": float(np.mean(np.abs(diff))),
        "sq_rel": float(np.mean(diff ** 2 / gt)),
        "rmse": float(np.sqrt(np.mean(diff ** 2))),
        "rmse_log": float(np.sqrt(np.mean((np.log(pred) - np.log(gt)) ** 2))),
        "a1": float(np.mean(ratio < 1.25)),
        "a2": float(np.mean(ratio < 1.25 ** 2)),
        "a3": float(np.mean(ratio < 1.25 ** 3)),
        "within_5cm": float(np.mean(np.abs(diff) < SURFACE_TOLERANCE)),
        "near_5cm": float(np.mean(diff <= -SURFACE_TOLERANCE)),
        "coverage": float(np.mean(covered)),
        "median_ratio": float(np.median(raw[covered] / gt[covered])) if covered.any() else float("nan"),
    }


def depth_edges(depth_m: np.ndarray, valid: np.ndarray, jump: float = EDGE_JUMP) -> np.ndarray:
    """(H, W) bool: pixels whose depth differs from a valid 4-neighbour's by a ratio above `jump`.

    Both sides of an edge are marked; pixels outside `valid` never are.
    """
    log_d = np.log(np.where(valid, np.maximum(depth_m, 1e-6), 1.0))
    limit = np.log(jump)
    return mark_neighbour_pairs(lambda lo, hi: (np.abs(log_d[hi] - log_d[lo]) > limit) & valid[lo] & valid[hi],
                                depth_m.shape)


def edge_counts(pred_m: np.ndarray, gt_m: np.ndarray, valid: np.ndarray, tolerance_px: int = EDGE_TOLERANCE_PX
                ) -> tuple[int, int, int, int]:
    """(predicted edge pixels near a true edge, predicted edge pixels, true edge pixels near a predicted
    edge, true edge pixels) on the pixels valid in both, within `tolerance_px` (Euclidean)."""
    import cv2

    pred_valid = valid & np.isfinite(pred_m) & (pred_m > 0)
    true_edges = depth_edges(gt_m, valid)
    pred_edges = depth_edges(pred_m, pred_valid)

    def near(edges: np.ndarray) -> np.ndarray:
        if not edges.any():
            return np.zeros_like(edges)
        return cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 3) <= tolerance_px

    return (int((pred_edges & near(true_edges)).sum()), int(pred_edges.sum()),
            int((true_edges & near(pred_edges)).sum()), int(true_edges.sum()))


def edge_scores(counts: list[tuple[int, int, int, int]]) -> dict[str, float]:
    """Precision, recall and F-score of occluding edges from `edge_counts` summed over frames (NaN
    where a share has no pixels)."""
    hit_p, pred, hit_t, true = (sum(c[i] for c in counts) for i in range(4))
    precision = hit_p / pred if pred else float("nan")
    recall = hit_t / true if true else float("nan")
    f = float("nan")
    if pred and true:
        f = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {"edge_precision": precision, "edge_recall": recall, "edge_f": f}


def on_gt_grid(pred_m: np.ndarray, gt_m: np.ndarray) -> np.ndarray:
    """A prediction stored at network resolution, resampled (nearest, so holes stay holes) onto the
    ground truth's grid: every score is taken at the GT's pixels. (H', W') -> gt_m's (H, W)."""
    if pred_m.shape == gt_m.shape:
        return pred_m
    import cv2

    return cv2.resize(pred_m, (gt_m.shape[1], gt_m.shape[0]), interpolation=cv2.INTER_NEAREST)


def median_scale(pred_m: np.ndarray, gt_m: np.ndarray) -> float:
    """Ratio median(gt) / median(pred) on pixels valid in both: aligns non-metric predictions."""
    both = (pred_m > 0) & (gt_m > 0) & np.isfinite(pred_m) & np.isfinite(gt_m)
    return float(np.median(gt_m[both]) / np.median(pred_m[both])) if both.any() else 1.0


def flicker(pred_a: np.ndarray, pred_b: np.ndarray, K: np.ndarray, a_to_world: np.ndarray, b_to_world: np.ndarray,
            gt_a: np.ndarray | None = None, gt_b: np.ndarray | None = None, occlusion_rel: float = 0.05
            ) -> float | None:
    """Pose-aware disagreement of two consecutive predictions: mean |warp(a) - b| / b over shared pixels.

    Frame a's prediction is reprojected into b with the poses. With GT depth, pixels
    where the warped GT disagrees with b's GT by more than `occlusion_rel` (occlusions,
    disocclusions) are excluded, so the figure measures inconsistency, not visibility.
    """
    warped = reproject_depth(pred_a, K, a_to_world, b_to_world, pred_b.shape)
    shared = (warped > 0) & (pred_b > 0)
    if gt_a is not None and gt_b is not None:
        gt_warped = reproject_depth(gt_a, K, a_to_world, b_to_world, gt_b.shape)
        shared &= (gt_warped > 0) & (gt_b > 0) & (np.abs(gt_warped - gt_b) <= occlusion_rel * np.maximum(gt_b, 1e-6))
    if not shared.any():
        return None
    return float(np.mean(np.abs(warped[shared] - pred_b[shared]) / pred_b[shared]))


def summarise(per_frame: list[dict[str, float]], flickers: list[float]) -> dict[str, float]:
    """Average per-frame metrics over frames; temporal keys from the per-frame mean absolute error."""
    out: dict[str, float] = {"frames": len(per_frame)}
    if per_frame:
        for key in (*DEPTH_KEYS, "coverage"):
            out[key] = float(np.mean([m[key] for m in per_frame]))
        ratios = [m["median_ratio"] for m in per_frame if np.isfinite(m["median_ratio"])]
        out["median_ratio"] = float(np.median(ratios)) if ratios else float("nan")
        mae = np.array([m["abs"] for m in per_frame])
        out["mae_mean"] = float(mae.mean())
        out["mae_std"] = float(mae.std())
    out["flicker"] = float(np.mean(flickers)) if flickers else float("nan")
    return out


def evaluate_depth_folder(pred_dir, scan, min_depth: float = 1e-3, max_depth: float = 10.0,
                          align: str = "none", progress=None, scale: float = 1.0) -> dict[str, float]:
    """Score a folder of predicted maps (`<frame name>.npy|.png`) against a scan's GT depth.

    Predictions of another size are resampled (nearest) onto the GT grid. `scale` multiplies every
    prediction first (an SfM run's depth into the GT's units: the Sim(3) scale of its trajectory).
    `align='median'` rescales each prediction by median(gt)/median(pred), for non-metric predictions;
    the result then says so. Temporal keys come from consecutive frames of the scan;
    `per_frame` lists each frame's abs_rel, abs and flicker (with the previous frame).
    """
    from recon.errors import ReconError
    from recon.io import load_depth_map

    if not scan.has_depth:
        raise ReconError(f"{scan.root or 'scan'}: has no ground-truth depth to evaluate against")
    if align not in ("none", "median"):
        raise ReconError(f"unknown alignment {align!r} (none, median)")
    K = scan.intrinsics.K
    per_frame, flickers, edges, rows, prev = [], [], [], [], None
    for i in range(len(scan)):
        gt = scan.depth(i)
        pred = on_gt_grid(load_depth_map(pred_dir, scan.frames[i].name), gt)
        if scale != 1.0:
            pred = pred * np.float32(scale)
        if align == "median":
            pred = pred * median_scale(pred, gt)
        m = depth_metrics(pred, gt, min_depth, max_depth)
        if m is not None:
            per_frame.append(m)
            edges.append(edge_counts(pred, gt, np.isfinite(gt) & (gt > min_depth) & (gt < max_depth)))
        f = None
        if prev is not None:
            f = flicker(prev[0], pred, K, prev[2], scan.frames[i].camera_to_world, prev[1], gt)
            if f is not None:
                flickers.append(f)
        rows.append({"name": scan.frames[i].name, "abs_rel": m["abs_rel"] if m else None,
                     "abs": m["abs"] if m else None, "flicker": f})
        prev = (pred, gt, scan.frames[i].camera_to_world)
        if progress:
            progress(i + 1, len(scan))
    out = summarise(per_frame, flickers)
    out.update(edge_scores(edges))
    out.update({"min_depth": min_depth, "max_depth": max_depth, "align": align, "per_frame": rows})
    return out
