"""`recon run INPUT --out DIR`: the whole pipeline, resumable, with a summary table and an HTML report."""
from __future__ import annotations

import dataclasses

from apps import options
from apps.progress import progress_bar


def add_pipeline_args(p, with_input: bool = True) -> None:
    if with_input:
        p.add_argument("input", help="a video file, an image folder, or a recorded scan in any supported format")
        p.add_argument("--out", required=True, help="run folder (stage outputs are cached here)")
        options.add_format(p)
    options.add_selection(p)
    options.add_pose_source(p)
    options.add_sfm(p)
    options.add_keyframes(p)
    options.add_depth(p)
    options.add_depth_storage(p)
    options.add_fusion(p)
    options.add_device(p)
    options.add_evaluation(p)
    p.add_argument("--force", nargs="+", default=[], metavar="STAGE",
                   help="redo these stages (and the ones after): scan depth fusion reference evaluate report")


def register(subparsers):
    subparsers.add_parser("run", help="video / images / scan -> poses -> depth -> mesh -> report",
                          description="The whole pipeline. Stage outputs are cached in the run folder; a re-run "
                                      "skips finished stages and frames. Writes mesh.ply, report.json and "
                                      "report.html; `recon export` turns a finished run into other formats.",
                          arguments=add_arguments)


def add_arguments(p) -> None:
    add_pipeline_args(p)
    p.set_defaults(func=run)


def config_from_args(args, input_path: str, out: str, **input_changes):
    """The run config of a command line: each stage's config from the shared options."""
    from apps.pipeline import EvalConfig, InputConfig, RunConfig

    source = InputConfig(path=input_path, format=getattr(args, "format", "auto"), poses=args.poses, start=args.start,
                         stride=args.stride, max_frames=args.max_frames, gt_poses=args.gt_poses)
    return RunConfig(input=dataclasses.replace(source, **input_changes), out=out, sfm=options.poses_config(args),
                     keyframes=options.keyframe_config(args),
                     depth=options.depth_options(args, options.pick_mode(args.mode, args.weights)),
                     fusion=options.tsdf_config(args), depth_filter=options.filter_config(args),
                     cleanup=options.cleanup_config(args), evaluation=EvalConfig(gt_mesh=args.gt_mesh)).validate()


def execute(config, force, quiet: bool) -> dict:
    """Run the pipeline with progress bars and print the summary; returns report.json's content."""
    from apps.pipeline import Pipeline

    pipeline = Pipeline(config, progress=lambda label, total: progress_bar(label, total, quiet=quiet))
    report = pipeline.run(force=tuple(force))
    print_summary(report, pipeline.out)
    return report


# One summary line per metrics section of report.json, when the run has it.
METRIC_LINES = {
    "depth": "abs_rel {abs_rel:.4f}  rmse {rmse:.3f}  a1 {a1:.3f}  ({frames} frames, align {align})",
    "temporal": "mae {mae_mean:.3f} +- {mae_std:.3f}  flicker {flicker:.4f}",
    "mesh": "F-score {fscore:.3f}  acc {acc:.3f}  comp {comp:.3f}  prec {prec:.3f}  recall {recall:.3f}",
    "poses": "ATE {ate_rmse:.4f}  registered {registered:.1%}",
}


def print_summary(report: dict, out) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title="recon run summary")
    table.add_column("section")
    table.add_column("figures")
    stages = report.get("stages", {})
    if "scan" in stages:
        table.add_row("frames", f"{stages['scan'].get('frames')} ({stages['scan'].get('keyframes')} keyframes)")
    if "faces" in stages.get("fusion", {}):
        table.add_row("mesh", f"{stages['fusion']['faces']:,} triangles, {stages['fusion']['vertices']:,} vertices")
    for stage, seconds in report.get("timing", {}).items():
        table.add_row(f"time: {stage}", f"{seconds:.1f} s")
    table.add_row("peak memory", f"{report['memory']['peak_rss_mb']:.0f} MB")
    for section, line in METRIC_LINES.items():
        if section in report:
            table.add_row(section, line.format(**report[section]))
    table.add_row("scale", "metric" if report.get("metric_scale") else "unknown (arbitrary units)")
    console.print(table)
    print(f"report: {out / 'report.html'}")


def run(args):
    execute(config_from_args(args, args.input, args.out), args.force, args.quiet)
    return 0
