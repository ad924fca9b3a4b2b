"""Mesh accuracy against a ground-truth mesh (the TransformerFusion / SimpleRecon protocol).

Both meshes are sampled with a fixed seed; Accuracy is the mean distance from predicted
points to the GT points, Completeness the reverse, Chamfer their mean; Precision and
Recall count distances under a threshold (5 cm) and give the F-score. Distances are
capped (1 m). Given a scan, points its cameras never saw are culled from both sides,
so a GT model larger than the capture does not count against completeness.

"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from recon.geometry import invert_pose, project, transform_points
from recon.scan import Scan

from .mesh import load_mesh


@dataclass
class MeshEvalConfig:
    n_points: int = 200_000
    threshold: float = 0.05  # metres: precision / recall / F-score
    distance_cap: float = 1.0
    seed: int = 0
    visibility_frames: int = 100  # at most this many scan frames decide what the capture saw
    occlusion_margin: float = 0.05  # metres behind the GT depth still counted as seen (sensor noise); more
    #                                 would count crevices no camera saw (gaps between books) as observed


def sample_points(mesh: trimesh.Trimesh, n: int, seed: int) -> np.ndarray:
    """n points uniformly on the surface (area-weighted), reproducible for a given seed.

    Each face's corners, then the faces, are put in a canonical (lexicographic) order first, so the
    same surface stored in another face or corner order (Open3D's hash map does that) gives the
    same points.
    """
    rng = np.random.default_rng(seed)
    tri = mesh.triangles
    corner_order = np.lexsort(tri.transpose(2, 0, 1)[::-1], axis=-1)  # per face: by x, then y, then z
    tri = np.take_along_axis(tri, corner_order[..., None], axis=1)
    order = np.lexsort(tri.reshape(len(tri), -1).T[::-1])
    tri = tri[order]
    area = mesh.area_faces[order]
    face = rng.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    tri = tri[face]
    return tri[:, 0] + r1[:, None] * (tri[:, 1] - tri[:, 0]) + r2[:, None] * (tri[:, 2] - tri[:, 0])


def visible_mask(points: np.ndarray, scan: Scan, config: MeshEvalConfig) -> np.ndarray:
    """Which points fall in some camera's view, in front of (or just behind) its GT depth when it has one."""
    seen = np.zeros(len(points), dtype=bool)
    n = len(scan)
    picks = np.unique(np.linspace(0, n - 1, min(n, config.visibility_frames)).round().astype(int))
    intr = scan.intrinsics
    K = intr.K
    for i in picks:
        todo = ~seen
        cam = transform_points(invert_pose(scan.frames[i].camera_to_world), points[todo])
        uv, z = project(cam, K)
        u, v = np.round(uv[:, 0]).astype(np.int64), np.round(uv[:, 1]).astype(np.int64)
        inside = (z > 1e-3) & (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
        if scan.frames[i].has_depth:
            gt = scan.depth(i)
            d = np.zeros_like(z)
            d[inside] = gt[v[inside], u[inside]]
            inside &= (d > 0) & (z <= d + config.occlusion_margin)
        idx = np.flatnonzero(todo)
        seen[idx[inside]] = True
    return seen


def point_metrics(pred_points: np.ndarray, gt_points: np.ndarray, config: MeshEvalConfig) -> dict[str, float]:
    """Accuracy, completeness, chamfer, precision, recall, F-score of two point sets."""
    if len(pred_points) == 0 or len(gt_points) == 0:
        cap = config.distance_cap
        return {"acc": cap, "comp": cap, "chamfer": cap, "prec": 0.0, "recall": 0.0, "fscore": 0.0}
    d_pred = np.minimum(cKDTree(gt_points).query(pred_points, workers=-1)[0], config.distance_cap)
    d_gt = np.minimum(cKDTree(pred_points).query(gt_points, workers=-1)[0], config.distance_cap)
    prec = float(np.mean(d_pred < config.threshold))
    recall = float(np.mean(d_gt < config.threshold))
    acc, comp = float(d_pred.mean()), float(d_gt.mean())
    return {"acc": acc, "comp": comp, "chamfer": 0.5 * (acc + comp), "prec": prec, "recall": recall,
            "fscore": 2 * prec * recall / (prec + recall) if prec + recall > 0 else 0.0}


def mesh_metrics(pred: trimesh.Trimesh | str | os.PathLike, gt: trimesh.Trimesh | str | os.PathLike,
                 scan: Scan | None = None, config: MeshEvalConfig | None = None) -> dict[str, float]:
    """Score a predicted mesh against a GT mesh; `scan` enables visibility culling."""
    config = config or MeshEvalConfig()
    pred_mesh = pred if isinstance(pred, trimesh.Trimesh) else load_mesh(pred)
    gt_mesh = gt if isinstance(gt, trimesh.Trimesh) else load_mesh(gt)
    pred_pts = sample_points(pred_mesh, config.n_points, config.seed)
    gt_pts = sample_points(gt_mesh, config.n_points, config.seed)
    if scan is not None:
        pred_pts = pred_pts[visible_mask(pred_pts, scan, config)]
        gt_pts = gt_pts[visible_mask(gt_pts, scan, config)]
    out = point_metrics(pred_pts, gt_pts, config)
    out.update({"pred_points": int(len(pred_pts)), "gt_points": int(len(gt_pts)), "threshold": config.threshold})
    return out
