"""`recon bench poses`: SfM on 200 frames at 640x480 (7-Scenes kitchen, every 5th frame), time per step.

Ingest, feature extraction and matching run once; the global and the incremental mapper
then each map their own copy of the database (the global mapper's view-graph calibration
rewrites it), so both are timed end to end in the same run, on the same matches, and
scored against the sequence's ground-truth poses (ATE after Sim(3), share registered).
The target is <= 120 s end to end on 2 CPU cores. The CPU load average is printed with
the table: on a shared machine the times are upper bounds.
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

from apps.common import print_json

KITCHEN = "../shared/data/7scenes-redkitchen"


def add_arguments(parser):
    parser.add_argument("--input", default=KITCHEN, help=f"scan, video or image folder (default {KITCHEN})")
    parser.add_argument("--stride", type=int, default=5)
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--mappers", default="global,incremental", help="comma-separated (default both)")
    parser.add_argument("--keep", default=None, metavar="DIR", help="keep the outputs here instead of a temp folder")
    parser.add_argument("--json", action="store_true")


def run(args) -> int:
    from poses.evaluate import pose_metrics
    from poses.ingest import IngestConfig, ingest
    from recon.readers import detect_format, open_scan
    from poses.scale import resolve_scale
    from poses.sfm import SfMConfig, SfMResult, extract_and_match, map_images, scan_from_sfm, sparse_depths
    from recon.errors import ReconError
    from recon.scan import save_scan

    if not Path(args.input).exists():
        print(f"note: {args.input} not found; pass --input (a video, image folder or scan)")
        return 2
    mappers = [m.strip() for m in args.mappers.split(",") if m.strip()]
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench-poses-") as tmp:
        root = Path(args.keep or tmp)
        root.mkdir(parents=True, exist_ok=True)
        shared: dict[str, float] = {}
        t0 = time.perf_counter()
        frames = ingest(args.input, root / "frames", IngestConfig(stride=args.stride, max_frames=args.frames))
        shared["ingest"] = time.perf_counter() - t0
        names = sorted(f.path.name for f in frames.frames)
        config = SfMConfig()
        extract_and_match(frames.image_dir, names, root / "database.db", config, shared)
        gt = None
        try:
            detect_format(args.input)
            gt = open_scan(args.input).select(0, args.stride, args.frames)
        except ReconError:
            pass  # a video or image folder: no ground truth to score against
        results = {}
        for mapper in mappers:
            work = root / mapper
            work.mkdir(exist_ok=True)
            shutil.copy(root / "database.db", work / "database.db")
            steps: dict[str, float] = {}
            models = map_images(work / "database.db", frames.image_dir, work / "sparse", mapper, config, steps)
            row = {"steps_s": {**shared, **steps}, "registered": 0, "frames": len(names)}
            if models:
                index, rec = max(models.items(), key=lambda kv: kv[1].num_reg_images())
                t0 = time.perf_counter()
                result = SfMResult(rec, frames.image_dir, mapper, [], [], steps, work, work / "database.db",
                                   work / "sparse" / str(index))
                scan, _ = resolve_scale(scan_from_sfm(result), sparse_depths(rec))
                save_scan(scan, work / "scan")
                row["steps_s"]["scale_save"] = time.perf_counter() - t0
                row["registered"] = len(scan)
                if gt is not None:
                    m = pose_metrics(scan, gt)
                    row.update(ate_rmse_m=m["ate_rmse"], registered_share=m["registered"],
                               trajectory_m=m["trajectory_length"])
            row["total_s"] = sum(row["steps_s"].values())
            results[mapper] = row
    summary = {"input": args.input, "frames": len(names), "size": list(frames.size),
               "cpu_count": os.cpu_count(), "load_average_before": round(load_before, 2),
               "load_average_after": round(os.getloadavg()[0], 2), "mappers": results}
    if args.json:
        print_json(summary)
        return 0
    from rich.console import Console
    from rich.table import Table

    load = f"load average {load_before:.1f} -> {summary['load_average_after']:.1f}"
    table = Table(title=f"recon bench poses: {len(names)} frames {frames.size[0]}x{frames.size[1]} "
                        f"({os.cpu_count()} cores, {load})")
    table.add_column("step")
    for mapper in results:
        table.add_column(mapper, justify="right")
    order = ["ingest", "extract", "match", "calibrate", "map_global", "map_incremental", "scale_save"]
    steps = [s for s in order if any(s in r["steps_s"] for r in results.values())]
    for step in steps:
        table.add_row(step, *(f"{r['steps_s'][step]:.1f} s" if step in r["steps_s"] else "-" for r in results.values()))
    table.add_row("end to end", *(f"{r['total_s']:.1f} s" for r in results.values()))
    table.add_row("registered", *(f"{r['registered']}/{r['frames']}" for r in results.values()))
    if gt is not None:
        table.add_row("ATE RMSE (Sim3)", *(f"{r['ate_rmse_m'] * 100:.1f} cm" if "ate_rmse_m" in r else "-"
                                           for r in results.values()))
    Console().print(table)
    return 0
