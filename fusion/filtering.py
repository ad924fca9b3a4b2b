"""Which pixels of a depth map fusion should trust, for any depth source (the network, the plane sweep, a
user's own folder): COLMAP's stereo fusion and SimpleRecon fuse only depth that is in range, away from depth
edges and confirmed by other views. Four tests, each optional:

- range: depth outside the fusion range [depth_min, depth_max] is dropped (fusion would ignore it anyway;
  dropping it first keeps it from confirming other views).
- edges: flying pixels. Neighbouring pixels whose back-projected points line up with the viewing ray
  (the surface between them would be seen at more than `edge_max_angle` from its normal) straddle a depth
  discontinuity; both are dropped.
- consistency: each map is reprojected into its `views` nearest keyframes (pose distance, as keyframes and
  sources are chosen); a pixel is kept where the neighbour's depth at the reprojected pixel agrees with the
  reprojected depth (relative difference under `max_rel_diff`) in at least `min_views` of those that have
  depth there (a pixel no neighbour sees stays: nothing contradicts it).
- photometric (optional, with consistency): an agreeing view also has to see the same grey level there
  (each image divided by its mean, so exposure changes do not count).

The consistency score, the soft count of agreeing views (each counts 1 - difference / max_rel_diff) over
`views`, is served as the confidence of depth that has none of its own (a user's depth folder); depth with
its own (the network's peak plane probability) keeps it: a threshold on that (`--min-confidence`) keeps
more mesh F-score than one on the score at 80 and 60 % of the pixels on all four held-out scans
(docs/evaluation.md compares the two). With `weights` the score sets each pixel's TSDF integration weight
(1 + agreeing views, scaled to at most 1).

Predicted depth is also weighed by nearness: each pixel counts `near_weight_m` / depth in the TSDF, so where a
near and a far view disagree the near one, whose depth errs less (a stereo network's error grows with depth),
moves the surface more. Chosen on the held-out scans (docs/evaluation.md): it raised the mesh F-score of the
network's, the hybrid's and the plane sweep's depth on each of the four. A scan's own depth is never weighed (it is the reference).
Vectorised numpy, so it costs a fraction of the depth stage (`recon bench fusion`).
"""
from __future__ import annotations

import functools
import json
import os
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from recon.errors import ReconError
from recon.geometry import backproject, invert_pose, mark_neighbour_pairs, project, transform_points
from recon.keyframes import pose_distances
from recon.scan import Intrinsics, Scan

from .tsdf import DepthMap, DepthSource, TSDFConfig, depth_source

CHECKS = ("consistency", "edges", "photometric")
NETWORK_CHECKS = ("consistency", "edges")  # what `auto` runs on a network's (or a user's) depth
# Depth modes `auto` leaves to the range test: the plane sweep's pixels already agreed with two sources, and
# the hybrid's meshes (mostly refined or network pixels) scored higher unfiltered on the held-out scans
# (docs/evaluation.md).
RANGE_ONLY_MODES = ("planesweep", "hybrid")


