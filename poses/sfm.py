"""Camera poses for plain images through pycolmap: SIFT, matching, a parallax check, mapping.

Tuned for video of a room on a CPU: one shared camera with radial distortion (the
frames of a clip come from one lens), SIFT on images downscaled to about 640 px with
a capped feature count, sequential matching over a window of neighbours (exhaustive
for short clips, where it costs the same and finds more pairs), a check that the
camera moved rather than only turned (`homography_parallax`), then the incremental
mapper or the global one (GLOMAP, after view-graph calibration of the unknown focal
length), with the other one as a fallback when the first fails or registers too few
frames. The largest model wins and becomes a canonical scan with
`metadata.metric_scale = False`; the scan carries the lens distortion, so saving it
writes undistorted pinhole images (same K; cheaper than COLMAP's undistorter, which
would also re-encode every image).

Everything COLMAP computed stays under `<work_dir>`, so a user can open it in the
COLMAP GUI (File > Import model, with the frames folder as images): database.db and
sparse/<mapper>/<n>/. Frames that did not register are listed, never given a pose.
"""
from __future__ import annotations

import logging
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from poses.ingest import IngestConfig, ingest
from poses.scale import ScaleConfig, resolve_scale
from recon import io as rio
from recon.errors import ReconError
from recon.scan import Scan, save_scan

log = logging.getLogger(__name__)

MAPPERS = ("global", "incremental")
CAMERA_MODELS = ("SIMPLE_RADIAL", "OPENCV", "RADIAL", "PINHOLE", "SIMPLE_PINHOLE")


@dataclass
class SfMConfig:
    """pycolmap settings; the defaults pose 200 frames at 640x480 in about a minute on 2 cores (docs/poses.md)."""

    mapper: str = "incremental"  # "global" (GLOMAP) or "incremental"; see docs/poses.md for the comparison
    fallback: bool = True  # also try the other mapper when the first registers under `retry_below`; keep the larger
    retry_below: float = 0.9  # share of frames
    camera_model: str = "SIMPLE_RADIAL"  # one shared camera; OPENCV for strongly distorted lenses
    max_image_size: int = 640  # SIFT runs on images downscaled to this long side
    max_num_features: int = 2048  # per image; matching cost grows with its square
    first_octave: int | None = None  # None: -1 (upsampled octave) below 600 px, else 0 (~1.6x faster, enough there)
    sequential_overlap: int = 10  # each frame is matched with this many following frames
    exhaustive_below: int = 40  # clips with at most this many frames are matched all-pairs
    min_registered_fraction: float = 0.5  # a model with fewer frames is a failure
    min_parallax: float = 0.003  # homography_parallax below this: the camera only turned, refuse before mapping
    num_threads: int = -1  # -1: all cores
    seed: int = 0  # fixed RANSAC/mapper seeds so reruns agree


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
    attempts: dict[str, int] = field(default_factory=dict)  # mapper -> frames registered (0 = failed)
    camera: dict = field(default_factory=dict)  # the estimated (distorted) camera, for the report
    parallax: float = 0.0  # homography_parallax of the matches


def _pycolmap():
    """pycolmap, with COLMAP's own log lines (thousands per run) shown only when debugging."""
    import pycolmap

    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 2
    return pycolmap


