"""Photos posed where their own matches say they are not.

In a photo collection nothing orders the views, so a photo of a repeating or bare wall can register
against the wrong part of the room: its pose then fits a few hundred observations, metres away from
where it was taken (docs/poses.md, "Photo collections": one photo 5.4 m off sets the whole ATE). Each
verified pair of photos has its own two-view geometry, the relative rotation and direction of travel
its inlier matches give. A well-placed photo agrees with at least some of its pairs (on the rendered
rooms 16-80 % of its inliers lie in agreeing pairs; pairs matched across repeated textures disagree),
a misplaced one with none, so `misplaced` picks out the photos whose agreeing share is near zero.

The same residuals find the pairs themselves that are wrong: on the rendered collections a third to two
thirds of the verified pairs join views of different walls through a repeated texture (most of those with
15-30 inliers), and where enough of them pull together the incremental mapper bends the whole model.
`grossly_off` marks the pairs far off the first model; SfM maps again without them and keeps the model
that more of all the pairs' inliers agree with (poses/sfm.py, `map_without_gross_pairs`).
"""
from __future__ import annotations

import numpy as np

ROTATION_TOLERANCE_DEG = 5.0  # the pair's rotation and the model's differ by less: they agree
DIRECTION_TOLERANCE_DEG = 15.0  # and so do their directions of travel
MIN_INLIERS = 15  # pairs with fewer inlier matches give no usable geometry and are not counted
MIN_AGREEING_SHARE = 0.05  # of a photo's inliers in agreeing pairs; below it the photo is misplaced
GROSS_ROTATION_DEG = 30.0  # a pair this far off the model in rotation (or GROSS_DIRECTION_DEG in travel
GROSS_DIRECTION_DEG = 60.0  # direction) matched something else than the same surface: pruned before a second mapping


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


def pose_residuals(model: tuple[np.ndarray, np.ndarray], pair: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    """(rotation, travel direction) differences in degrees between the model's relative pose (R, t) of b from a and
    the pair's own."""
    (r_model, t_model), (r_pair, t_pair) = model, pair
    return rotation_angle_deg(r_model.T @ r_pair), direction_angle_deg(t_model, t_pair)


def agrees(rotation_deg: float, direction_deg: float) -> bool:
    """Whether a pair with these residuals agrees with the model."""
    return rotation_deg < ROTATION_TOLERANCE_DEG and direction_deg < DIRECTION_TOLERANCE_DEG


def grossly_off(rotation_deg: float, direction_deg: float) -> bool:
    """Whether a pair with these residuals is too far off the model to be a noisy estimate of the same poses."""
    return rotation_deg > GROSS_ROTATION_DEG or direction_deg > GROSS_DIRECTION_DEG


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