@dataclass(frozen=True)
class FilterConfig:
    """The depth filter before fusion (`--filter`); `checks` empty: only the fusion range applies; None (auto):
    NETWORK_CHECKS on predicted depth, nothing but the range on the plane sweep's and the hybrid's
    (RANGE_ONLY_MODES) or a scan's own."""

    checks: tuple[str, ...] | None = None
    views: int = 4  # nearest keyframes (pose distance) each depth map is checked against
    min_views: int = 2  # of them that must agree for a pixel to stay (fewer when a frame has fewer neighbours)
    max_rel_diff: float = 0.1  # |reprojected depth - neighbour's depth| / neighbour's depth still agreeing
    edge_max_angle: float = 85.0  # degrees between a surface's normal and the viewing ray beyond which it is an edge
    max_color_diff: float = 0.1  # photometric check: grey-level difference (image / its mean) still agreeing
    weights: bool = False  # the consistency score weighs each pixel in the TSDF (Open3D's integration counts 1)
    near_weight_m: float = 2.0  # predicted depth: each pixel weighs near_weight_m / depth in the TSDF (0: all count 1)

    def validate(self) -> "FilterConfig":
        unknown = [c for c in self.checks or () if c not in CHECKS]
        if unknown:
            raise ReconError(f"unknown depth filter check {unknown[0]!r} "
                             f"(auto, none, or a comma list of {', '.join(CHECKS)})")
        if "photometric" in (self.checks or ()) and "consistency" not in self.checks:
            raise ReconError("the photometric check compares views the consistency check matched: "
                             "use --filter consistency,photometric")
        if self.views < 1 or not 1 <= self.min_views <= self.views:
            raise ReconError(f"the consistency filter needs views >= 1 and 1 <= min views <= views "
                             f"(got {self.views}, {self.min_views})")
        if not self.max_rel_diff > 0 or not 0 < self.edge_max_angle < 90 or not self.max_color_diff > 0:
            raise ReconError("filter thresholds: relative difference > 0, edge angle in (0, 90) degrees, "
                             "colour difference > 0")
        if not self.near_weight_m >= 0:
            raise ReconError(f"--near-weight-m must be >= 0 (0 weighs every pixel alike), got {self.near_weight_m}")
        return self

    def for_depth(self, depth: "str | os.PathLike") -> "FilterConfig":
        """The checks settled for one depth source: 'gt', or a folder whose depth.json (the depth stage's
        summary) names the mode that made it; a folder without one is a user's own predicted depth. A scan's
        own depth is not weighed by nearness."""
        if str(depth) == "gt":
            return replace(self, checks=() if self.checks is None else self.checks, near_weight_m=0.0)
        if self.checks is not None:
            return self
        summary = Path(depth) / "depth.json"
        try:
            mode = json.loads(summary.read_text()).get("mode") if summary.is_file() else None
        except (OSError, ValueError, AttributeError):
            mode = None
        return replace(self, checks=() if mode in RANGE_ONLY_MODES else NETWORK_CHECKS)


def parse_checks(text: str) -> tuple[str, ...] | None:
    """'auto' -> None; 'none' -> (); 'consistency,edges' -> ('consistency', 'edges') (the command-line form of
    `checks`)."""
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    if names == ("auto",):
        return None
    return () if names in ((), ("none",)) else names


@dataclass
class FilterStats:
    """What the filter did over the frames it served (report.json's "filter" section)."""

    frames: int = 0
    valid_pixels: int = 0  # pixels with depth before filtering
    kept_pixels: int = 0
    dropped: dict = field(default_factory=lambda: {"range": 0, "edges": 0, "consistency": 0})
    seconds: float = 0.0  # filtering, reading the neighbours' maps included

    def as_dict(self) -> dict:
        out = asdict(self)
        out["kept_share"] = self.kept_pixels / self.valid_pixels if self.valid_pixels else 0.0
        return out


def edge_mask(depth_m: np.ndarray, K: np.ndarray, max_angle_deg: float) -> np.ndarray:
    """Pixels at depth discontinuities (flying pixels): True where the segment to a 4-neighbour lies closer
    to the viewing ray than 90 - max_angle degrees. depth_m (H, W) metres, 0 invalid; K (3, 3) -> (H, W) bool."""
    points = backproject(depth_m, K).astype(np.float32)
    valid = depth_m > 0
    cos2_limit = np.float32(np.cos(np.radians(90.0 - max_angle_deg)) ** 2)

    def grazing(lo, hi) -> np.ndarray:
        step = points[hi] - points[lo]
        ray = points[lo] + points[hi]  # the pair's mean viewing direction
        along = np.einsum("...i,...i", step, ray)
        steep = along * along > cos2_limit * np.einsum("...i,...i", step, step) * np.einsum("...i,...i", ray, ray)
        return steep & valid[lo] & valid[hi]

    return mark_neighbour_pairs(grazing, depth_m.shape)


def nearest_views(camera_to_world: np.ndarray, views: int) -> list[np.ndarray]:
    """Each frame's `views` nearest other frames by combined pose distance (recon.keyframes), nearest first."""
    poses = np.asarray(camera_to_world, np.float64)
    distance = pose_distances(poses[:, None], poses[None])[0]
    np.fill_diagonal(distance, np.inf)
    order = np.argsort(distance, axis=1, kind="stable")[:, :views]
    return [row[np.isfinite(distance[i, row])] for i, row in enumerate(order)]


