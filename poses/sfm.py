"""Camera poses for plain images through pycolmap: SIFT, matching, a parallax check, mapping.

Tuned for a room filmed on a phone and posed on a CPU, and repeatable: the same input and
settings give the same registered frames and poses on every run (docs/poses.md says what
that costs). Three things make COLMAP vary from run to run, and each is pinned here:
  - image ids: feature extraction numbers images in the order its threads finish, and
    matching, pair order and the mapper's choices follow the ids. A first pass on 16 px
    thumbnails (one thread, a fraction of a second) registers every image in name order;
    the real, multi-threaded extraction then fills in features under those ids.
  - random draws: every RANSAC, the mapper and the global mapper's steps get `seed`.
  - threads: bundle adjustment and the global mapper sum in thread order, and matching on two
    threads returned a subset of a pair's matches in 2 of 30 runs, so with `deterministic` matching
    and the mappers run on one thread (extraction stays parallel: its result per image does not
    depend on the thread count).

The camera is one shared pinhole unless the data shows distortion (`camera_model="auto"`):
mapping keeps the distortion at zero, then `distortion_test` bundle-adjusts the model with and
without one radial coefficient and keeps it only when it lowers the reprojection error in the
image's outer ring by `min_distortion_gain`, several times more than in the centre (a
distortion-free rendered camera got k1 = 0.28 from free self-calibration, which bent the
undistorted frames). A recorded scan's own camera is
the starting camera.

Matching follows the input: all pairs for short clips and for photo collections (unordered,
wide baselines) of up to `exhaustive_max` images, a window of neighbours for longer videos, plus
the far-apart frames that look alike (`loop_detection`, poses/retrieval.py: revisits).
When a mapping registers fewer than `retry_below` of the frames, what a careful COLMAP user
would try runs next (`mapping_plan`): the other mapper, a looser initial pair, the other
camera model, all-pairs matching; the largest model wins (the first on a tie). In a video, a block
of frames posed away from the path around it is left unposed (`drop_displaced_blocks`); in a photo
collection, a photo that none of its matched pairs' own geometry agrees with (`drop_misplaced_photos`), and
the collection is mapped again without the pairs far off the first model (`map_without_gross_pairs`). The kept model
becomes a canonical scan with `metadata.metric_scale = False`; distortion, when kept, stays on
the scan, so saving it writes undistorted pinhole images (same K).

Everything COLMAP computed stays under `<work_dir>`, so a user can open it in the
COLMAP GUI (File > Import model, with the frames folder as images): database.db and
sparse/<attempt>/<n>/. Frames that did not register are listed, never given a pose.
"""
from __future__ import annotations

import logging
import os
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from poses.ingest import IngestConfig, ingest
from poses.motion import displaced_blocks
from poses.placement import MIN_INLIERS, agrees, grossly_off, misplaced, pair_relative_pose, pose_residuals
from poses.scale import ScaleConfig, resolve_scale
from recon import io as rio
from recon.errors import ReconError
from recon.scan import Intrinsics, Scan, save_scan

log = logging.getLogger(__name__)

