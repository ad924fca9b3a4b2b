"""The end-to-end run: input -> canonical scan -> depth -> mesh -> evaluation -> report.

Each stage reads and writes files in the run folder, records itself in `run.json`
(options fingerprint, wall time, peak memory) and is skipped on a re-run when its
outputs exist for the same options; `force` redoes a stage and everything after it.
A lock file keeps two runs out of one folder.

    DIR/scan/            canonical scan of the selected frames (poses supplied or from SfM)
    DIR/.scan-sfm/       where SfM builds the scan (it replaces scan/ once SfM succeeded)
    DIR/keyframes.json   frames the depth stage estimates (camera-motion keyframes)
    DIR/depth/           <frame>.png/.conf.png (depth mm, confidence; the network grid) + depth.json
    DIR/mesh.ply         fused, cleaned mesh
    DIR/reference.ply    GT mesh used for scoring (given, or the fusion of GT depth)
    DIR/metrics.json     depth / temporal / mesh / pose metrics
    DIR/report.json, DIR/report.html
"""
from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import hashlib
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, ContextManager, Iterator

import numpy as np

from depth.checkpoint import DEFAULT_WEIGHTS, INDOOR_DEPTH_RANGE, load_checkpoint, trained_depth_range, weights_digest
from depth.inference import estimate_depth
from depth.metrics import DEPTH_KEYS, evaluate_depth_folder
from depth.options import DepthOptions
from fusion.evaluate import mesh_metrics
from fusion.filtering import FilterConfig, filtered_depth
from fusion.mesh import MeshCleanup, load_mesh, save_mesh
from fusion.tsdf import TSDFConfig, fuse_scan
from poses.evaluate import pose_metrics
from poses.sfm import PosesConfig
from recon.errors import ReconError, naming
from recon.io import fingerprint_input, remove_path, replace_dir, write_json_atomic
from recon.keyframes import KeyframeConfig, select_keyframes
from recon.readers import FORMATS, detect_format, open_scan
from recon.scan import Scan, gt_mesh_path, load_scan, save_scan

from .resources import measure

log = logging.getLogger("recon")

STAGES = ("scan", "depth", "fusion", "reference", "evaluate", "report")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")
POSE_SOURCES = ("auto", "supplied", "colmap")
SFM_STAGING = ".scan-sfm"  # where SfM builds the scan before it replaces scan/
# Folders the stages empty and refill: a link among them would let cleaning or writing reach outside the run folder.
STAGE_FOLDERS = ("scan", "scan/frames", "scan/images", "scan/depth", "scan/colmap", SFM_STAGING, "depth",
                 "depth/.estm-memory")


@dataclass(frozen=True)
class InputConfig:
    """What the run reads: the input and which of its frames, and where poses come from."""

    path: str = ""
    format: str = "auto"
    poses: str = "auto"  # auto: the input's own poses when it has them, SfM otherwise; colmap: always SfM
    start: int = 0
    stride: int = 1
    max_frames: int | None = None
    gt_poses: str | None = None  # a scan whose poses score SfM's (a recorded input serves by itself)

    def validate(self) -> "InputConfig":
        if self.poses not in POSE_SOURCES:
            raise ReconError(f"unknown --poses {self.poses!r} ({', '.join(POSE_SOURCES)})")
        if self.format != "auto" and self.format not in FORMATS:
            raise ReconError(f"unknown --format {self.format!r} (known: auto, {', '.join(FORMATS)})")
        if self.start < 0 or self.stride < 1 or (self.max_frames is not None and self.max_frames < 1):
            given = f"--start {self.start} --stride {self.stride}" + (
                f" --max-frames {self.max_frames}" if self.max_frames is not None else "")
            raise ReconError(f"invalid frame selection ({given}): need --start >= 0, --stride >= 1, --max-frames >= 1")
        for option, path in (("input", self.path), ("--gt-poses", self.gt_poses)):
            if path and not Path(path).exists():
                raise ReconError(f"{path}: no such file or folder ({option})")
        return self