def extract_and_match(image_dir: Path, image_names: list[str], database_path: Path, config: SfMConfig,
                      timings: dict[str, float]) -> None:
    """SIFT features (one shared camera) and verified matches into a fresh COLMAP database."""
    pycolmap = _pycolmap()
    if config.camera_model not in CAMERA_MODELS:
        raise ReconError(f"unsupported camera model {config.camera_model!r} (use one of {', '.join(CAMERA_MODELS)})")
    database_path.unlink(missing_ok=True)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = config.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = config.max_image_size
    extraction.num_threads = config.num_threads
    extraction.sift.max_num_features = config.max_num_features
    extraction.sift.first_octave = config.first_octave if config.first_octave is not None else _first_octave(image_dir,
                                                                                                           image_names)
    t0 = time.perf_counter()
    pycolmap.extract_features(database_path, image_dir, image_names=image_names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    timings["extract"] = time.perf_counter() - t0

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = config.num_threads
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = config.seed
    t0 = time.perf_counter()
    if len(image_names) <= config.exhaustive_below:
        pycolmap.match_exhaustive(database_path, matching_options=matching, verification_options=verification,
                                  device=pycolmap.Device.cpu)
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = config.sequential_overlap
        pairing.quadratic_overlap = False
        pairing.loop_detection = False  # needs a vocabulary tree download; rooms are short clips
        pycolmap.match_sequential(database_path, matching_options=matching, pairing_options=pairing,
                                  verification_options=verification, device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - t0


def _first_octave(image_dir: Path, image_names: list[str]) -> int:
    """SIFT's upsampled octave finds the small features low-resolution frames need; 640 px frames have enough."""
    import cv2

    first = cv2.imread(str(image_dir / image_names[0]), cv2.IMREAD_GRAYSCALE)
    return -1 if first is None or max(first.shape) < 600 else 0


def map_images(database_path: Path, image_dir: Path, output_dir: Path, mapper: str, config: SfMConfig,
               timings: dict[str, float]) -> dict:
    """Run one mapper; returns {model index: Reconstruction} (each written to output_dir/<index>)."""
    pycolmap = _pycolmap()
    if output_dir.exists():
        shutil.rmtree(output_dir)
    output_dir.mkdir(parents=True)
    pycolmap.set_random_seed(config.seed)
    t0 = time.perf_counter()
    if mapper == "global":
        # GLOMAP's rotation averaging needs calibrated pairs; a video's focal length is unknown, and
        # skipping this step leaves the default focal guess in place and collapses the trajectory.
        calibration = pycolmap.ViewGraphCalibrationOptions()
        calibration.random_seed = config.seed
        pycolmap.calibrate_view_graph(database_path, calibration)
        timings["calibrate"] = time.perf_counter() - t0
        options = pycolmap.GlobalPipelineOptions()
        options.num_threads = config.num_threads
        options.random_seed = config.seed
        t1 = time.perf_counter()
        models = pycolmap.global_mapping(database_path, image_dir, output_dir, options)
        timings["map_global"] = time.perf_counter() - t1
    elif mapper == "incremental":
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = config.num_threads
        options.random_seed = config.seed
        # Video frames overlap heavily: fewer, shorter global bundle adjustments lose no accuracy
        # (7-Scenes ATE unchanged) and halve mapping time.
        options.ba_global_frames_ratio = 1.4
        options.ba_global_points_ratio = 1.4
        options.ba_global_max_num_iterations = 25
        options.ba_local_max_num_iterations = 10
        # Neighbouring video frames rarely reach COLMAP's 16 degree initial-pair angle.
        options.mapper.init_min_tri_angle = 8.0
        models = pycolmap.incremental_mapping(database_path, image_dir, output_dir, options)
        timings["map_incremental"] = time.perf_counter() - t0
    else:
        raise ReconError(f"unknown mapper {mapper!r} (use one of {', '.join(MAPPERS)})")
    return dict(models)


def homography_parallax(database_path: Path) -> float | None:
    """How far the matched views are from a camera that only turned on the spot (0 = pure rotation).

    Two views of a turning camera are related by H = K R K^-1, whose eigenvalues (after scaling
    to det 1) all have modulus 1 whatever K is; translation against a 3D scene pulls them apart.
    The score is the median, over the quarter of verified pairs furthest apart in the sequence,
    of max |log |eigenvalue|| of COLMAP's homography. Rooms filmed while walking score 0.02-0.05,
    a slow 3 s clip 0.007, a camera turning on a tripod 0.001. None when no pair matched.
    """
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(database_path)
    try:
        pair_ids, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    gaps, scores = [], []
    for pair_id, geometry in zip(pair_ids, geometries):
        H = np.asarray(geometry.H, dtype=np.float64)
        det = np.linalg.det(H) if H.shape == (3, 3) and np.all(np.isfinite(H)) else 0.0
        if abs(det) < 1e-12:
            continue
        moduli = np.abs(np.linalg.eigvals(H / np.cbrt(det)))
        a, b = pycolmap.pair_id_to_image_pair(pair_id)
        gaps.append(abs(int(b) - int(a)))
        scores.append(float(np.max(np.abs(np.log(moduli)))))
    if not scores:
        return None
    gaps, scores = np.array(gaps), np.array(scores)
    return float(np.median(scores[gaps >= np.percentile(gaps, 75)]))


def run_sfm(image_dir: str | os.PathLike, image_names: list[str], work_dir: str | os.PathLike,
            config: SfMConfig | None = None) -> SfMResult:
    """Reconstruct `image_names` (files in `image_dir`) into `work_dir`; raises ReconError on failure.

    On failure everything computed so far (database, any partial models) stays in `work_dir`.
    """
    config = config or SfMConfig()
    if config.mapper not in MAPPERS:
        raise ReconError(f"unknown mapper {config.mapper!r} (use one of {', '.join(MAPPERS)})")
    image_dir, work_dir = Path(image_dir), Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    database_path = work_dir / "database.db"
    timings: dict[str, float] = {}
    t_start = time.perf_counter()
    extract_and_match(image_dir, image_names, database_path, config, timings)
    parallax = homography_parallax(database_path)
    if parallax is None:
        raise ReconError(_failure_message(0, len(image_names), work_dir))
    if parallax < config.min_parallax:
        raise ReconError(
            f"{image_dir}: the camera turned on the spot without moving (parallax score {parallax:.4f}, needs "
            f"{config.min_parallax}; COLMAP files kept in {work_dir}): depth needs parallax, so walk the camera "
            "sideways while filming, or supply poses (Stray Scanner, transforms.json)")

    needed = max(3, int(np.ceil(config.min_registered_fraction * len(image_names))))
    order = [config.mapper] + ([m for m in MAPPERS if m != config.mapper] if config.fallback else [])
    attempts: dict[str, int] = {}
    best = None  # (registered, mapper, index, reconstruction)
    for mapper in order:
        try:
            models = map_images(database_path, image_dir, work_dir / "sparse" / mapper, mapper, config, timings)
        except (RuntimeError, ValueError) as exc:  # pycolmap reports mapper failures as plain exceptions
            log.warning("sfm: %s mapper failed: %s", mapper, exc)
            models = {}
        if models:
            index, rec = max(models.items(), key=lambda kv: kv[1].num_reg_images())
            attempts[mapper] = rec.num_reg_images()
            if best is None or rec.num_reg_images() > best[0]:
                best = (rec.num_reg_images(), mapper, index, rec)
        else:
            attempts[mapper] = 0
        log.info("sfm: %s mapper registered %d of %d frames", mapper, attempts[mapper], len(image_names))
        if best is not None and best[0] >= config.retry_below * len(image_names):
            break

    if best is None or best[0] < needed:
        got = 0 if best is None else best[0]
        raise ReconError(_failure_message(got, len(image_names), work_dir))

    _, mapper, index, rec = best
    model_dir = work_dir / "sparse" / mapper / str(index)
    timings["sfm_total"] = time.perf_counter() - t_start
    registered = sorted(im.name for im in rec.images.values() if im.has_pose)
    unregistered = sorted(set(image_names) - set(registered))
    cam = next(iter(rec.cameras.values()))
    camera = {"model": cam.model_name, "width": cam.width, "height": cam.height,
              "params": [float(p) for p in cam.params]}
    if unregistered:
        log.warning("sfm: %d of %d frames did not register and are left out: %s", len(unregistered),
                    len(image_names), ", ".join(unregistered[:10]) + (" ..." if len(unregistered) > 10 else ""))
    return SfMResult(rec, image_dir, mapper, registered, unregistered, timings, work_dir, database_path, model_dir,
                     attempts, camera, parallax)


def _failure_message(registered: int, total: int, work_dir: Path) -> str:
    return (f"SfM registered {registered} of {total} frames (COLMAP files kept in {work_dir}): the frames overlap "
            "too little; move slower, use more frames (smaller --stride, higher --fps), or supply poses")


def sparse_depths(reconstruction) -> dict[str, np.ndarray]:
    """Camera-space depth (z) of every triangulated point each registered image observes, keyed by frame name."""
    points = reconstruction.points3D
    out = {}
    for im in reconstruction.images.values():
        if not im.has_pose:
            continue
        cfw = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
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
    scan.metadata.metric_scale = False
    scan.metadata.extra["sfm"] = {
        "mapper": result.mapper, "registered": len(result.registered),
        "unregistered": [Path(n).stem for n in result.unregistered], "attempts": result.attempts,
        "timings_s": {k: round(v, 2) for k, v in result.timings.items()}, "camera": result.camera,
        "parallax": round(result.parallax, 4),
        "colmap_dir": str(result.work_dir)}
    return scan


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
        result = run_sfm(frames.image_dir, sorted(by_file), out_dir / "colmap", config.sfm)
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
    if staging.exists():
        shutil.rmtree(staging)
    save_scan(scan, staging)
    if (out_dir / "images").exists():
        shutil.rmtree(out_dir / "images")
    os.replace(staging / "images", out_dir / "images")
    os.replace(staging / "scan.json", out_dir / "scan.json")  # last: the scan exists once this lands
    shutil.rmtree(staging)
