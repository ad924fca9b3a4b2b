"""`recon bench poses`: is SfM repeatable and complete on the inputs people bring?

Four sections (`--sections`), each printed as a table with the issue's target beside the figure:

  rooms         rendered room videos (40 frames, one seed each), each posed `--runs` times: are the
                runs identical (poses to 1e-6), is >= 95 % registered, is ATE <= 2 % of the path?
  photos        folders of 50 wide-baseline photos of rendered rooms (25 degrees apart round the
                room, shuffled names; `--photo-rooms` seeds), each as plain JPEGs, as a phone writes
                them (EXIF 35 mm-equivalent focal length), and with every third photo in portrait:
                share registered, ATE, focal length error.
  kitchen       7-Scenes kitchen, every 5th frame, 200 frames (640x480), posed `--runs` times:
                registered, ATE, time end to end (target <= 60 s on 2 cores), identical runs.
  kitchen-video the same 200 frames as an mp4, through the whole pipeline as a plain video, with the
                kitchen's poses given only to score it: depth and mesh after the Sim(3) alignment.
  loops         loop detection on and off: rendered walks (`--walk-frames` at 10 fps, `--walks` seeds,
                matched sequentially) and the kitchen's 200 frames: loop pairs, first attempt, ATE.

Times are wall clock with the process CPU time beside them: on a shared machine the wall time is an
upper bound (the load average is printed), CPU time shows what the work itself cost.
"""
from __future__ import annotations

import dataclasses
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from apps.common import print_json

KITCHEN = "../shared/data/7scenes-redkitchen"
SECTIONS = ("rooms", "photos", "kitchen", "kitchen-video", "loops")


def add_arguments(parser):
    parser.add_argument("--sections", default=",".join(SECTIONS), help=f"comma-separated of {', '.join(SECTIONS)}")
    parser.add_argument("--rooms", type=int, default=10, help="rendered room videos (seeds 0..N-1; default 10)")
    parser.add_argument("--room-frames", type=int, default=40)
    parser.add_argument("--room-fps", type=float, default=10.0,
                        help="frame rate of the rendered walk: 40 frames at 10 fps are a 4 s, 1-2 m walk (default 10)")
    parser.add_argument("--photo-rooms", type=int, default=3, help="photo collections (seeds 0..N-1; default 3)")
    parser.add_argument("--walks", type=int, default=3, help="loops: rendered walks (seeds 0..N-1; default 3)")
    parser.add_argument("--walk-frames", type=int, default=150, help="loops: frames per walk, at 10 fps (default 150)")
    parser.add_argument("--runs", type=int, default=3, help="SfM runs per input for the repeatability check")
    parser.add_argument("--kitchen", default=KITCHEN, help=f"7-Scenes sequence (default {KITCHEN})")
    parser.add_argument("--keep", default=None, metavar="DIR", help="keep the outputs here instead of a temp folder")
    parser.add_argument("--json", action="store_true")


