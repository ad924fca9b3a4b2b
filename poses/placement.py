"""Photos posed where their own matches say they are not.

In a photo collection nothing orders the views, so a photo of a repeating or bare wall can register
against the wrong part of the room: its pose then fits a few hundred observations, metres away from
where it was taken (docs/poses.md, "Photo collections": one photo 5.4 m off sets the whole ATE). Each
verified pair of photos has its own two-view geometry, the relative rotation and direction of travel
its inlier matches give. A well-placed photo agrees with at least some of its pairs (on the rendered
rooms 16-80 % of its inliers lie in agreeing pairs; pairs matched across repeated textures disagree),
a misplaced one with none, so `misplaced` picks out the photos whose agreeing share is near zero.
"""
from __future__ import annotations

import numpy as np

ROTATION_TOLERANCE_DEG = 5.0  # the pair's rotation and the model's differ by less: they agree
DIRECTION_TOLERANCE_DEG = 15.0  # and so do their directions of travel
MIN_INLIERS = 15  # pairs with fewer inlier matches give no usable geometry and are not counted
MIN_AGREEING_SHARE = 0.05  # of a photo's inliers in agreeing pairs; below it the photo is misplaced


def rotation_angle_deg(r: np.ndarray) -> float:
    """Angle of the rotation matrix `r` (3, 3), in degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def direction_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between the vectors `a` and `b` (3,), in degrees; 180 when either is zero."""
    norms = np.linalg.norm(a) * np.linalg.norm(b)
    if norms < 1e-12:
        return 180.0
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / norms, -1.0, 1.0))))


def pair_relative_pose(points_a: np.ndarray, points_b: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(R, t) of camera b from camera a (x_b = R x_a + t, |t| = 1) from matched normalised image points.

    points_a, points_b: (N, 2) matches in normalised camera coordinates (pixels through K^-1); threshold:
    the RANSAC error bound in those units (a pixel over the focal length). None when no essential
    matrix is found.
    """
    import cv2

    if len(points_a) < 5:
        return None
    a, b = np.ascontiguousarray(points_a, np.float64), np.ascontiguousarray(points_b, np.float64)
    # Plain RANSAC stops at the first model all points fit, and with walls seen head-on a wrong one often does
    # (half the pairs of a test box room); USAC's local optimisation and degeneracy tests find the right one.
    essential, mask = cv2.findEssentialMat(a, b, np.eye(3), method=cv2.USAC_ACCURATE, prob=0.999,
                                           threshold=threshold)
    if essential is None or essential.shape != (3, 3):
        return None
    _, r, t, _ = cv2.recoverPose(essential, a, b, np.eye(3), mask=mask)
    return r, t.ravel()


def pose_agrees(model: tuple[np.ndarray, np.ndarray], pair: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether the model's relative pose (R, t) of b from a matches the pair's own within the tolerances."""
    (r_model, t_model), (r_pair, t_pair) = model, pair
    return (rotation_angle_deg(r_model.T @ r_pair) < ROTATION_TOLERANCE_DEG
            and direction_angle_deg(t_model, t_pair) < DIRECTION_TOLERANCE_DEG)


def misplaced(pairs: list[tuple[str, str, int, bool]], min_share: float = MIN_AGREEING_SHARE) -> list[str]:
    """Photos whose pairs hardly agree with where they were placed.

    pairs: (photo a, photo b, inlier matches, agrees) for each verified pair of posed photos. A photo
    is misplaced when the pairs that agree hold under `min_share` of its inliers. Returns names, sorted.
    """
    inliers: dict[str, float] = {}
    agreeing: dict[str, float] = {}
    for a, b, count, agrees in pairs:
        for name in (a, b):
            inliers[name] = inliers.get(name, 0.0) + count
            agreeing[name] = agreeing.get(name, 0.0) + count * agrees
    return sorted(name for name, total in inliers.items() if agreeing[name] < min_share * total)
