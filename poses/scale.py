"""Scale for SfM poses, and the depth range each frame's depth search should cover.

A COLMAP model is correct only up to a similarity: its unit is arbitrary. Four ways
out, in order of preference:

1. `reference`: a scan with metric poses for the same frames (a phone's ARKit track,
   a dataset's ground truth). The SfM camera centres are aligned to it by a Sim(3)
   (Umeyama) fit; the result is metric and in the reference's world frame.
2. `known_distance`: the distance in metres between the camera centres of two named
   frames (e.g. measured with a tape between two places the phone was held).
3. `factor`: metres per SfM unit, when the user knows it from elsewhere.
4. Otherwise the default normalisation: scale so that the median depth of the sparse
   points seen by the frames is `target_median_depth` (2 m, a typical indoor viewing
   distance, the middle of the depth network's 0.25-10 m working range). Not metric,
   and the scan says so.

Per-frame depth ranges come from the sparse points each frame sees: the
`depth_percentiles` of their depths widened by `depth_margin`, stored in
`metadata.extra["frame_depth_ranges"]` ({name: [near, far]}) and overall in
`metadata.depth_range`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from recon.errors import ReconError
from recon.scan import Scan


@dataclass
class ScaleConfig:
    """How SfM units become (near-)metres; set at most one of reference, known_distance and factor."""

    factor: float | None = None  # metres per SfM unit
    known_distance: tuple[str, str, float] | None = None  # (frame A, frame B, metres between their cameras)
    target_median_depth: float = 2.0  # default normalisation: median sparse depth after scaling
    depth_percentiles: tuple[float, float] = (2.0, 98.0)  # of each frame's sparse point depths
    depth_margin: float = 0.25  # near /= (1 + margin), far *= (1 + margin): sparse points miss the extremes
    min_points: int = 20  # frames seeing fewer points get the overall range


@dataclass
class ScaleResult:
    method: str  # "reference", "known_distance", "factor" or "normalised"
    factor: float  # new units per SfM unit
    metric: bool
    alignment_rmse: float | None = None  # metres, camera centres after the Sim(3) fit (reference only)
    matched_frames: int | None = None

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def transform_scan(scan: Scan, scale: float, rotation: np.ndarray | None = None,
                   translation: np.ndarray | None = None) -> Scan:
    """Apply the similarity x -> s R x + t to the world: poses stay rigid, centres move and scale."""
    rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    trans = np.zeros(3) if translation is None else np.asarray(translation, np.float64)
    frames = []
    for f in scan.frames:
        pose = np.eye(4)
        pose[:3, :3] = rot @ f.camera_to_world[:3, :3]
        pose[:3, 3] = scale * rot @ f.camera_to_world[:3, 3] + trans
        frames.append(dataclasses.replace(f, camera_to_world=pose))
    return dataclasses.replace(scan, frames=frames, metadata=dataclasses.replace(
        scan.metadata, extra=dict(scan.metadata.extra)))


def _centre(scan: Scan, name: str) -> np.ndarray:
    try:
        return scan.frames[scan.index_of(name)].camera_to_world[:3, 3]
    except KeyError:
        raise ReconError(f"--known-distance: frame {name!r} is not among the registered frames "
                         f"({', '.join(scan.names[:3])}, ...)") from None


def frame_depth_ranges(sparse_depths: dict[str, np.ndarray], config: ScaleConfig) -> tuple[dict[str, list[float]],
                                                                                          tuple[float, float]]:
    """Per-frame [near, far] from sparse point depths (percentiles + margin) and the overall range."""
    lo_p, hi_p = config.depth_percentiles
    grow = 1.0 + config.depth_margin
    everything = np.concatenate([d for d in sparse_depths.values() if len(d)] or [np.zeros(0)])
    if not len(everything):
        raise ReconError("no triangulated points: cannot estimate depth ranges (SfM produced no structure)")
    overall = (float(np.percentile(everything, lo_p) / grow), float(np.percentile(everything, hi_p) * grow))
    ranges = {}
    for name, d in sparse_depths.items():
        if len(d) >= config.min_points:
            ranges[name] = [float(np.percentile(d, lo_p) / grow), float(np.percentile(d, hi_p) * grow)]
        else:
            ranges[name] = list(overall)
    return ranges, overall


def resolve_scale(scan: Scan, sparse_depths: dict[str, np.ndarray], config: ScaleConfig | None = None,
                  reference: Scan | None = None) -> tuple[Scan, ScaleResult]:
    """Scale (or Sim(3)-align) an SfM scan and store depth ranges; returns the new scan and what was done.

    `sparse_depths` ({frame name: depths of the sparse points it sees, SfM units}) is what
    `poses.sfm.sparse_depths` returns; a similarity scales camera-space depths by its factor only.
    """
    config = config or ScaleConfig()
    chosen = [n for n, v in (("reference", reference), ("known_distance", config.known_distance),
                             ("factor", config.factor)) if v is not None]
    if len(chosen) > 1:
        raise ReconError(f"choose one way to set the scale, not {' and '.join(chosen)}")
    if reference is not None:
        from poses.evaluate import umeyama

        ref_index = {f.name: f for f in reference.frames}
        common = [f for f in scan.frames if f.name in ref_index]
        if len(common) < 3:
            raise ReconError(f"the reference scan shares only {len(common)} frame names with the SfM frames; "
                             "need 3 or more (ingest the reference scan itself so names match)")
        src = np.array([f.camera_to_world[:3, 3] for f in common])
        dst = np.array([ref_index[f.name].camera_to_world[:3, 3] for f in common])
        s, rot, trans = umeyama(src, dst, with_scale=True)
        out = transform_scan(scan, s, rot, trans)
        residual = s * src @ rot.T + trans - dst
        result = ScaleResult("reference", s, reference.metadata.metric_scale,
                             float(np.sqrt((residual ** 2).sum(1).mean())), len(common))
    elif config.known_distance is not None:
        a, b, metres = config.known_distance
        if not metres > 0:
            raise ReconError(f"--known-distance must be positive, got {metres}")
        units = float(np.linalg.norm(_centre(scan, a) - _centre(scan, b)))
        if units < 1e-9:
            raise ReconError(f"--known-distance: frames {a} and {b} are at the same place in the SfM model; "
                             "pick two frames taken some distance apart")
        s = metres / units
        out, result = transform_scan(scan, s), ScaleResult("known_distance", s, True)
    elif config.factor is not None:
        if not config.factor > 0:
            raise ReconError(f"--scale must be positive, got {config.factor}")
        out, result = transform_scan(scan, config.factor), ScaleResult("factor", config.factor, True)
    else:
        depths = np.concatenate([d for d in sparse_depths.values() if len(d)] or [np.zeros(0)])
        if not len(depths):
            raise ReconError("no triangulated points: cannot normalise the SfM scale")
        s = config.target_median_depth / float(np.median(depths))
        out, result = transform_scan(scan, s), ScaleResult("normalised", s, False)

    ranges, overall = frame_depth_ranges({k: v * result.factor for k, v in sparse_depths.items()}, config)
    out.metadata.metric_scale = result.metric
    out.metadata.depth_range = overall
    out.metadata.extra["scale"] = result.to_dict()
    out.metadata.extra["frame_depth_ranges"] = {f.name: ranges.get(f.name, list(overall)) for f in out.frames}
    return out, result