@dataclass(frozen=True)
class EvalConfig:
    gt_mesh: str | None = None  # None: the scan's own GT mesh, or the fusion of its GT depth
    max_depth: float = 10.0  # depth evaluation range end (metres)

    def validate(self) -> "EvalConfig":
        """The mesh file must exist now; its content is read (and refused if broken) by the reference stage."""
        if self.gt_mesh and not Path(self.gt_mesh).is_file():
            raise ReconError(f"{self.gt_mesh}: mesh file not found (--gt-mesh)")
        if not self.max_depth > 0:
            raise ReconError(f"the depth evaluation range must end above 0 m, got {self.max_depth}")
        return self


@dataclass(frozen=True)
class ReportConfig:
    frames: int = 6  # keyframes shown as image / depth / error panels


@dataclass
class RunConfig:
    """Everything that decides a run's outputs, composed of the stages' own configs."""

    input: InputConfig
    out: str
    sfm: PosesConfig = field(default_factory=PosesConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    depth: DepthOptions = field(default_factory=DepthOptions)
    fusion: TSDFConfig = field(default_factory=TSDFConfig)
    depth_filter: FilterConfig = field(default_factory=FilterConfig)  # what fusion trusts of the predicted depth
    cleanup: MeshCleanup = field(default_factory=MeshCleanup)
    evaluation: EvalConfig = field(default_factory=EvalConfig)
    report: ReportConfig = field(default_factory=ReportConfig)

    def validate(self) -> "RunConfig":
        """Every option checked before the first stage runs (files named by options must exist; weights
        given by path must be a readable checkpoint)."""
        if self.out and Path(self.out).exists() and not Path(self.out).is_dir():
            raise ReconError(f"{self.out}: exists and is not a folder (--out names the run folder)")
        self.input.validate()
        self.sfm.ingest.validate()
        self.sfm.sfm.validate()
        self.keyframes.validate()
        self.depth.validate()
        self.fusion.validate()
        self.depth_filter.validate()
        self.cleanup.validate()
        self.evaluation.validate()
        if self.report.frames < 0:
            raise ReconError(f"the report cannot show {self.report.frames} frames")
        if self.depth.mode != "planesweep" and self.depth.weights:
            load_checkpoint(self.depth.weights)
        return self

    def stage_options(self, stage: str) -> dict:
        """What a stage's outputs depend on: its options, and the content of the files they name (the input, a
        GT mesh or scan, the weights) by resolved path, sizes, times and metadata hashes, never by the path as
        typed. Device choice is not among them."""
        a = dataclasses.asdict
        if stage == "scan":
            if not self.input.path:
                raise ReconError("no input given (a video, an image folder or a scan)")
            scan_input = {k: v for k, v in a(self.input).items() if k not in ("gt_poses", "path")}
            scan_input["content"] = fingerprint_input(self.input.path, exclude=self.out)
            return {"input": scan_input, "sfm": a(self.sfm), "keyframes": a(self.keyframes)}
        if stage == "depth":
            options = {k: v for k, v in a(self.depth).items() if k not in ("device", "compile", "weights")}
            learned = self.depth.mode != "planesweep"
            options["weights_digest"] = weights_digest(self.depth.weights or DEFAULT_WEIGHTS) if learned else None
            return options
        fusion = {k: v for k, v in a(self.fusion).items() if k != "device"}
        gt_mesh, gt_poses = self.evaluation.gt_mesh, self.input.gt_poses
        return {
            "fusion": {**fusion, "filter": a(self.depth_filter), "cleanup": a(self.cleanup)},
            "reference": {"gt_mesh": fingerprint_input(gt_mesh) if gt_mesh else None, "fusion": fusion,
                          "gt_poses": fingerprint_input(gt_poses) if gt_poses else None},
            "evaluate": {**{k: v for k, v in a(self.evaluation).items() if k != "gt_mesh"},  # reference.ply's
                         "gt_poses": fingerprint_input(gt_poses) if gt_poses else None},
            "report": a(self.report),
        }[stage]


@dataclass
class StageRecord:
    done: bool = False
    fingerprint: str = ""
    seconds: float = 0.0
    peak_rss_mb: float = 0.0
    info: dict = field(default_factory=dict)


def _fingerprint(options: dict) -> str:
    return hashlib.sha1(json.dumps(options, sort_keys=True, default=str).encode()).hexdigest()[:16]


class RunLock:
    """An exclusive lock on the run folder (released by the OS if the process dies)."""

    def __init__(self, folder: Path):
        self.path = folder / ".lock"
        self._fh = None

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "a+")
        try:
            fcntl.flock(self._fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._fh.seek(0)
            holder = self._fh.read().strip() or "?"
            self._fh.close()
            raise ReconError(f"{self.path.parent}: another run (pid {holder}) is using this folder") from None
        self._fh.seek(0)
        self._fh.truncate()
        self._fh.write(str(os.getpid()))
        self._fh.flush()
        return self

    def __exit__(self, *exc):
        fcntl.flock(self._fh, fcntl.LOCK_UN)
        self._fh.close()


class Pipeline:
    """Runs the stages of one input into one folder; each stage is also callable alone."""

    def __init__(self, config: RunConfig, progress: Callable[[str, int], ContextManager] | None = None):
        self.config = config
        self.out = Path(config.out)
        self.state_path = self.out / "run.json"
        self.records: dict[str, StageRecord] = {}
        self._progress = progress

    # -- state -------------------------------------------------------------------------------
    def _load_state(self) -> None:
        self.records = {}
        if self.state_path.is_file():
            try:
                doc = json.loads(self.state_path.read_text())
                self.records = {k: StageRecord(**v) for k, v in doc.get("stages", {}).items()}
            except (json.JSONDecodeError, TypeError):
                log.warning("%s unreadable: every stage runs again", self.state_path)

    def _save_state(self) -> None:
        write_json_atomic(self.state_path, {"config": dataclasses.asdict(self.config),
                                            "stages": {k: dataclasses.asdict(v) for k, v in self.records.items()}})

    def is_current(self, stage: str, fingerprint: str | None = None) -> bool:
        rec = self.records.get(stage)
        fingerprint = fingerprint or _fingerprint(self.config.stage_options(stage))
        return bool(rec and rec.done and rec.fingerprint == fingerprint)

    def check_folder(self) -> None:
        """Refuse a run folder whose stage folders are links: a stage empties and refills them, and would
        write (or delete) wherever a link points instead of inside the run folder."""
        for name in STAGE_FOLDERS:
            path = self.out / name
            if path.is_symlink():
                raise ReconError(f"{path}: is a link (to {os.readlink(path)}); a run folder's stage folders must be "
                                 "its own (remove the link)")

    # -- driver ------------------------------------------------------------------------------
    def run(self, force: tuple[str, ...] = (), until: str = "report") -> dict:
        """Run every stage up to `until`, skipping current ones; returns the report dict (or {})."""
        for name in force:
            if name not in STAGES:
                raise ReconError(f"unknown stage {name!r} (stages: {', '.join(STAGES)})")
        last = STAGES.index(until)
        self.config.validate()
        self.check_folder()
        with RunLock(self.out):
            self._load_state()
            first_forced = min((STAGES.index(f) for f in force), default=len(STAGES))
            redo_rest = False
            for i, stage in enumerate(STAGES[: last + 1]):
                # Taken before the stage runs: an input that changes meanwhile must not look current next time.
                fingerprint = _fingerprint(self.config.stage_options(stage))
                redo = redo_rest or i >= first_forced or not self.is_current(stage, fingerprint)
                if not redo:
                    log.info("%s: up to date, skipped", stage)
                    continue
                redo_rest = True  # everything downstream depends on this stage's outputs
                self._run_stage(stage, fingerprint)
        report = self.out / "report.json"
        return json.loads(report.read_text()) if report.is_file() and until == "report" else {}

    def _run_stage(self, stage: str, fingerprint: str) -> None:
        self.records.pop(stage, None)
        self._save_state()
        log.info("%s: running", stage)
        with measure() as usage:
            info = getattr(self, f"stage_{stage}")() or {}
        self.records[stage] = StageRecord(True, fingerprint, usage.seconds, usage.peak_rss_mb, info)
        self._save_state()
        log.info("%s: done in %.1f s (peak %.0f MB)", stage, usage.seconds, usage.peak_rss_mb)

    @contextlib.contextmanager
    def _bar(self, label: str, total: int) -> Iterator[Callable[[int, int], None]]:
        """A `progress(i, n)` callback for a stage's loop, backed by the caller's progress display."""
        if self._progress is None:
            yield lambda i, n: None
            return
        with self._progress(label, total) as advance:
            yield lambda i, n: advance(1)

    # -- stages ------------------------------------------------------------------------------
    def load_scan(self) -> Scan:
        return load_scan(self.out / "scan")

    def keyframe_names(self) -> list[str]:
        return json.loads((self.out / "keyframes.json").read_text())["keyframes"]

    def keyframe_scan(self) -> Scan:
        scan = self.load_scan()
        names = set(self.keyframe_names())
        return scan.subset([i for i, f in enumerate(scan.frames) if f.name in names])

    def stage_scan(self) -> dict:
        cfg = self.config.input
        src = Path(cfg.path)
        if not src.exists():
            raise ReconError(f"{src}: no such file or folder")
        if self._needs_sfm(src):
            self._sfm_scan(src)
        else:
            scan = open_scan(src, cfg.format).select(cfg.start, cfg.stride, cfg.max_frames)
            with self._bar("scan", len(scan)) as bar:
                save_scan(scan, self.out / "scan", progress=bar)
        scan = self.load_scan()
        keys = select_keyframes(scan.camera_to_world, self.config.keyframes)
        if len(keys) < 3:
            raise ReconError(f"{src}: only {len(keys)} keyframes after selection; the camera barely moves "
                             "(use more frames, or a lower --keyframe-distance)")
        write_json_atomic(self.out / "keyframes.json", {"keyframe_distance": self.config.keyframes.keyframe_distance,
                                                        "keyframes": [scan.frames[i].name for i in keys]})
        return {"frames": len(scan), "keyframes": len(keys), "metric_scale": scan.metadata.metric_scale,
                "source_format": scan.metadata.source_format, "has_depth": scan.has_depth,
                "width": scan.intrinsics.width, "height": scan.intrinsics.height}

    def _needs_sfm(self, src: Path) -> bool:
        poses = self.config.input.poses
        if poses == "colmap":
            return True
        if src.is_file() and src.suffix.lower() in VIDEO_SUFFIXES:
            if poses == "supplied":
                raise ReconError(f"{src}: a plain video has no poses to supply (use --poses colmap)")
            return True
        try:
            detect_format(src)
            return False
        except ReconError:
            if poses == "supplied" or not src.is_dir():
                raise
            return True  # a plain image folder

    def _sfm_scan(self, src: Path) -> Scan:
        from poses.sfm import estimate_poses

        if self.config.input.start:
            raise ReconError("--start is not supported when poses come from SfM (trim the video instead)")
        ingest = dataclasses.replace(self.config.sfm.ingest, stride=self.config.input.stride,
                                     max_frames=self.config.input.max_frames)
        # SfM works in a folder of its own and replaces scan/ only once it succeeded: a failed attempt keeps
        # the previous scan (and leaves its diagnostics in the staging folder).
        staging = self.out / SFM_STAGING
        remove_path(staging)
        with naming(src):  # SfM's messages name its working folders; the user needs to hear which input failed
            scan, _ = estimate_poses(src, staging, dataclasses.replace(self.config.sfm, ingest=ingest))
        replace_dir(staging, self.out / "scan")
        return scan

    def gt_poses_scan(self) -> Scan | None:
        """Ground-truth poses for an SfM run: --gt-poses, or the recorded scan SfM ignored the poses of."""
        cfg = self.config.input
        if cfg.gt_poses:
            return open_scan(cfg.gt_poses)
        src = Path(cfg.path)
        if cfg.poses == "colmap" and src.is_dir():
            try:
                detect_format(src)
            except ReconError:
                return None
            return open_scan(src)
        return None

    def depth_options(self, scan: Scan) -> DepthOptions:
        """The run's depth options with the weights and range settled (never from GT depth)."""
        opts = self.config.depth
        if opts.mode != "planesweep":
            opts = dataclasses.replace(opts, weights=opts.weights or DEFAULT_WEIGHTS)
        learned_range = trained_depth_range(opts.weights) if opts.mode != "planesweep" else None
        if opts.depth_range is None and learned_range is None and scan.metadata.depth_range is None:
            if not scan.metadata.metric_scale:
                raise ReconError(f"{self.config.input.path}: the scan's scale is unknown and it states no depth "
                                 "range: pass --depth-range MIN MAX in its units")
            # A recorded RGB-D scan rarely says; its GT depth must not decide it (that would leak ground truth).
            opts = dataclasses.replace(opts, depth_range=INDOOR_DEPTH_RANGE)
            log.info("depth: no depth range given, sweeping %.2f-%.2f m", *INDOOR_DEPTH_RANGE)
        return opts

    def stage_depth(self) -> dict:
        scan = self.keyframe_scan()
        opts = self.depth_options(scan)
        with self._bar("depth", len(scan)) as bar:
            summary = estimate_depth(scan, self.out / "depth", opts, resume=True, progress=bar)
        return {"mode": opts.mode, "frames": len(summary["frames"]), "seconds_per_frame": summary["seconds_per_frame"],
                "weights": summary.get("weights"), "config": summary.get("config"),
                "precision": summary.get("precision"), "depth_range": summary.get("depth_range"),
                **({"adaptation": summary["adaptation"]} if "adaptation" in summary else {})}

    def stage_fusion(self) -> dict:
        """The keyframes' depth through the depth filter into the TSDF; the filter's figures go to report.json."""
        scan = self.keyframe_scan()
        source = filtered_depth(scan, self.out / "depth", self.config.depth_filter, self.config.fusion)
        with self._bar("fusion", len(scan)) as bar:
            mesh = fuse_scan(scan, source, self.config.fusion, cleanup=self.config.cleanup, progress=bar)
        save_mesh(mesh, self.out / "mesh.ply")
        return {"vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces)),
                "filter": {"checks": list(source.config.checks), "near_weight_m": source.config.near_weight_m,
                           **source.stats.as_dict()}}

    def ground_truth_scan(self) -> Scan:
        """The scan that holds this run's ground truth: its own, or for an SfM run without any, the frames of
        the ground-truth scan (--gt-poses) that the run kept (matched by name)."""
        scan = self.load_scan()
        if scan.has_depth or gt_mesh_path(scan) is not None or not self.poses_from_sfm:
            return scan
        gt_scan = self.gt_poses_scan()
        return frames_named(gt_scan, scan.names) if gt_scan is not None else scan

    def stage_reference(self) -> dict:
        """The GT mesh to score against: --gt-mesh, the ground-truth scan's own (`ground_truth_scan`), or the
        fusion of its GT depth."""
        target = self.out / "reference.ply"
        truth = self.ground_truth_scan()
        given = Path(self.config.evaluation.gt_mesh) if self.config.evaluation.gt_mesh else gt_mesh_path(truth)
        if given is not None:
            save_mesh(load_mesh(given), target)
            return {"source": str(given)}
        if truth.has_depth:
            with self._bar("reference", len(truth)) as bar:
                mesh = fuse_scan(truth, "gt", self.config.fusion, progress=bar)
            save_mesh(mesh, target)
            return {"source": "fusion of the ground-truth depth"}
        target.unlink(missing_ok=True)
        return {"source": None}

    def stage_evaluate(self) -> dict:
        """Depth, mesh and pose metrics; an SfM run with ground-truth poses is scored in the ground truth's frame
        and scale (the Sim(3) of its trajectory onto the GT poses moves the mesh and scales the depth)."""
        scan = self.load_scan()
        metrics: dict = {"metric_scale": scan.metadata.metric_scale}
        gt_scan = self.gt_poses_scan() if self.poses_from_sfm else None
        alignment = None
        if gt_scan is not None:
            p = pose_metrics(scan, gt_scan)
            metrics["poses"] = {"ate_rmse": p["ate_rmse"], "registered": p["registered"],  # of the frames SfM got
                                "frames_used": p["frames_used"], "metric_scale": scan.metadata.metric_scale,
                                "sim3_scale": p["scale"]}
            alignment = p["alignment"]
            gt_scan = frames_named(gt_scan, scan.names)  # what this run saw, for depth and visibility
        metrics.update(self._depth_metrics(scan, gt_scan, alignment))
        metrics.update(self._mesh_metrics(scan, gt_scan, alignment))
        write_json_atomic(self.out / "metrics.json", metrics)
        return {k: v for k, v in metrics.items() if k in ("depth", "mesh", "poses")}

    def _depth_metrics(self, scan: Scan, gt_scan: Scan | None, alignment: dict | None) -> dict:
        """Against the run's own GT depth, or (SfM with GT poses) the GT scan's depth of the same keyframes with
        the prediction scaled by the trajectory's Sim(3) scale."""
        kf, scale, align = self.keyframe_scan(), 1.0, "none" if scan.metadata.metric_scale else "median"
        if alignment is not None and gt_scan is not None:
            gt_kf = frames_named(gt_scan, kf.names)
            if gt_kf.has_depth:
                kf, scale, align = gt_kf, float(alignment["scale"]), "sim3"
        if not kf.has_depth:
            return {}
        d = evaluate_depth_folder(self.out / "depth", kf, max_depth=self.config.evaluation.max_depth,
                                  align="median" if align == "median" else "none", scale=scale)
        d["align"] = align
        return {"depth": {k: d[k] for k in (*DEPTH_KEYS, "edge_precision", "edge_recall", "edge_f", "coverage",
                                           "median_ratio", "frames", "min_depth", "max_depth", "align")},
                "temporal": {k: d[k] for k in ("mae_mean", "mae_std", "flicker")},
                "depth_per_frame": d["per_frame"]}

    def _mesh_metrics(self, scan: Scan, gt_scan: Scan | None, alignment: dict | None) -> dict:
        reference = self.out / "reference.ply"
        if not reference.is_file():
            return {}
        mesh = self.out / "mesh.ply"
        if not scan.metadata.metric_scale and alignment is None:
            return {"mesh_skipped": "the mesh's scale is unknown and no ground-truth poses align it "
                                    "(pass --gt-poses SCAN)"}
        out = {}
        if alignment is not None:  # SfM poses live in their own frame, metric or not
            mesh = aligned_mesh(mesh, alignment)
            out["mesh_alignment"] = "Sim(3) from the camera trajectory to the ground-truth poses"
        out["mesh"] = mesh_metrics(mesh, reference, scan=gt_scan if gt_scan is not None else scan)
        return out

    @property
    def poses_from_sfm(self) -> bool:
        return (self.out / "scan" / "poses_report.json").is_file()

    def stage_report(self) -> dict:
        from apps.report import write_report

        report = self.summary()
        write_json_atomic(self.out / "report.json", report)
        write_report(self, report, self.out / "report.html")
        return {"html": str(self.out / "report.html")}

    def summary(self) -> dict:
        """report.json: the metric sections (absent without their ground truth), timing, memory, config."""
        metrics = json.loads((self.out / "metrics.json").read_text()) if (self.out / "metrics.json").is_file() else {}
        report = {k: metrics[k] for k in ("depth", "temporal", "mesh", "poses") if k in metrics}
        if "filter" in self.records.get("fusion", StageRecord()).info:
            report["filter"] = self.records["fusion"].info["filter"]
        report["metric_scale"] = metrics.get("metric_scale")
        report["timing"] = {k: round(v.seconds, 3) for k, v in self.records.items() if v.done}
        report["memory"] = {"peak_rss_mb": round(max((v.peak_rss_mb for v in self.records.values()), default=0.0), 1),
                            "per_stage_mb": {k: round(v.peak_rss_mb, 1) for k, v in self.records.items()}}
        report["stages"] = {k: v.info for k, v in self.records.items()}
        report["config"] = dataclasses.asdict(self.config)
        return report


def frames_named(scan: Scan, names: list[str]) -> Scan:
    """The frames of `scan` with these names, in the order given (names it lacks are left out)."""
    index = {f.name: i for i, f in enumerate(scan.frames)}
    return scan.subset([index[n] for n in names if n in index])


def aligned_mesh(mesh_path: Path, alignment: dict):
    """The predicted mesh moved into the ground truth's frame by a Sim(3) {scale, rotation, translation}."""
    mesh = load_mesh(mesh_path)
    mesh.vertices = alignment["scale"] * np.asarray(mesh.vertices) @ np.asarray(alignment["rotation"]).T \
        + np.asarray(alignment["translation"])
    return mesh