MAPPERS = ("incremental", "global")
CAMERA_MODELS = ("auto", "SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
MATCHERS = ("auto", "sequential", "exhaustive")
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


@dataclass
class SfMConfig:
    """pycolmap settings; the defaults pose 200 frames at 640x480 in about a minute on 2 cores (docs/poses.md)."""

    mapper: str = "incremental"  # "incremental" or "global" (GLOMAP); see docs/poses.md for the comparison
    fallback: bool = True  # when a mapping registers under `retry_below`, try the rest of `mapping_plan`
    retry_below: float = 0.9  # share of frames
    camera_model: str = "auto"  # auto: pinhole unless distortion lowers the reprojection error; or a COLMAP model
    min_distortion_gain: float = 0.01  # auto: keep radial distortion when it cuts the outer-ring error this much
    max_image_size: int = 640  # SIFT runs on images downscaled to this long side
    max_num_features: int = 2048  # per image; matching cost grows with its square
    first_octave: int | None = None  # None: -1 (upsampled octave) for photos and below 600 px, else 0 (1.6x faster)
    matcher: str = "auto"  # auto: exhaustive for short clips and photo collections, else sequential
    sequential_overlap: int = 10  # each frame is matched with this many following frames
    loop_detection: bool = True  # sequential matching: also match far-apart frames that look alike (retrieval.py)
    loop_candidates: int = 3  # per frame, its most similar far-apart frames to verify
    exhaustive_below: int = 40  # clips with at most this many frames are matched all-pairs and mapped with every attempt
    exhaustive_max: int = 300  # photo collections (and the last fallback) up to this many images: all pairs
    min_registered_fraction: float = 0.5  # a model with fewer frames is a failure
    min_parallax: float = 0.003  # homography_parallax below this: the camera only turned, refuse before mapping
    num_threads: int = -1  # extraction (-1: all cores; its result does not depend on it), and the rest unless deterministic
    deterministic: bool = True  # matching and mappers on one thread: identical poses every run (docs/poses.md: cost)
    motion_check: bool = True  # videos: leave unposed a block of frames posed away from the path (poses/motion.py)
    placement_check: bool = True  # photos: leave unposed a photo its own pairs disagree with (poses/placement.py)
    pair_pruning: bool = True  # photos: map again without the pairs far off the first model, keep the better model
    seed: int = 0  # every RANSAC and mapper draw

    def validate(self) -> "SfMConfig":
        for name, value, allowed in (("mapper", self.mapper, MAPPERS), ("camera model", self.camera_model,
                                                                         CAMERA_MODELS),
                                     ("matcher", self.matcher, MATCHERS)):
            if value not in allowed:
                raise ReconError(f"unknown SfM {name} {value!r} (use one of {', '.join(allowed)})")
        return self


@dataclass(frozen=True)
class MappingAttempt:
    """One mapping run: which mapper, whether the camera's distortion is refined, looser initialisation."""

    mapper: str
    distortion: bool
    relaxed: bool = False
    exhaustive: bool = False  # after adding all-pairs matches to a sequentially matched database

    @property
    def label(self) -> str:
        parts = [self.mapper, "radial" if self.distortion else "pinhole"]
        parts += ["relaxed"] * self.relaxed + ["exhaustive"] * self.exhaustive
        return "-".join(parts)


@dataclass
class SfMResult:
    """What SfM produced and where."""

    reconstruction: object  # pycolmap.Reconstruction, the kept (largest) model
    image_dir: Path
    mapper: str  # the mapper whose model was kept
    registered: list[str]  # image names with a pose
    unregistered: list[str]  # image names without one
    timings: dict[str, float]  # seconds per step
    work_dir: Path
    database_path: Path
    model_dir: Path  # the kept model on disk
    attempts: list[dict] = field(default_factory=list)  # [{"attempt": label, "registered": n}] in the order run
    # (a short clip's also "agreeing_inliers": _map_most_agreed)
    camera: dict = field(default_factory=dict)  # the estimated camera, for the report
    parallax: float = 0.0  # homography_parallax of the matches
    matcher: str = ""  # "sequential" or "exhaustive" (the first matching)
    loops: dict = field(default_factory=dict)  # loop detection: candidate and verified pairs, seconds
    distortion: dict = field(default_factory=dict)  # the distortion test: errors, gain, kept
    displaced: list[str] = field(default_factory=list)  # posed where the video's path or the photo's pairs say it
    # is not, left unposed
    pruning: dict = field(default_factory=dict)  # photos: the second mapping without the pairs far off the first
    links: dict = field(default_factory=dict)  # unposed (not displaced) name: most verified matches with a posed one


def _pycolmap():
    """pycolmap, with COLMAP's own log lines (thousands per run) shown only when debugging."""
    import pycolmap

    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 2
    return pycolmap


def _reader_options(config: SfMConfig, camera: Intrinsics | None):
    """One shared camera: COLMAP's model of `camera_model`; with "auto" a SIMPLE_RADIAL whose distortion
    mapping holds at zero (`distortion_test` decides later), starting from the capture's camera when known."""
    pycolmap = _pycolmap()
    reader = pycolmap.ImageReaderOptions()
    if config.camera_model != "auto":
        reader.camera_model = config.camera_model
        return reader
    reader.camera_model = "SIMPLE_RADIAL"
    if camera is not None:  # COLMAP puts pixel centres at +0.5
        reader.camera_params = f"{(camera.fx + camera.fy) / 2},{camera.cx + 0.5},{camera.cy + 0.5},0"
    return reader


def extract_features(image_dir: Path, image_names: list[str], database_path: Path, config: SfMConfig,
                     timings: dict[str, float], camera: Intrinsics | None = None, ordered: bool = True) -> None:
    """SIFT features of `image_names` into a fresh COLMAP database, image ids in name order."""
    pycolmap = _pycolmap()
    config.validate()
    database_path.unlink(missing_ok=True)
    reader = _reader_options(config, camera)
    t0 = time.perf_counter()
    names = sorted(image_names)
    thumbnails = pycolmap.FeatureExtractionOptions()
    thumbnails.max_image_size, thumbnails.num_threads = 16, 1
    pycolmap.extract_features(database_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=thumbnails, device=pycolmap.Device.cpu)
    db = pycolmap.Database.open(database_path)
    try:
        db.clear_keypoints()
        db.clear_descriptors()
    finally:
        db.close()
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = config.max_image_size
    extraction.num_threads = config.num_threads
    extraction.sift.max_num_features = config.max_num_features
    extraction.sift.first_octave = (config.first_octave if config.first_octave is not None
                                    else _first_octave(image_dir, names, ordered))
    pycolmap.extract_features(database_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    timings["extract"] = time.perf_counter() - t0


def match_features(database_path: Path, matcher: str, config: SfMConfig, timings: dict[str, float]) -> dict:
    """Verified matches: all pairs, or each frame with its `sequential_overlap` followers (and, with
    `loop_detection`, the far-apart frames that look alike); pairs already in the database are kept,
    so all-pairs matching after sequential only adds the missing ones. Returns the loop figures."""
    pycolmap = _pycolmap()
    pycolmap.set_random_seed(config.seed)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = _ordered_threads(config)  # two threads lost 35-52 matches of a pair in 2 of 30 runs
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = config.seed
    t0 = time.perf_counter()
    loops: dict = {}
    if matcher == "exhaustive":
        pycolmap.match_exhaustive(database_path, matching_options=matching, verification_options=verification,
                                  device=pycolmap.Device.cpu)
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = config.sequential_overlap
        pairing.quadratic_overlap = False
        pairing.loop_detection = False  # COLMAP's needs a vocabulary-tree file: ours is match_loops
        pycolmap.match_sequential(database_path, matching_options=matching, pairing_options=pairing,
                                  verification_options=verification, device=pycolmap.Device.cpu)
        if config.loop_detection:
            loops = match_loops(database_path, config, matching, verification)
    timings["match"] = timings.get("match", 0.0) + time.perf_counter() - t0
    return loops


def match_loops(database_path: Path, config: SfMConfig, matching, verification) -> dict:
    """Match the loop candidates of poses/retrieval.py (frames beyond the sequential window that look alike);
    the pair list is kept beside the database (loop_pairs.txt, COLMAP's match-list format)."""
    from poses.retrieval import find_loop_pairs

    pycolmap = _pycolmap()
    t0 = time.perf_counter()
    db = pycolmap.Database.open(database_path)
    try:
        images = sorted(db.read_all_images(), key=lambda im: im.name)
        descriptors = [np.asarray(db.read_descriptors(im.image_id).data) for im in images]
    finally:
        db.close()
    pairs = find_loop_pairs(descriptors, config.sequential_overlap, config.loop_candidates, seed=config.seed)
    pair_file = database_path.parent / "loop_pairs.txt"
    rio.write_bytes_atomic(pair_file, "".join(f"{images[i].name} {images[j].name}\n" for i, j in pairs).encode())
    if pairs:
        imported = pycolmap.ImportedPairingOptions()
        imported.match_list_path = str(pair_file)
        pycolmap.match_image_pairs(database_path, matching_options=matching, pairing_options=imported,
                                   verification_options=verification, device=pycolmap.Device.cpu)
    verified = _verified_pairs(database_path, {(images[i].image_id, images[j].image_id) for i, j in pairs})
    log.info("sfm: loop detection: %d of %d candidate pairs verified", verified, len(pairs))
    return {"candidates": len(pairs), "verified": verified, "seconds": round(time.perf_counter() - t0, 2)}


def two_view_geometries(database_path: Path) -> list[tuple[int, int, object]]:
    """Every verified pair in the database as (image id, image id, pycolmap.TwoViewGeometry)."""
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(database_path)
    try:
        pair_ids, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    return [(*(int(i) for i in pycolmap.pair_id_to_image_pair(pid)), g) for pid, g in zip(pair_ids, geometries)]


def _verified_pairs(database_path: Path, pairs: set[tuple[int, int]]) -> int:
    """How many of `pairs` (image ids) have a verified two-view geometry with inliers."""
    both = pairs | {(b, a) for a, b in pairs}
    return sum(1 for a, b, g in two_view_geometries(database_path) if (a, b) in both and len(g.inlier_matches) > 0)


def choose_matcher(config: SfMConfig, num_images: int, ordered: bool) -> str:
    """Exhaustive for short clips and for photo collections up to `exhaustive_max`; sequential otherwise."""
    if config.matcher != "auto":
        return config.matcher
    if num_images <= config.exhaustive_below or (not ordered and num_images <= config.exhaustive_max):
        return "exhaustive"
    if not ordered:
        log.warning("sfm: %d unordered images is more than %d: matching each with its %d followers in name order "
                    "(pass --matcher exhaustive to match all pairs; it costs the square of the count)",
                    num_images, config.exhaustive_max, config.sequential_overlap)
    return "sequential"


def _first_octave(image_dir: Path, image_names: list[str], ordered: bool) -> int:
    """SIFT's upsampled octave (-1) finds the small features that low-resolution frames need, and that photos
    25 degrees apart need to match at all (a rendered room: 31 of 50 photos registered without it, 49 with);
    neighbouring 640 px video frames have enough without (0, 1.6x faster extraction)."""
    import cv2

    first = cv2.imread(str(image_dir / image_names[0]), cv2.IMREAD_GRAYSCALE)
    return -1 if not ordered or first is None or max(first.shape) < 600 else 0


def _ordered_threads(config: SfMConfig) -> int:
    """Threads for the steps whose result depends on the thread count (matching, mapping)."""
    return 1 if config.deterministic else config.num_threads


def _incremental_options(attempt: MappingAttempt, config: SfMConfig):
    pycolmap = _pycolmap()
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = options.mapper.num_threads = _ordered_threads(config)
    options.random_seed = options.mapper.random_seed = options.triangulation.random_seed = config.seed
    options.ba_refine_extra_params = attempt.distortion
    # Video frames overlap heavily: fewer, shorter global bundle adjustments lose no accuracy
    # (7-Scenes ATE unchanged) and halve mapping time.
    options.ba_global_frames_ratio = 1.4
    options.ba_global_points_ratio = 1.4
    options.ba_global_max_num_iterations = 25
    options.ba_local_max_num_iterations = 10
    # Neighbouring video frames rarely reach COLMAP's 16 degree initial-pair angle.
    options.mapper.init_min_tri_angle = 8.0
    if attempt.relaxed:  # a short or weakly textured clip: accept a thinner initial pair and registrations
        options.mapper.init_min_tri_angle = 4.0
        options.mapper.init_min_num_inliers = 50
        options.mapper.abs_pose_min_num_inliers = 15
        options.min_num_matches = 10
    return options


def _global_options(attempt: MappingAttempt, config: SfMConfig):
    pycolmap = _pycolmap()
    options = pycolmap.GlobalPipelineOptions()
    options.num_threads = options.mapper.num_threads = _ordered_threads(config)
    options.random_seed = options.mapper.random_seed = config.seed
    options.mapper.rotation_averaging.random_seed = options.mapper.global_positioning.random_seed = config.seed
    options.mapper.bundle_adjustment.refine_extra_params = attempt.distortion
    options.mapper.bundle_adjustment.ceres.solver_options.num_threads = _ordered_threads(config)
    return options


def map_images(database_path: Path, image_dir: Path, output_dir: Path, attempt: MappingAttempt, config: SfMConfig,
               timings: dict[str, float]) -> dict:
    """Run one mapping attempt; returns {model index: Reconstruction} (each written to output_dir/<index>)."""
    pycolmap = _pycolmap()
    rio.remove_path(output_dir)
    output_dir.mkdir(parents=True)
    pycolmap.set_random_seed(config.seed)
    t0 = time.perf_counter()
    if attempt.mapper == "global":
        # GLOMAP's rotation averaging needs calibrated pairs; a video's focal length is unknown, and
        # skipping this step leaves the default focal guess in place and collapses the trajectory.
        calibration = pycolmap.ViewGraphCalibrationOptions()
        calibration.random_seed = config.seed
        pycolmap.calibrate_view_graph(database_path, calibration)
        timings["calibrate"] = timings.get("calibrate", 0.0) + time.perf_counter() - t0
        t1 = time.perf_counter()
        models = pycolmap.global_mapping(database_path, image_dir, output_dir, _global_options(attempt, config))
        timings["map_global"] = timings.get("map_global", 0.0) + time.perf_counter() - t1
    elif attempt.mapper == "incremental":
        models = pycolmap.incremental_mapping(database_path, image_dir, output_dir,
                                              _incremental_options(attempt, config))
        timings["map_incremental"] = timings.get("map_incremental", 0.0) + time.perf_counter() - t0
    else:
        raise ReconError(f"unknown mapper {attempt.mapper!r} (use one of {', '.join(MAPPERS)})")
    return dict(models)


def mapping_plan(config: SfMConfig) -> list[MappingAttempt]:
    """The attempts in order: the configured one, then (with `fallback`) the other mapper, a looser
    initial pair, and the other camera model (radial <-> pinhole; not for a pinhole `camera_model`)."""
    radial = config.camera_model not in ("auto", *PINHOLE_MODELS)
    first = MappingAttempt(config.mapper, radial)
    if not config.fallback:
        return [first]
    other = next(m for m in MAPPERS if m != config.mapper)
    plan = [first, MappingAttempt(other, radial), MappingAttempt("incremental", radial, relaxed=True)]
    if config.camera_model not in PINHOLE_MODELS:
        plan.append(MappingAttempt("incremental", not radial, relaxed=True))
    return plan


def homography_parallax(database_path: Path) -> float | None:
    """How far the matched views are from a camera that only turned on the spot (0 = pure rotation).

    Two views of a turning camera are related by H = K R K^-1, whose eigenvalues (after scaling
    to det 1) all have modulus 1 whatever K is; translation against a 3D scene pulls them apart.
    The score is the median, over the quarter of verified pairs furthest apart in the sequence,
    of max |log |eigenvalue|| of COLMAP's homography. Rooms filmed while walking score 0.02-0.05,
    a slow 3 s clip 0.007, a camera turning on a tripod 0.001. None when no pair matched.
    """
    gaps, scores = [], []
    for a, b, geometry in two_view_geometries(database_path):
        H = np.asarray(geometry.H, dtype=np.float64)
        det = np.linalg.det(H) if H.shape == (3, 3) and np.all(np.isfinite(H)) else 0.0
        if abs(det) < 1e-12:
            continue
        moduli = np.abs(np.linalg.eigvals(H / np.cbrt(det)))
        gaps.append(abs(b - a))
        scores.append(float(np.max(np.abs(np.log(moduli)))))
    if not scores:
        return None
    gaps, scores = np.array(gaps), np.array(scores)
    return float(np.median(scores[gaps >= np.percentile(gaps, 75)]))


def run_sfm(image_dir: str | os.PathLike, image_names: list[str], work_dir: str | os.PathLike,
            config: SfMConfig | None = None, camera: Intrinsics | None = None, ordered: bool = True) -> SfMResult:
    """Reconstruct `image_names` (files in `image_dir`) into `work_dir`; raises ReconError on failure.

    `camera`: the capture's own pinhole camera at the images' size, when it has one (a recorded
    scan); `ordered`: the names follow the capture (a video), False for a photo collection. On
    failure everything computed so far (database, any partial models) stays in `work_dir`.
    """
    config = (config or SfMConfig()).validate()
    image_dir, work_dir = Path(image_dir), Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    database_path = work_dir / "database.db"
    timings: dict[str, float] = {}
    t_start = time.perf_counter()
    n = len(image_names)
    extract_features(image_dir, image_names, database_path, config, timings, camera, ordered)
    matcher = choose_matcher(config, n, ordered)
    loops = match_features(database_path, matcher, config, timings)
    parallax = _check_parallax(database_path, image_dir, work_dir, config, n)
    attempts: list[dict] = []
    short_clip = config.fallback and ordered and n <= config.exhaustive_below
    best = _first_mapping(database_path, image_dir, work_dir, config, timings, attempts, n, short_clip)
    if config.fallback and matcher == "sequential" and n <= config.exhaustive_max and best[0] < config.retry_below * n:
        log.info("sfm: matching all pairs of the %d frames and mapping again", n)
        match_features(database_path, "exhaustive", config, timings)
        retry = [MappingAttempt(a.mapper, a.distortion, a.relaxed, exhaustive=True)
                 for a in mapping_plan(config)]
        best = max(best, _map_until_enough(database_path, image_dir, work_dir, retry, config, timings, attempts, n),
                   key=lambda b: b[0])
    registered_count, attempt, model_dir, rec = best
    if registered_count < max(3, int(np.ceil(config.min_registered_fraction * n))):
        raise ReconError(_failure_message(registered_count, n, work_dir, attempts))
    distortion = {}
    if config.camera_model == "auto" and not attempt.distortion:
        rec, distortion = distortion_test(rec, config, timings)
    pruning: dict = {}
    if ordered:
        displaced = drop_displaced_blocks(rec, image_names) if config.motion_check else []
    else:
        kept = checked_model(rec, model_dir, distortion, database_path, config)
        if config.pair_pruning:
            kept, pruning = map_without_gross_pairs(kept, database_path, image_dir, work_dir, attempt, config, timings)
        rec, model_dir, distortion, displaced, _ = kept
    if distortion.get("kept") or displaced or pruning.get("kept") == "pruned":
        rec.write(str(model_dir))
    timings["sfm_total"] = time.perf_counter() - t_start
    registered = sorted(im.name for im in rec.images.values() if im.has_pose)
    unregistered = sorted(set(image_names) - set(registered))
    cam = next(iter(rec.cameras.values()))
    camera_report = {"model": cam.model_name, "width": cam.width, "height": cam.height,
                     "params": [float(p) for p in cam.params], "from_capture": camera is not None}
    missed = [name for name in unregistered if name not in displaced]
    links = links_to_posed(database_path, set(registered), missed) if missed else {}
    if missed:
        log.warning("sfm: %d of %d frames did not register and are left out: %s (in brackets: the most verified "
                    "matches each shares with a posed frame; a frame needs a few dozen, so take views that overlap "
                    "it and more textured surfaces)", len(missed), n,
                    ", ".join(f"{name} ({links[name]})" for name in missed[:10]) + (" ..." if len(missed) > 10 else ""))
    return SfMResult(rec, image_dir, attempt.mapper, registered, unregistered, timings, work_dir, database_path,
                     model_dir, attempts, camera_report, parallax, matcher, loops=loops, distortion=distortion,
                     displaced=displaced, pruning=pruning, links=links)


def links_to_posed(database_path: Path, posed: set[str], unposed: list[str]) -> dict[str, int]:
    """{unposed image name: the most verified inlier matches it shares with any posed image}: why it stayed out
    (a view of a bare wall shares a handful, a photo of another room none)."""
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(database_path)
    try:
        names = {im.image_id: im.name for im in db.read_all_images()}
    finally:
        db.close()
    links = dict.fromkeys(unposed, 0)
    for a, b, geometry in two_view_geometries(database_path):
        for mine, other in ((names[a], names[b]), (names[b], names[a])):
            if mine in links and other in posed:
                links[mine] = max(links[mine], len(geometry.inlier_matches))
    return links


def drop_displaced_blocks(rec, image_names: list[str]) -> list[str]:
    """Unpose the blocks of frames posed away from the video's path (poses/motion.py); `image_names` in
    capture order. Returns the names left unposed, with one warning."""
    order = {name: i for i, name in enumerate(image_names)}
    images = sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: order[im.name])
    index = np.array([order[im.name] for im in images])
    centres = np.array([im.projection_center() for im in images]).reshape(-1, 3)
    dropped = [images[p] for block in displaced_blocks(index, centres) for p in block]
    for im in dropped:
        rec.deregister_frame(im.frame_id)
    names = [im.name for im in dropped]
    if names:
        log.warning("sfm: %d frames were posed away from the path of the frames around them (a repeating texture "
                    "matched one repeat away?) and are left out: %s", len(names),
                    ", ".join(names[:10]) + (" ..." if len(names) > 10 else ""))
    return names


def posed_pairs(rec, database_path: Path) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """The verified pairs of posed images with at least MIN_INLIERS inliers, as (name a, name b, (N, 2) pixel
    positions in a, (N, 2) in b) of their inlier matches, in COLMAP's pixel convention."""
    pycolmap = _pycolmap()
    posed = {im.image_id: im.name for im in rec.images.values() if im.has_pose}
    db = pycolmap.Database.open(database_path)
    try:
        keypoints = {i: np.asarray(db.read_keypoints(i))[:, :2] for i in posed}
    finally:
        db.close()
    pairs = []
    for a, b, geometry in two_view_geometries(database_path):
        matches = np.asarray(geometry.inlier_matches)
        if a in posed and b in posed and len(matches) >= MIN_INLIERS:
            pairs.append((posed[a], posed[b], keypoints[a][matches[:, 0]], keypoints[b][matches[:, 1]]))
    return pairs


PairResidual = tuple[str, str, int, float, float]  # name a, name b, inliers, rotation and direction residuals (deg)


def pair_residuals(rec, pairs: list[tuple[str, str, np.ndarray, np.ndarray]]) -> list[PairResidual]:
    """(name a, name b, inliers, rotation and travel-direction residuals in degrees) for each of `pairs` (as
    posed_pairs gives them): how far the pair's own relative pose, from its inliers through the model's camera,
    is from the model's (poses/placement.py); 180, 180 when the inliers give no pose."""
    images = {im.name: im for im in rec.images.values() if im.has_pose}
    cam = next(iter(rec.cameras.values()))
    threshold = 1.0 / cam.mean_focal_length()  # one pixel
    residuals = []
    for a, b, pixels_a, pixels_b in pairs:
        pair = pair_relative_pose(np.asarray(cam.cam_from_img(pixels_a)), np.asarray(cam.cam_from_img(pixels_b)),
                                  threshold)
        b_from_a = np.asarray((_cam_from_world(images[b]) * _cam_from_world(images[a]).inverse()).matrix())
        off = (180.0, 180.0) if pair is None else pose_residuals((b_from_a[:, :3], b_from_a[:, 3]), pair)
        residuals.append((a, b, len(pixels_a), *off))
    return residuals


def agreeing_inliers(residuals: list[PairResidual]) -> int:
    """Inliers of the pairs that agree with the model, summed: how much of the matching a model explains."""
    return sum(n for _, _, n, rotation, direction in residuals if agrees(rotation, direction))


def drop_misplaced_photos(rec, residuals: list[PairResidual]) -> list[str]:
    """Unpose the photos whose verified pairs' own geometry disagrees with where the model put them
    (poses/placement.py); `residuals` as pair_residuals gives them. Returns the names left unposed, with one warning."""
    names = misplaced([(a, b, n, agrees(rotation, direction)) for a, b, n, rotation, direction in residuals])
    frame_ids = {im.name: im.frame_id for im in rec.images.values()}
    for name in names:
        rec.deregister_frame(frame_ids[name])
    if names:
        log.warning("sfm: left out %d photo%s posed where none of its matched pairs puts it (a repeating texture or "
                    "a bare wall matched elsewhere?): %s", len(names), "s" * (len(names) > 1),
                    ", ".join(names[:10]) + (" ..." if len(names) > 10 else ""))
    return names


class KeptModel(NamedTuple):
    """A photo collection's model on its way out of SfM."""

    reconstruction: object  # pycolmap.Reconstruction
    model_dir: Path
    distortion: dict  # its distortion test ({} when none ran)
    displaced: list[str]  # photos the placement check left unposed
    residuals: list[PairResidual]  # pair_residuals of the photos still posed


def checked_model(rec, model_dir: Path, distortion: dict, database_path: Path, config: SfMConfig) -> KeptModel:
    """`rec` through the placement check (when on), with the pair residuals pair pruning weighs it by (when on).
    Unposing a photo moves no other, so the residuals of the pairs left are those measured before the check."""
    if not (config.placement_check or config.pair_pruning):
        return KeptModel(rec, model_dir, distortion, [], [])
    residuals = pair_residuals(rec, posed_pairs(rec, database_path))
    displaced = drop_misplaced_photos(rec, residuals) if config.placement_check else []
    left = set(displaced)
    return KeptModel(rec, model_dir, distortion, displaced,
                     [r for r in residuals if r[0] not in left and r[1] not in left])


def copy_database_without(database_path: Path, out_path: Path, pairs: list[tuple[str, str]]) -> Path:
    """Copy the COLMAP database to `out_path` without the verified geometries of `pairs` (image names)."""
    rio.remove_path(out_path)
    shutil.copyfile(database_path, out_path)
    db = _pycolmap().Database.open(out_path)
    try:
        ids = {im.name: im.image_id for im in db.read_all_images()}
        for a, b in pairs:
            db.delete_two_view_geometry(ids[a], ids[b])
    finally:
        db.close()
    return out_path


def map_without_gross_pairs(first: KeptModel, database_path: Path, image_dir: Path, work_dir: Path,
                            attempt: MappingAttempt, config: SfMConfig, timings: dict[str, float]) -> tuple[KeptModel, dict]:
    """Map a photo collection again without the verified pairs far off the first model (poses/placement.py:
    repeated textures matched across walls) and keep whichever model more of all the pairs' inliers agree with.

    `first` has been through the placement check, so a misplaced photo's pairs neither count as far off nor
    against it. The second mapping runs on a copy of the database (database_pruned.db) with the same attempt,
    the distortion test when the first had one, and the placement check. Returns the kept model and a report."""
    t0 = time.perf_counter()
    residuals = first.residuals
    gross = [(a, b) for a, b, _, rotation, direction in residuals if grossly_off(rotation, direction)]
    report = {"pairs": len(residuals), "pruned": len(gross), "kept": "first"}
    if not gross:
        return first, report
    pruned_db = copy_database_without(database_path, work_dir / "database_pruned.db", gross)
    out = work_dir / "sparse" / f"{attempt.label}-pruned"
    models = _models_or_none(pruned_db, image_dir, out, attempt, config, timings,
                             "mapping without the pairs far off the first model")
    if not models:
        return first, report
    index, rec = _largest_model(models)
    distortion = first.distortion
    if distortion:  # the first model went through the distortion test: so does the second
        rec, distortion = distortion_test(rec, config, timings)
    second = checked_model(rec, out / str(index), distortion, database_path, config)
    first_inliers, second_inliers = agreeing_inliers(residuals), agreeing_inliers(second.residuals)
    report.update(agreeing_inliers_first=first_inliers, agreeing_inliers_pruned=second_inliers,
                  registered_pruned=rec.num_reg_images())
    timings["pair_pruning"] = time.perf_counter() - t0
    if second_inliers <= first_inliers:
        return first, report
    report["kept"] = "pruned"
    log.info("sfm: kept the mapping without %d of %d pairs far off the first model (%d against %d agreeing inliers)",
             len(gross), len(residuals), second_inliers, first_inliers)
    return second, report


def _models_or_none(database_path: Path, image_dir: Path, out: Path, attempt: MappingAttempt, config: SfMConfig,
                    timings: dict[str, float], what: str) -> dict:
    """map_images, with a mapper failure logged as `what` failed and returned as no models."""
    try:
        return map_images(database_path, image_dir, out, attempt, config, timings)
    except (RuntimeError, ValueError) as exc:  # pycolmap reports mapper failures as plain exceptions
        log.warning("sfm: %s failed: %s", what, exc)
        return {}


def _check_parallax(database_path: Path, image_dir: Path, work_dir: Path, config: SfMConfig, n: int) -> float:
    """Refuse a camera that only turned (or matched nothing) before any mapping."""
    parallax = homography_parallax(database_path)
    if parallax is None:
        raise ReconError(_failure_message(0, n, work_dir, []))
    if parallax < config.min_parallax:
        raise ReconError(
            f"{image_dir}: the camera barely moved: it stood still or only turned (parallax score {parallax:.4f}, needs "
            f"{config.min_parallax}; COLMAP files kept in {work_dir}): depth needs parallax, so walk the camera "
            "sideways while filming, or supply poses (Stray Scanner, transforms.json)")
    return parallax


def _map_until_enough(database_path: Path, image_dir: Path, work_dir: Path, plan: list[MappingAttempt],
                      config: SfMConfig, timings: dict[str, float], attempts: list[dict], n: int) -> tuple:
    """Run the plan's attempts until one registers `retry_below` of the frames.

    Returns the best (registered, attempt, model dir, Reconstruction); the first wins a tie.
    """
    best: tuple = (0, plan[0], None, None)
    for attempt in plan:
        out = work_dir / "sparse" / attempt.label
        models = _models_or_none(database_path, image_dir, out, attempt, config, timings, f"{attempt.label} mapping")
        registered = 0
        if models:
            index, rec = _largest_model(models)
            registered = rec.num_reg_images()
            if registered > best[0]:
                best = (registered, attempt, out / str(index), rec)
        attempts.append({"attempt": attempt.label, "registered": registered})
        log.info("sfm: %s registered %d of %d frames", attempt.label, registered, n)
        if best[0] >= config.retry_below * n:
            break
    return best


def _first_mapping(database_path: Path, image_dir: Path, work_dir: Path, config: SfMConfig,
                   timings: dict[str, float], attempts: list[dict], n: int, short_clip: bool) -> tuple:
    """The plan's attempts until one registers enough; for a short clip, every attempt with the first's camera
    model, compared by agreement (_map_most_agreed), and the other camera model only when none registers
    enough (a radial model is kept only where the distortion test or the user asks for it)."""
    plan = mapping_plan(config)
    if not short_clip:
        return _map_until_enough(database_path, image_dir, work_dir, plan, config, timings, attempts, n)
    same_camera = [a for a in plan if a.distortion == plan[0].distortion]
    best = _map_most_agreed(database_path, image_dir, work_dir, same_camera, config, timings, attempts, n)
    other_camera = [a for a in plan if a not in same_camera]
    if max(row["registered"] for row in attempts) < config.retry_below * n and other_camera:
        best = max(best, _map_until_enough(database_path, image_dir, work_dir, other_camera, config, timings,
                                           attempts, n), key=lambda b: b[0])
    return best


def _map_most_agreed(database_path: Path, image_dir: Path, work_dir: Path, plan: list[MappingAttempt],
                     config: SfMConfig, timings: dict[str, float], attempts: list[dict], n: int) -> tuple:
    """A short clip: run every attempt of the plan and keep the model whose matched pairs' own geometry agrees
    with it most (agreeing_inliers). A walk of a few seconds constrains the focal length weakly, and each
    mapper can settle on a bent model that registers every frame (docs/poses.md); the pairs tell them apart.

    Returns the kept (registered, attempt, model dir, Reconstruction); the first wins a tie, and a model under
    `min_registered_fraction` of the frames never wins over one above it.
    """
    enough = max(3, int(np.ceil(config.min_registered_fraction * n)))
    best, best_key = (0, plan[0], None, None), (False, -1)
    for attempt in plan:
        out = work_dir / "sparse" / attempt.label
        models = _models_or_none(database_path, image_dir, out, attempt, config, timings, f"{attempt.label} mapping")
        row = {"attempt": attempt.label, "registered": 0}
        if models:
            index, rec = _largest_model(models)
            t0 = time.perf_counter()
            agreeing = agreeing_inliers(pair_residuals(rec, posed_pairs(rec, database_path)))
            timings["compare_attempts"] = timings.get("compare_attempts", 0.0) + time.perf_counter() - t0
            row.update(registered=rec.num_reg_images(), agreeing_inliers=agreeing)
            key = (row["registered"] >= enough, agreeing)
            if key > best_key:
                best, best_key = (row["registered"], attempt, out / str(index), rec), key
        attempts.append(row)
        log.info("sfm: %s registered %d of %d frames (%s agreeing inliers)", attempt.label, row["registered"], n,
                 row.get("agreeing_inliers", 0))
    return best


def _largest_model(models: dict) -> tuple[int, object]:
    """(index, Reconstruction) of the model with the most registered images; the lowest index wins a tie."""
    return max(sorted(models.items()), key=lambda kv: kv[1].num_reg_images())


def distortion_test(rec, config: SfMConfig, timings: dict[str, float]) -> tuple[object, dict]:
    """Does the data show lens distortion? Bundle-adjust the pinhole model twice, once with one radial
    coefficient free, and compare the reprojection errors where distortion acts and where it does not.
    A lens bends points by about r^3: (0.7 / 0.4)^3 = 5 times more beyond `OUTER_RING` of the
    half-diagonal than inside `INNER_RING`. So the radial model is kept only when it lowers the outer
    ring's error by `min_distortion_gain` and that gain is `RING_CONTRAST` times the centre's. Overall
    error is no guide: a weakly constrained clip trades a wrong focal length for distortion at almost no
    cost, and the gain is then spread over the whole image (a rendered pinhole room: k1 0.09, outer
    gain 1.2 %, only twice the centre's), while a real lens (7-Scenes kitchen, k1 -0.025) cuts the outer
    ring's error by 1.8 %, 23 times the centre's 0.08 %. Returns (model, measurements).
    """
    pycolmap = _pycolmap()
    t0 = time.perf_counter()

    def adjusted(radial: bool):
        model = pycolmap.Reconstruction(rec)  # the database camera is SIMPLE_RADIAL with k held at 0
        options = pycolmap.BundleAdjustmentOptions()
        options.refine_extra_params = radial
        options.print_summary = False
        options.ceres.solver_options.num_threads = _ordered_threads(config)
        pycolmap.bundle_adjustment(model, options)
        return model, ring_errors(model)

    # Two independent adjustments of two copies, each on its own thread count: side by side (pycolmap
    # releases the GIL) they give the same models as one after the other, in about half the time.
    with ThreadPoolExecutor(2) as pool:
        models, errors = zip(*pool.map(adjusted, (False, True)))  # indexed by radial: False 0, True 1
    (inner0, outer0), (inner1, outer1) = errors
    gain = 1.0 - outer1 / outer0 if outer0 > 0 else 0.0
    inner_gain = 1.0 - inner1 / inner0 if inner0 > 0 else 0.0
    kept = bool(gain >= config.min_distortion_gain and gain >= RING_CONTRAST * max(inner_gain, 0.0))
    cam = next(iter(models[True].cameras.values()))
    timings["distortion_test"] = time.perf_counter() - t0
    result = {"outer_error_pinhole_px": round(outer0, 4), "outer_error_radial_px": round(outer1, 4),
              "gain": round(gain, 4), "inner_gain": round(inner_gain, 4), "radial_k1": round(float(cam.params[3]), 5),
              "kept": kept}
    log.info("sfm: radial distortion %s (reprojection error at the border %.3f -> %.3f px, %.1f %% lower, in the "
             "centre %.1f %%; needs %.1f %% and %g times the centre's)", "kept" if kept else "not needed", outer0,
             outer1, 100 * gain, 100 * inner_gain, 100 * config.min_distortion_gain, RING_CONTRAST)
    return models[kept], result


INNER_RING, OUTER_RING = 0.4, 0.7  # shares of the half-diagonal: the centre, and where the border begins
RING_CONTRAST = 4.0  # a lens's gain at the border over its gain in the centre (about 5 for r^3, some slack)


def ring_errors(rec) -> tuple[float, float]:
    """Mean reprojection errors (px) of the observations inside INNER_RING and beyond OUTER_RING of the
    image half-diagonal."""
    sums, counts = np.zeros(2), np.zeros(2)
    for im in rec.images.values():
        if not im.has_pose:
            continue
        observed = [(p.xy, p.point3D_id) for p in im.points2D if p.has_point3D()]
        if not observed:
            continue
        cam = rec.cameras[im.camera_id]
        xy = np.array([o[0] for o in observed], dtype=np.float64)
        world = np.array([rec.points3D[o[1]].xyz for o in observed])
        m = np.asarray(_cam_from_world(im).matrix(), dtype=np.float64)
        error = np.linalg.norm(cam.img_from_cam(world @ m[:, :3].T + m[:, 3], check_cheirality=False) - xy, axis=1)
        half = np.array([cam.width, cam.height], dtype=np.float64) / 2
        radius = np.linalg.norm(xy - half, axis=1) / np.linalg.norm(half)
        for ring, inside in enumerate((radius < INNER_RING, radius > OUTER_RING)):
            sums[ring] += error[inside].sum()
            counts[ring] += inside.sum()
    inner, outer = np.divide(sums, counts, out=np.zeros(2), where=counts > 0)
    return float(inner), float(outer)


def _cam_from_world(image):
    cfw = image.cam_from_world
    return cfw() if callable(cfw) else cfw


def _failure_message(registered: int, total: int, work_dir: Path, attempts: list[dict]) -> str:
    tried = f"; tried {', '.join(a['attempt'] for a in attempts)}" if attempts else ""
    return (f"SfM registered {registered} of {total} frames (COLMAP files kept in {work_dir}{tried}): the frames "
            "overlap too little; move slower, use more frames (smaller --stride, higher --fps), or supply poses")


def sparse_depths(reconstruction) -> dict[str, np.ndarray]:
    """Camera-space depth (z) of every triangulated point each registered image observes, keyed by frame name."""
    points = reconstruction.points3D
    out = {}
    for im in reconstruction.images.values():
        if not im.has_pose:
            continue
        cfw = _cam_from_world(im)
        xyz = np.array([points[p.point3D_id].xyz for p in im.points2D if p.has_point3D()], dtype=np.float64)
        name = Path(im.name).with_suffix("").as_posix().replace("/", "_")
        if not len(xyz):
            out[name] = np.zeros(0)
            continue
        m = np.asarray(cfw.matrix(), dtype=np.float64)
        z = xyz @ m[2, :3] + m[2, 3]
        out[name] = z[z > 0]
    return out


def scan_from_sfm(result: SfMResult) -> Scan:
    """The kept model as a canonical scan: unknown scale, registered frames only, distortion on the scan."""
    from recon.readers.colmap import scan_from_reconstruction

    scan = scan_from_reconstruction(result.reconstruction, result.image_dir, source_format="sfm")
    if scan.distortion is not None and not np.any(scan.distortion):
        scan.distortion = None  # a radial model whose distortion stayed at zero is a pinhole
    scan.metadata.metric_scale = False
    scan.metadata.extra["sfm"] = {
        "mapper": result.mapper, "matcher": result.matcher, "loops": result.loops, "registered": len(result.registered),
        "unregistered": [Path(n).stem for n in result.unregistered], "attempts": result.attempts,
        "unregistered_links": {Path(n).stem: k for n, k in result.links.items()},
        "displaced": [Path(n).stem for n in result.displaced], "pair_pruning": result.pruning,
        "timings_s": {k: round(v, 2) for k, v in result.timings.items()}, "camera": result.camera,
        "distortion_test": result.distortion, "parallax": round(result.parallax, 4),
        "colmap_dir": str(result.work_dir), "model_dir": str(result.model_dir), **model_statistics(result.reconstruction)}
    return scan


def model_statistics(rec) -> dict:
    """What says how well a model is constrained: points, track lengths (with their histogram), reprojection error."""
    lengths = np.array([p.track.length() for p in rec.points3D.values()], dtype=int)
    counts = np.bincount(np.minimum(lengths, 12), minlength=13)  # 12 stands for "12 or more"
    return {"points3D": int(rec.num_points3D()), "mean_track_length": round(float(rec.compute_mean_track_length()), 2),
            "mean_reprojection_error_px": round(float(rec.compute_mean_reprojection_error()), 3),
            "mean_observations_per_image": round(float(rec.compute_mean_observations_per_reg_image()), 1),
            "track_length_histogram": {str(k): int(counts[k]) for k in range(2, 13) if counts[k]}}


# -- the whole stage -------------------------------------------------------------------------------

@dataclass
class PosesConfig:
    """Everything `estimate_poses` needs; each part documents its own fields."""

    ingest: IngestConfig = field(default_factory=IngestConfig)
    sfm: SfMConfig = field(default_factory=SfMConfig)
    scale: ScaleConfig = field(default_factory=ScaleConfig)


REPORT_FILE = "poses_report.json"


def estimate_poses(source: str | os.PathLike, out_dir: str | os.PathLike, config: PosesConfig | None = None,
                   reference: Scan | None = None) -> tuple[Scan, dict]:
    """Video / image folder / recorded scan -> SfM poses -> scaled canonical scan in `out_dir`.

    `out_dir` gets frames/ (the images SfM saw), colmap/ (database and models), the canonical
    scan (scan.json + undistorted images/) and poses_report.json. A recorded scan's own poses
    are ignored, and its frame names kept, so the result can be scored against them. On a
    ReconError everything computed so far stays, and the report says what failed.
    """
    config = config or PosesConfig()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "scan.json").unlink(missing_ok=True)  # never leave an older run's scan looking current
    report: dict = {"input": str(source), "out": str(out_dir)}
    timings: dict[str, float] = {}
    try:
        t0 = time.perf_counter()
        frames = ingest(source, out_dir / "frames", config.ingest)
        timings["ingest"] = time.perf_counter() - t0
        report["ingest"] = frames.summary()
        by_file = {f.path.name: f for f in frames.frames}
        result = run_sfm(frames.image_dir, sorted(by_file), out_dir / "colmap", config.sfm, frames.camera,
                         ordered=frames.kind != "images")
        timings.update(result.timings)
        scan = scan_from_sfm(result)
        by_name = {f.name: f for f in frames.frames}
        for f in scan.frames:
            f.source_index, f.timestamp = by_name[f.name].source_index, by_name[f.name].timestamp
        scan.metadata.source = str(source)
        scan.metadata.extra["ingest"] = frames.summary()
        depths = sparse_depths(result.reconstruction)
        report["sfm"] = scan.metadata.extra["sfm"]
        scan, scale = resolve_scale(scan, depths, config.scale, reference)
        report["scale"] = scale.to_dict()
        report["metric_scale"] = scan.metadata.metric_scale
        t0 = time.perf_counter()
        _save_scan_into(scan, out_dir)
        timings["save"] = time.perf_counter() - t0
        report.update(registered=len(scan), frames=len(frames.frames),
                      unregistered=scan.metadata.extra["sfm"]["unregistered"])
    except ReconError as exc:
        report["error"] = str(exc)
        raise
    finally:
        report["timings_s"] = {k: round(v, 2) for k, v in timings.items()}
        rio.write_json_atomic(out_dir / REPORT_FILE, report)
    return scan, report


def _save_scan_into(scan: Scan, out_dir: Path) -> None:
    """Write the canonical scan beside frames/ and colmap/ (save_scan alone would replace the folder)."""
    staging = out_dir / ".scan.tmp"
    rio.remove_path(staging)
    save_scan(scan, staging)
    rio.remove_path(out_dir / "images")
    os.replace(staging / "images", out_dir / "images")
    os.replace(staging / "scan.json", out_dir / "scan.json")  # last: the scan exists once this lands
    rio.remove_path(staging)
