"""The end-to-end run: input -> canonical scan -> depth -> mesh -> evaluation -> report.

Each stage reads and writes files in the run folder, records itself in `run.json`
(options fingerprint, wall time, peak memory) and is skipped on a re-run when its
outputs exist for the same options; `force` redoes a stage and everything after it.
A lock file keeps two runs out of one folder.

    DIR/scan/            canonical scan of the selected frames (poses supplied or from SfM)
    DIR/keyframes.json   frames the depth stage estimates (camera-motion keyframes)
    DIR/depth/           <frame>.npy/.png/.conf.npy + depth.json
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

from .errors import ReconError
from .io import write_json_atomic
from .resources import measure

log = logging.getLogger("recon")

STAGES = ("scan", "depth", "fusion", "reference", "evaluate", "report")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")


@dataclass
class RunConfig:
    """Everything that decides a run's outputs (and so when a stage must be redone)."""

    input: str
    out: str
    format: str = "auto"
    poses: str = "auto"  # auto: the input's own poses when it has them, SfM otherwise; colmap: always SfM
    mapper: str = "incremental"  # SfM mapper when SfM runs (the other one is the fallback)
    gt_poses: str | None = None  # a scan whose poses score SfM's (a recorded input serves by itself)
    start: int = 0
    stride: int = 1
    max_frames: int | None = None
    keyframe_threshold: float = 0.1  # combined translation/rotation motion between keyframes; 0 keeps all
    mode: str = "estm"
    weights: str | None = None  # None: the shipped default for learned modes
    window: str = "offline"
    memory_size: int | None = None
    depth_range: tuple[float, float] | None = None
    fit: str = "stretch"  # frames to the network size: "stretch" or "crop" (aspect kept)
    device: str = "auto"
    voxel_size: float = 0.04
    fusion_depth_max: float = 4.0
    min_confidence: float | None = None
    gt_mesh: str | None = None
    eval_max_depth: float = 10.0
    report_frames: int = 6

    def stage_options(self, stage: str) -> dict:
        """The options a stage's outputs depend on (device choice is not among them; the weights' content is)."""
        keys = {
            "scan": ("input", "format", "poses", "mapper", "start", "stride", "max_frames"),
            "evaluate": ("eval_max_depth", "gt_poses"),
            "depth": ("keyframe_threshold", "mode", "weights", "window", "memory_size", "depth_range", "fit"),
            "fusion": ("voxel_size", "fusion_depth_max", "min_confidence"),
            "reference": ("gt_mesh", "voxel_size", "fusion_depth_max"),
            "report": ("report_frames",),
        }[stage]
        options = {k: getattr(self, k) for k in keys}
        if stage == "depth" and self.mode != "planesweep":
            from depth.checkpoint import DEFAULT_WEIGHTS, weights_digest

            options["weights_digest"] = weights_digest(self.weights or DEFAULT_WEIGHTS)
        return options


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

    def is_current(self, stage: str) -> bool:
        rec = self.records.get(stage)
        return bool(rec and rec.done and rec.fingerprint == _fingerprint(self.config.stage_options(stage)))

    # -- driver ------------------------------------------------------------------------------
    def run(self, force: tuple[str, ...] = (), until: str = "report") -> dict:
        """Run every stage up to `until`, skipping current ones; returns the report dict (or {})."""
        for name in force:
            if name not in STAGES:
                raise ReconError(f"unknown stage {name!r} (stages: {', '.join(STAGES)})")
        last = STAGES.index(until)
        with RunLock(self.out):
            self._load_state()
            first_forced = min((STAGES.index(f) for f in force), default=len(STAGES))
            redo_rest = False
            for i, stage in enumerate(STAGES[: last + 1]):
                redo = redo_rest or i >= first_forced or not self.is_current(stage)
                if not redo:
                    log.info("%s: up to date, skipped", stage)
                    continue
                redo_rest = True  # everything downstream depends on this stage's outputs
                self._run_stage(stage)
        report = self.out / "report.json"
        return json.loads(report.read_text()) if report.is_file() and until == "report" else {}

    def _run_stage(self, stage: str) -> None:
        self.records.pop(stage, None)
        self._save_state()
        log.info("%s: running", stage)
        with measure() as usage:
            info = getattr(self, f"stage_{stage}")() or {}
        self.records[stage] = StageRecord(True, _fingerprint(self.config.stage_options(stage)), usage.seconds,
                                          usage.peak_rss_mb, info)
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
    def load_scan(self):
        from .scan import load_scan

        return load_scan(self.out / "scan")

    def keyframe_names(self) -> list[str]:
        return json.loads((self.out / "keyframes.json").read_text())["keyframes"]

    def keyframe_scan(self):
        scan = self.load_scan()
        names = set(self.keyframe_names())
        return scan.subset([i for i, f in enumerate(scan.frames) if f.name in names])

    def stage_scan(self) -> dict:
        from depth.selection import select_keyframes
        from .scan import save_scan

        cfg = self.config
        src = Path(cfg.input)
        if not src.exists():
            raise ReconError(f"{src}: no such file or folder")
        if self._needs_sfm(src):
            scan = self._sfm_scan(src)
        else:
            from poses.readers import open_scan

            scan = open_scan(src, cfg.format).select(cfg.start, cfg.stride, cfg.max_frames)
            with self._bar("scan", len(scan)) as bar:
                save_scan(scan, self.out / "scan", progress=bar)
        scan = self.load_scan()
        if cfg.keyframe_threshold > 0:
            keys = select_keyframes(scan.camera_to_world, cfg.keyframe_threshold)
        else:
            keys = list(range(len(scan)))
        if len(keys) < 3:
            raise ReconError(f"{src}: only {len(keys)} keyframes after selection; the camera barely moves "
                             "(use more frames, or a lower --keyframe-threshold)")
        write_json_atomic(self.out / "keyframes.json", {"threshold": cfg.keyframe_threshold,
                                                        "keyframes": [scan.frames[i].name for i in keys]})
        return {"frames": len(scan), "keyframes": len(keys), "metric_scale": scan.metadata.metric_scale,
                "source_format": scan.metadata.source_format, "has_depth": scan.has_depth,
                "width": scan.intrinsics.width, "height": scan.intrinsics.height}

    def _needs_sfm(self, src: Path) -> bool:
        if self.config.poses == "colmap":
            return True
        if self.config.poses not in ("auto", "supplied"):
            raise ReconError(f"unknown --poses {self.config.poses!r} (auto, supplied, colmap)")
        if src.is_file() and src.suffix.lower() in VIDEO_SUFFIXES:
            if self.config.poses == "supplied":
                raise ReconError(f"{src}: a plain video has no poses to supply (use --poses colmap)")
            return True
        from poses.readers import detect_format

        try:
            detect_format(src)
            return False
        except ReconError:
            if self.config.poses == "supplied" or not src.is_dir():
                raise
            return True  # a plain image folder

    def _sfm_scan(self, src: Path):
        from poses.ingest import IngestConfig
        from poses.sfm import PosesConfig, SfMConfig, estimate_poses

        cfg = self.config
        if cfg.start:
            raise ReconError("--start is not supported when poses come from SfM (trim the video instead)")
        config = PosesConfig(ingest=IngestConfig(stride=cfg.stride, max_frames=cfg.max_frames),
                             sfm=SfMConfig(mapper=cfg.mapper))
        scan, _ = estimate_poses(src, self.out / "scan", config)
        return scan

    def gt_poses_scan(self):
        """Ground-truth poses for an SfM run: --gt-poses, or the recorded scan SfM ignored the poses of."""
        from poses.readers import detect_format, open_scan

        if self.config.gt_poses:
            return open_scan(self.config.gt_poses)
        src = Path(self.config.input)
        if self.config.poses == "colmap" and src.is_dir():
            try:
                detect_format(src)
            except ReconError:
                return None
            return open_scan(src)
        return None

    def stage_depth(self) -> dict:
        from depth.inference import DepthOptions, estimate_depth

        from depth.checkpoint import DEFAULT_WEIGHTS, INDOOR_DEPTH_RANGE, trained_depth_range

        cfg = self.config
        scan = self.keyframe_scan()
        weights = cfg.weights or (None if cfg.mode == "planesweep" else DEFAULT_WEIGHTS)
        depth_range = cfg.depth_range
        learned_range = trained_depth_range(weights) if cfg.mode != "planesweep" else None
        if depth_range is None and learned_range is None and scan.metadata.depth_range is None:
            if not scan.metadata.metric_scale:
                raise ReconError(f"{cfg.input}: the scan's scale is unknown and it states no depth range: "
                                 "pass --depth-range MIN MAX in its units")
            # A recorded RGB-D scan rarely says; its GT depth must not decide it (that would leak ground truth).
            depth_range = INDOOR_DEPTH_RANGE
            log.info("depth: no depth range given, sweeping %.2f-%.2f m", *depth_range)
        opts = DepthOptions(mode=cfg.mode, window=cfg.window, memory_size=cfg.memory_size,
                            depth_range=depth_range, fit=cfg.fit, device=cfg.device)
        with self._bar("depth", len(scan)) as bar:
            summary = estimate_depth(scan, self.out / "depth", opts, weights=weights, resume=True, progress=bar)
        return {"mode": cfg.mode, "frames": len(summary["frames"]), "seconds_per_frame": summary["seconds_per_frame"],
                "weights": summary.get("weights"), "config": summary.get("config"),
                "depth_range": summary.get("depth_range")}

    def stage_fusion(self) -> dict:
        from fusion.mesh import save_mesh
        from fusion.tsdf import fuse_scan

        scan = self.keyframe_scan()
        with self._bar("fusion", len(scan)) as bar:
            mesh = fuse_scan(scan, self.out / "depth", self._tsdf_config(), progress=bar)
        save_mesh(mesh, self.out / "mesh.ply")
        return {"vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces))}

    def _tsdf_config(self):
        from fusion.tsdf import TSDFConfig

        cfg = self.config
        return TSDFConfig(voxel_size=cfg.voxel_size, depth_max=cfg.fusion_depth_max,
                          min_confidence=cfg.min_confidence, device="auto" if cfg.device == "auto" else cfg.device)

    def stage_reference(self) -> dict:
        """The GT mesh to score against: --gt-mesh, the scan's own, or the fusion of its GT depth."""
        from fusion.mesh import load_mesh, save_mesh
        from fusion.tsdf import fuse_scan

        from .scan import gt_mesh_path

        target = self.out / "reference.ply"
        scan = self.load_scan()
        given = Path(self.config.gt_mesh) if self.config.gt_mesh else gt_mesh_path(scan)
        if given is not None:
            save_mesh(load_mesh(given), target)
            return {"source": str(given)}
        if scan.has_depth:
            with self._bar("reference", len(scan)) as bar:
                mesh = fuse_scan(scan, "gt", self._tsdf_config(), progress=bar)
            save_mesh(mesh, target)
            return {"source": "fusion of the ground-truth depth"}
        target.unlink(missing_ok=True)
        return {"source": None}

    def stage_evaluate(self) -> dict:
        from depth.metrics import evaluate_depth_folder
        from fusion.evaluate import mesh_metrics

        scan = self.load_scan()
        kf = self.keyframe_scan()
        metrics: dict = {"metric_scale": scan.metadata.metric_scale}
        if kf.has_depth:
            d = evaluate_depth_folder(self.out / "depth", kf, max_depth=self.config.eval_max_depth,
                                      align="none" if scan.metadata.metric_scale else "median")
            metrics["depth"] = {k: d[k] for k in ("abs_rel", "abs", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3",
                                                  "coverage", "frames", "min_depth", "max_depth", "align")}
            metrics["temporal"] = {k: d[k] for k in ("mae_mean", "mae_std", "flicker")}
            metrics["depth_per_frame"] = d["per_frame"]
        gt_scan = self.gt_poses_scan() if self.poses_from_sfm else None
        alignment = None
        if gt_scan is not None:
            from poses.evaluate import pose_metrics

            p = pose_metrics(scan, gt_scan)
            metrics["poses"] = {"ate_rmse": p["ate_rmse"], "registered": p["registered"],
                                "metric_scale": scan.metadata.metric_scale, "sim3_scale": p["scale"]}
            alignment = p["alignment"]
        reference = self.out / "reference.ply"
        if reference.is_file():
            mesh = self.out / "mesh.ply"
            if not scan.metadata.metric_scale and alignment is None:
                metrics["mesh_skipped"] = ("the mesh's scale is unknown and no ground-truth poses align it "
                                           "(pass --gt-poses SCAN)")
            else:
                if not scan.metadata.metric_scale:
                    mesh = aligned_mesh(mesh, alignment)
                    metrics["mesh_alignment"] = "Sim(3) from the camera trajectory to the ground-truth poses"
                metrics["mesh"] = mesh_metrics(mesh, reference, scan=gt_scan if gt_scan is not None else scan)
        write_json_atomic(self.out / "metrics.json", metrics)
        return {k: v for k, v in metrics.items() if k in ("depth", "mesh", "poses")}

    @property
    def poses_from_sfm(self) -> bool:
        return (self.out / "scan" / "poses_report.json").is_file()

    def stage_report(self) -> dict:
        from .report import write_report

        report = self.summary()
        write_json_atomic(self.out / "report.json", report)
        write_report(self, report, self.out / "report.html")
        return {"html": str(self.out / "report.html")}

    def summary(self) -> dict:
        """report.json: the metric sections (absent without their ground truth), timing, memory, config."""
        metrics = json.loads((self.out / "metrics.json").read_text()) if (self.out / "metrics.json").is_file() else {}
        report = {k: metrics[k] for k in ("depth", "temporal", "mesh", "poses") if k in metrics}
        report["metric_scale"] = metrics.get("metric_scale")
        report["timing"] = {k: round(v.seconds, 3) for k, v in self.records.items() if v.done}
        report["memory"] = {"peak_rss_mb": max((v.peak_rss_mb for v in self.records.values()), default=0.0),
                            "per_stage_mb": {k: round(v.peak_rss_mb, 1) for k, v in self.records.items()}}
        report["stages"] = {k: v.info for k, v in self.records.items()}
        report["config"] = dataclasses.asdict(self.config)
        return report


def aligned_mesh(mesh_path: Path, alignment: dict):
    """The predicted mesh moved into the ground truth's frame by a Sim(3) {scale, rotation, translation}."""
    import numpy as np

    from fusion.mesh import load_mesh

    mesh = load_mesh(mesh_path)
    mesh.vertices = alignment["scale"] * np.asarray(mesh.vertices) @ np.asarray(alignment["rotation"]).T \
        + np.asarray(alignment["translation"])
    return mesh