def normalised_grey(rgb: np.ndarray, width: int, height: int) -> np.ndarray:
    """Grey levels divided by their mean, on the depth grid: (H, W) float32 about 1."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    if grey.shape != (height, width):
        grey = cv2.resize(grey, (width, height), interpolation=cv2.INTER_AREA)
    return grey / max(float(grey.mean()), 1.0)


def depth_at_projection(points_world: np.ndarray, neighbour_depth: np.ndarray, K: np.ndarray,
                        neighbour_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points seen from a neighbour: (their depth z (N,) in its camera; its depth at the nearest pixel they project
    to (N,), 0 outside it; that flat pixel index (N,), -1 outside). points_world (N, 3); neighbour_depth (H, W)."""
    h, w = neighbour_depth.shape
    uv, z = project(transform_points(invert_pose(neighbour_to_world), points_world), K)
    u, v = np.round(uv[:, 0]), np.round(uv[:, 1])
    inside = (z > 1e-6) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    pixel = np.where(inside, v * w + u, -1).astype(np.int64)
    return z, np.where(inside, neighbour_depth.reshape(-1)[np.maximum(pixel, 0)], 0.0), pixel


def view_agreement(points_world: np.ndarray, neighbour_depth: np.ndarray, K: np.ndarray, neighbour_to_world: np.ndarray,
                   max_rel_diff: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How one neighbour's depth judges points: (observes (N,) bool: the neighbour has depth where they project;
    agrees (N,) bool; score (N,) in [0, 1]; flat pixel index (N,) into the neighbour, -1 outside it).
    points_world (N, 3); neighbour_depth (H, W); K (3, 3)."""
    z, seen, pixel = depth_at_projection(points_world, neighbour_depth, K, neighbour_to_world)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(z - seen) / seen
    observes = seen > 0
    agrees = observes & (rel < max_rel_diff)
    return observes, agrees, np.where(agrees, 1.0 - rel / max_rel_diff, 0.0), pixel


class DepthFilter:
    """A DepthSource (fusion.tsdf) serving each frame's depth with the untrusted pixels set to 0, its own
    confidence or else the consistency score; `stats` adds up what it did."""

    def __init__(self, scan: Scan, source: DepthSource, config: FilterConfig, depth_range: tuple[float, float]):
        if config.checks is None:  # in-memory depth of unknown origin: treated as predicted
            config = replace(config, checks=NETWORK_CHECKS)
        self.scan, self.source, self.config = scan, source, config.validate()
        self.depth_range = depth_range
        self.neighbours = nearest_views(scan.camera_to_world, config.views) if "consistency" in config.checks \
            else [np.zeros(0, np.int64)] * len(scan)
        self.stats = FilterStats()
        cache = functools.lru_cache(maxsize=4 * config.views + 8)
        self._prefiltered = cache(self._range_and_edges)
        self._grey = cache(self._grey_image)

    def _intrinsics(self, depth_m: np.ndarray) -> Intrinsics:
        h, w = depth_m.shape
        intr = self.scan.intrinsics
        return intr if (intr.width, intr.height) == (w, h) else intr.resized(w, h)

    def _range_and_edges(self, i: int) -> tuple[DepthMap, dict]:
        """Frame i with the range and edge tests applied (cached: neighbours reuse it) and what each dropped."""
        frame = self.source(i)
        depth = np.nan_to_num(frame.depth_m.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        valid = depth > 0
        in_range = valid & (depth >= self.depth_range[0]) & (depth <= self.depth_range[1])
        depth[~in_range] = 0.0
        counts = {"valid": int(valid.sum()), "range": int((valid & ~in_range).sum()), "edges": 0}
        if "edges" in self.config.checks:
            edge = edge_mask(depth, self._intrinsics(depth).K, self.config.edge_max_angle) & in_range
            depth[edge] = 0.0
            counts["edges"] = int(edge.sum())
        return DepthMap(depth, frame.confidence), counts

    def _grey_image(self, i: int) -> np.ndarray:
        h, w = self._prefiltered(i)[0].depth_m.shape
        return normalised_grey(self.scan.image(i), w, h)

    def _consistency(self, i: int, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(trusted (H, W) bool: agreeing in min_views of the neighbours that have depth there, or in all of them
        when fewer do; consistency score (H, W) float32 in [0, 1]) of frame i's depth."""
        cfg, frames = self.config, self.scan.frames
        K = self._intrinsics(depth).K
        valid = depth > 0
        points = transform_points(frames[i].camera_to_world, backproject(depth, K)[valid])
        observed, agreed = np.zeros(len(points), np.int32), np.zeros(len(points), np.int32)
        score = np.zeros(len(points))
        for j in self.neighbours[i]:
            neighbour = self._prefiltered(int(j))[0].depth_m
            observes, agrees, part, pixel = view_agreement(points, neighbour, self._intrinsics(neighbour).K,
                                                           frames[j].camera_to_world, cfg.max_rel_diff)
            if "photometric" in cfg.checks:
                grey_i, grey_j = self._grey(i), self._grey(int(j))
                if grey_i.shape == grey_j.shape:
                    same = np.abs(grey_i[valid] - grey_j.reshape(-1)[np.maximum(pixel, 0)]) < cfg.max_color_diff
                    agrees &= same
                    part = np.where(same, part, 0.0)
            observed += observes
            agreed += agrees
            score += part
        trusted, scores = np.zeros(depth.shape, bool), np.zeros(depth.shape, np.float32)
        trusted[valid] = agreed >= np.minimum(cfg.min_views, observed)
        scores[valid] = score / cfg.views
        return trusted, scores

    def __call__(self, i: int) -> DepthMap:
        started = time.perf_counter()
        prefiltered, counts = self._prefiltered(i)
        depth, score = prefiltered.depth_m.copy(), None
        dropped_consistency = 0
        if "consistency" in self.config.checks:
            if len(self.neighbours[i]):
                trusted, score = self._consistency(i, depth)
                drop = (depth > 0) & ~trusted
                depth[drop] = 0.0
                dropped_consistency = int(drop.sum())
            else:  # a scan of one frame: nothing to check against, nothing to distrust
                score = np.ones(depth.shape, np.float32)
        stats = self.stats
        stats.frames += 1
        stats.valid_pixels += counts["valid"]
        stats.kept_pixels += int((depth > 0).sum())
        for key, n in (("range", counts["range"]), ("edges", counts["edges"]), ("consistency", dropped_consistency)):
            stats.dropped[key] += n
        stats.seconds += time.perf_counter() - started
        weight = None
        if self.config.weights and score is not None:
            # The pixel's own view counts one, each agreeing neighbour up to one more: a kept pixel no other
            # view saw still adds to the TSDF, one confirmed by every neighbour adds views + 1 times as much.
            weight = (1.0 + score * self.config.views) / (1.0 + self.config.views)
        if self.config.near_weight_m > 0:
            near = near_weights(depth, self.config.near_weight_m)
            weight = near if weight is None else weight * near
        confidence = prefiltered.confidence if prefiltered.confidence is not None else score
        return DepthMap(depth, confidence, weight)


def near_weights(depth_m: np.ndarray, near_weight_m: float) -> np.ndarray:
    """Each pixel's TSDF weight near_weight_m / depth (0 where there is no depth). depth_m (H, W) -> (H, W) float32."""
    weight = np.zeros(depth_m.shape, np.float32)
    valid = depth_m > 0
    weight[valid] = np.float32(near_weight_m) / depth_m[valid]
    return weight


def filtered_depth(scan: Scan, depth: str | os.PathLike, config: FilterConfig, fusion: TSDFConfig) -> DepthFilter:
    """The filtered DepthSource of 'gt' or a depth folder, over the fusion's depth range (what `fuse_scan` takes);
    `config.checks` auto is settled for that source (`FilterConfig.for_depth`)."""
    return DepthFilter(scan, depth_source(scan, depth), config.for_depth(depth), (fusion.depth_min, fusion.depth_max))