def _timed(fn, *args, **kwargs):
    """(result, wall seconds, process CPU seconds) of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = fn(*args, **kwargs)
    return result, time.perf_counter() - wall, time.process_time() - cpu


def _pose_runs(source, gt, root: Path, runs: int, config) -> dict:
    """Pose `source` `runs` times: registered share, ATE, identical or not, time per run."""
    from poses.evaluate import pose_metrics
    from poses.sfm import estimate_poses
    from recon.errors import ReconError

    poses, rows = [], []
    for k in range(runs):
        try:
            (scan, report), wall, cpu = _timed(estimate_poses, source, root / f"run{k}", config)
        except ReconError as exc:
            rows.append({"error": str(exc)})
            poses.append(None)
            continue
        m = pose_metrics(scan, gt)
        poses.append({f.name: f.camera_to_world for f in scan.frames})
        rows.append({"registered": m["registered"], "frames": m["frames_used"], "ate_m": m["ate_rmse"],
                     "path_m": m["trajectory_length"], "wall_s": wall, "cpu_s": cpu,
                     "attempts": report["sfm"]["attempts"], "loops": report["sfm"]["loops"], "camera": report["sfm"]["camera"],
                     "distortion_test": report["sfm"]["distortion_test"], "steps_s": report["timings_s"]})
    return {"runs": rows, "max_pose_difference": _max_difference(poses)}


def _max_difference(poses: list[dict | None]) -> float | None:
    """Largest pose-matrix entry difference between the first run and any other (inf: different frames)."""
    if any(p is None for p in poses):
        return None
    worst = 0.0
    for other in poses[1:]:
        if set(other) != set(poses[0]):
            return float("inf")
        worst = max([worst] + [float(np.abs(other[n] - poses[0][n]).max()) for n in other])
    return worst


def bench_rooms(args, root: Path) -> dict:
    from poses.sfm import PosesConfig
    from recon.readers import open_scan
    from recon.synthetic.generate import SynthConfig, write_synthetic_scan

    rooms = {}
    for seed in range(args.rooms):
        folder = root / f"room{seed}"
        config = SynthConfig(seed=seed, frames=args.room_frames, fps=args.room_fps)
        write_synthetic_scan(config, folder / "scan", video=True)
        rooms[seed] = _pose_runs(folder / "scan" / "video.mp4", open_scan(folder / "scan"), folder, args.runs,
                                 PosesConfig())
    return rooms


def bench_photos(args, root: Path) -> dict:
    from poses.ingest import IngestConfig
    from poses.sfm import PosesConfig
    from recon.readers import open_scan
    from recon.synthetic.collection import GROUND_TRUTH, PHOTOS, write_photo_collection
    from recon.synthetic.generate import SynthConfig

    out = {}
    variants = {"": {}, " exif": {"exif": True}, " portraits": {"portrait_every": 3}}
    for seed in range(args.photo_rooms):
        for tag, variant in variants.items():
            key = f"{seed}{tag}"
            folder = write_photo_collection(SynthConfig(seed=seed, frames=50, width=640, height=480),
                                            root / f"photos{seed}{tag.strip() and '_' + tag.strip()}", step_deg=25.0,
                                            **variant)
            gt = open_scan(folder / GROUND_TRUTH)
            # Photos are not a video: no neighbours to call a frame blurry against.
            out[key] = _pose_runs(folder / PHOTOS, gt, folder / "sfm", 1, PosesConfig(ingest=IngestConfig(blur_ratio=0.0)))
            out[key]["true_focal_px"], out[key]["true_width"] = gt.intrinsics.fx, gt.intrinsics.width
    return out


def bench_kitchen(args, root: Path) -> dict:
    from poses.ingest import IngestConfig
    from poses.sfm import PosesConfig
    from recon.readers import open_scan

    gt = open_scan(args.kitchen).select(0, 5, 200)
    return _pose_runs(args.kitchen, gt, root / "kitchen", args.runs,
                      PosesConfig(ingest=IngestConfig(stride=5, max_frames=200)))


def bench_loops(args, root: Path) -> dict:
    """Each input posed once with loop detection and once without."""
    from poses.ingest import IngestConfig
    from poses.sfm import PosesConfig, SfMConfig
    from recon.readers import open_scan
    from recon.synthetic.generate import SynthConfig, write_synthetic_scan

    inputs = {}
    for seed in range(args.walks):
        folder = root / f"walk{seed}"
        write_synthetic_scan(SynthConfig(seed=seed, frames=args.walk_frames, fps=10.0), folder / "scan", video=True)
        inputs[f"walk {seed}"] = (folder / "scan" / "video.mp4", open_scan(folder / "scan"), IngestConfig(), folder)
    if Path(args.kitchen).is_dir():
        inputs["kitchen"] = (args.kitchen, open_scan(args.kitchen).select(0, 5, 200),
                             IngestConfig(stride=5, max_frames=200), root / "kitchen-loops")
    out = {}
    for name, (source, gt, ingest, folder) in inputs.items():
        out[name] = {f"loops {flag}": _pose_runs(source, gt, folder / f"loops-{flag}", 1, PosesConfig(
            ingest=ingest, sfm=SfMConfig(loop_detection=flag == "on")))["runs"][0] for flag in ("on", "off")}
    return out


def bench_kitchen_video(args, root: Path) -> dict:
    """The kitchen's 200 frames as a plain mp4 through `Pipeline`, its poses (renamed to the video's frame
    names) given as --gt-poses only to score poses, depth and mesh."""
    from apps.pipeline import InputConfig, Pipeline, RunConfig
    from recon.readers import open_scan
    from recon.scan import save_scan

    gt = open_scan(args.kitchen).select(0, 5, 200)
    renamed = [dataclasses.replace(f, name=f"frame_{i:06d}") for i, f in enumerate(gt.frames)]
    gt = dataclasses.replace(gt, frames=renamed)
    save_scan(gt, root / "kitchen_gt")
    video = root / "kitchen.mp4"
    _write_video(gt, video, fps=30.0 / 5)
    config = RunConfig(input=InputConfig(path=str(video), gt_poses=str(root / "kitchen_gt")),
                       out=str(root / "kitchen_run")).validate()
    report, wall, cpu = _timed(Pipeline(config).run)
    keep = ("poses", "depth", "mesh", "timing", "metric_scale")
    return {**{k: report[k] for k in keep if k in report}, "wall_s": wall, "cpu_s": cpu}


def _write_video(scan, path: Path, fps: float) -> None:
    import cv2

    intr = scan.intrinsics
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (intr.width, intr.height))
    try:
        for i in range(len(scan)):
            writer.write(cv2.cvtColor(scan.image(i), cv2.COLOR_RGB2BGR))
    finally:
        writer.release()


def run(args) -> int:
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        print(f"note: unknown sections {', '.join(sorted(unknown))} (use {', '.join(SECTIONS)})")
        return 2
    if {"kitchen", "kitchen-video"} & set(sections) and not Path(args.kitchen).is_dir():
        print(f"note: {args.kitchen} not found: the kitchen sections are skipped (pass --kitchen)")
        sections = [s for s in sections if not s.startswith("kitchen")]
    summary = {"cpu_count": os.cpu_count(), "load_average_before": round(os.getloadavg()[0], 2)}
    runners = {"rooms": bench_rooms, "photos": bench_photos, "kitchen": bench_kitchen,
               "kitchen-video": bench_kitchen_video, "loops": bench_loops}
    with tempfile.TemporaryDirectory(prefix="bench-poses-") as tmp:
        root = Path(args.keep or tmp)
        root.mkdir(parents=True, exist_ok=True)
        for name in sections:
            summary[name] = runners[name](args, root)
    summary["load_average_after"] = round(os.getloadavg()[0], 2)
    if args.json:
        print_json(summary)
    else:
        print_tables(summary)
    return 0


def _share(row: dict) -> str:
    return "failed" if "error" in row else f"{row['registered']:.0%} of {row['frames']}"


def print_tables(summary: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    load = (f"{summary['cpu_count']} cores, load average {summary['load_average_before']} -> "
            f"{summary['load_average_after']}")
    if "rooms" in summary:
        table = Table(title=f"rendered room videos, each posed {len(next(iter(summary['rooms'].values()))['runs'])} "
                            f"times ({load})")
        for col in ("seed", "registered (run 1)", "ATE / path", "max pose difference", "wall / CPU s per run"):
            table.add_column(col, justify="right")
        for seed, room in summary["rooms"].items():
            first = room["runs"][0]
            ate = "-" if "error" in first else f"{first['ate_m'] / first['path_m']:.2%} of {first['path_m']:.2f} m"
            diff = room["max_pose_difference"]
            times = " ".join(f"{r['wall_s']:.0f}/{r['cpu_s']:.0f}" for r in room["runs"] if "error" not in r)
            table.add_row(str(seed), _share(first), ate, "-" if diff is None else f"{diff:.1e}", times)
        console.print(table)
        console.print(_room_verdict(summary["rooms"]))
    if "photos" in summary:
        table = Table(title="photo collections: 50 photos 25 degrees apart, shuffled names (target >= 95 % registered)")
        for col in ("seed", "registered", "ATE", "focal error", "first attempt", "wall / CPU s"):
            table.add_column(col, justify="right")
        for seed, photos in summary["photos"].items():
            row = photos["runs"][0]
            if "error" in row:
                table.add_row(str(seed), "failed", row["error"][:50], "", "", "")
                continue
            first = row["attempts"][0]
            focal_error = (row["camera"]["params"][0] * photos["true_width"] / row["camera"]["width"]
                           / photos["true_focal_px"] - 1.0)
            table.add_row(str(seed), _share(row), f"{row['ate_m'] * 100:.1f} cm", f"{focal_error:+.2%}",
                          f"{first['attempt']} {first['registered']}", f"{row['wall_s']:.0f}/{row['cpu_s']:.0f}")
        console.print(table)
    if "kitchen" in summary:
        _print_kitchen(console, summary["kitchen"], load)
    if "kitchen-video" in summary:
        _print_video(console, summary["kitchen-video"])
    if "loops" in summary:
        _print_loops(console, summary["loops"], load)


def _room_verdict(rooms: dict) -> str:
    firsts = [r["runs"][0] for r in rooms.values()]
    complete = sum(1 for r in firsts if "error" not in r and r["registered"] >= 0.95)
    ok_ate = sum(1 for r in firsts if "error" not in r and r["ate_m"] <= 0.02 * r["path_m"])
    same = sum(1 for r in rooms.values() if r["max_pose_difference"] is not None and r["max_pose_difference"] <= 1e-6)
    n = len(rooms)
    return (f"identical runs: {same}/{n} (target {n}/{n}); >= 95 % registered: {complete}/{n} (target >= "
            f"{math.ceil(0.9 * n)}/{n}); ATE <= 2 % of the path: {ok_ate}/{n}")


def _print_kitchen(console, kitchen: dict, load: str) -> None:
    from rich.table import Table

    table = Table(title=f"7-Scenes kitchen, 200 frames every 5th, 640x480 ({load})")
    for col in ("run", "registered", "ATE", "wall s (target <= 60)", "CPU s", "steps (s)"):
        table.add_column(col, justify="right")
    for k, row in enumerate(kitchen["runs"]):
        if "error" in row:
            table.add_row(str(k + 1), "failed", row["error"][:60], "", "", "")
            continue
        steps = ", ".join(f"{s} {v:.0f}" for s, v in row["steps_s"].items() if s != "sfm_total")
        table.add_row(str(k + 1), _share(row), f"{row['ate_m'] * 100:.2f} cm", f"{row['wall_s']:.1f}",
                      f"{row['cpu_s']:.1f}", steps)
    console.print(table)
    diff = kitchen["max_pose_difference"]
    console.print(f"max pose difference between runs: {'-' if diff is None else f'{diff:.1e}'} (target <= 1e-6)")


def _print_video(console, video: dict) -> None:
    nan = float("nan")
    poses, depth, mesh = video.get("poses", {}), video.get("depth", {}), video.get("mesh", {})
    console.print(f"kitchen as a plain video ({video['wall_s']:.0f} s end to end): poses ATE "
                  f"{poses.get('ate_rmse', nan) * 100:.1f} cm, registered {poses.get('registered', nan):.0%}; "
                  f"depth Abs Rel {depth.get('abs_rel', nan):.3f}, delta<1.25 {depth.get('a1', nan):.3f}; mesh "
                  f"F-score {mesh.get('fscore', nan):.3f} (acc {mesh.get('acc', nan):.3f} m, comp "
                  f"{mesh.get('comp', nan):.3f} m)")


def _print_loops(console, loops: dict, load: str) -> None:
    from rich.table import Table

    table = Table(title=f"loop detection on / off ({load})")
    for col in ("input", "loop pairs (candidates / verified)", "first attempt (on / off)", "registered (on / off)",
                "ATE / path (on / off)", "matching s (on / off)"):
        table.add_column(col, justify="right")
    for name, runs in loops.items():
        on, off = runs["loops on"], runs["loops off"]
        if "error" in on or "error" in off:
            table.add_row(name, "failed", (on.get("error") or off.get("error"))[:60], "", "", "")
            continue
        pair = " / ".join
        table.add_row(name, f"{on['loops'].get('candidates', 0)} / {on['loops'].get('verified', 0)}",
                      pair(str(r["attempts"][0]["registered"]) for r in (on, off)), pair(_share(r) for r in (on, off)),
                      pair(f"{r['ate_m'] / r['path_m']:.2%}" for r in (on, off)),
                      pair(f"{r['steps_s'].get('match', 0):.1f}" for r in (on, off)))
    console.print(table)
