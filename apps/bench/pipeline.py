"""`recon bench pipeline`: end-to-end wall time and peak memory per stage, on the demo room and on
100 frames of the 7-Scenes kitchen with supplied poses. Each case runs fresh in a temporary folder."""
from __future__ import annotations

import tempfile
from pathlib import Path

from apps.common import print_json

KITCHEN = "../shared/data/7scenes-redkitchen"


def add_arguments(parser):
    parser.add_argument("--mode", default=None, help="depth mode (default: estm with shipped weights, else planesweep)")
    parser.add_argument("--weights", default=None)
    parser.add_argument("--kitchen", default=KITCHEN, help=f"7-Scenes folder (default {KITCHEN}; skipped if absent)")
    parser.add_argument("--kitchen-frames", type=int, default=100)
    parser.add_argument("--json", action="store_true")


def run(args) -> int:
    from apps.commands.demo import ensure_example
    from apps.options import pick_mode
    from apps.pipeline import EvalConfig, InputConfig, Pipeline, RunConfig
    from depth.options import DepthOptions

    mode = pick_mode(args.mode, args.weights)
    depth = DepthOptions(mode=mode, weights=args.weights)
    cases = [("demo", RunConfig(InputConfig(str(ensure_example())), "", depth=depth,
                                evaluation=EvalConfig(gt_mesh=str(ensure_example() / "gt_mesh.ply"))))]
    if Path(args.kitchen).is_dir():
        cases.append((f"7scenes x{args.kitchen_frames}",
                      RunConfig(InputConfig(args.kitchen, max_frames=args.kitchen_frames), "", depth=depth)))
    else:
        print(f"note: {args.kitchen} not found, the kitchen case is skipped")
    results = {}
    for name, config in cases:
        with tempfile.TemporaryDirectory(prefix="bench-pipeline-") as tmp:
            config.out = tmp
            report = Pipeline(config).run()
        results[name] = {"mode": mode, "timing": report["timing"], "total_s": sum(report["timing"].values()),
                         "peak_rss_mb": report["memory"]["peak_rss_mb"],
                         "per_stage_mb": report["memory"]["per_stage_mb"],
                         "fscore": report.get("mesh", {}).get("fscore"),
                         "abs_rel": report.get("depth", {}).get("abs_rel"),
                         "frames": report["stages"]["scan"]["frames"],
                         "keyframes": report["stages"]["scan"]["keyframes"]}
    if args.json:
        print_json(results)
        return 0
    from rich.console import Console
    from rich.table import Table

    stages = list(next(iter(results.values()))["timing"])
    table = Table(title=f"pipeline wall time (s) and peak memory (MB) per stage, depth mode {mode}")
    table.add_column("stage")
    for name in results:
        table.add_column(name)
    for stage in stages:
        table.add_row(stage, *(f"{r['timing'].get(stage, 0):.1f} s / {r['per_stage_mb'].get(stage, 0):.0f} MB"
                               for r in results.values()))
    table.add_row("total", *(f"{r['total_s']:.1f} s / {r['peak_rss_mb']:.0f} MB" for r in results.values()))
    table.add_row("frames (keyframes)", *(f"{r['frames']} ({r['keyframes']})" for r in results.values()))
    table.add_row("mesh F-score", *(f"{r['fscore']:.3f}" if r["fscore"] is not None else "-" for r in results.values()))
    table.add_row("depth abs_rel", *(f"{r['abs_rel']:.4f}" if r["abs_rel"] is not None else "-"
                                     for r in results.values()))
    Console().print(table)
    return 0
