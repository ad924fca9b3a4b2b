"""`recon run INPUT --out DIR`: the whole pipeline, resumable, with a summary table and an HTML report."""
from __future__ import annotations

from apps.common import add_selection_args
from apps.progress import progress_bar


def add_pipeline_args(p, with_input: bool = True) -> None:
    if with_input:
        p.add_argument("input", help="a video file, an image folder, or a recorded scan in any supported format")
        p.add_argument("--out", required=True, help="run folder (stage outputs are cached here)")
        p.add_argument("--format", default="auto", help="input scan format (default auto)")
        add_selection_args(p)
    g = p.add_argument_group("poses")
    g.add_argument("--poses", choices=["auto", "supplied", "colmap"], default="auto",
                   help="auto: the input's own poses when it has them, else SfM; colmap: always SfM")
    g.add_argument("--mapper", choices=["incremental", "global"], default="incremental",
                   help="SfM mapper (the other one is the fallback)")
    g.add_argument("--gt-poses", default=None, help="scan whose poses score SfM's (frames matched by name)")
    g = p.add_argument_group("depth")
    g.add_argument("--mode", choices=["estm", "joint", "independent", "planesweep"], default=None,
                   help="default: estm with the shipped (or --weights) network; planesweep when there are none")
    g.add_argument("--weights", default=None, help="network weights: a shipped name or a checkpoint path "
                                                   "(default: the shipped compact weights)")
    g.add_argument("--window", choices=["offline", "online"], default="offline",
                   help="ESTM sources before and after each frame (offline) or before only (online)")
    g.add_argument("--memory", type=int, default=None, help="ESTM memory length (default: the network's, 2)")
    g.add_argument("--depth-range", type=float, nargs=2, metavar=("MIN", "MAX"), default=None,
                   help="depth planes' range (default: from the scan's metadata)")
    g.add_argument("--fit", choices=["stretch", "crop"], default="stretch",
                   help="fit frames to the network size: stretch the whole frame (default) or crop (scale to cover, keep the "
                        "aspect ratio; the cropped-off borders get no depth)")
    g.add_argument("--keyframe-threshold", type=float, default=0.1,
                   help="camera motion between keyframes (translation + rotation measure); 0 = every frame")
    g.add_argument("--device", default="auto", help="auto, cpu or cuda (network and fusion)")
    g = p.add_argument_group("fusion and evaluation")
    g.add_argument("--voxel-size", type=float, default=0.04, help="TSDF voxel size (default 0.04 m)")
    g.add_argument("--depth-max", type=float, default=4.0, help="fuse depth up to this distance (default 4 m)")
    g.add_argument("--min-confidence", type=float, default=None, help="drop depth below this confidence")
    g.add_argument("--gt-mesh", default=None, help="ground-truth mesh to score against")
    g.add_argument("--force", nargs="+", default=[], metavar="STAGE",
                   help="redo these stages (and the ones after): scan depth fusion reference evaluate report")


def register(subparsers):
    p = subparsers.add_parser("run", help="video / images / scan -> poses -> depth -> mesh -> report",
                              description="The whole pipeline. Stage outputs are cached in the run folder; a re-run "
                                          "skips finished stages and frames. Writes mesh.ply, report.json and "
                                          "report.html.")
    add_pipeline_args(p)
    p.set_defaults(func=run)


def pick_mode(requested: str | None, weights: str | None) -> str:
    """ESTM with the given or shipped weights; the classical plane sweep, said out loud, when none ship."""
    if requested:
        return requested
    if weights is not None:
        return "estm"  # the depth stage names a missing or unreadable file
    from depth.checkpoint import DEFAULT_WEIGHTS, resolve_weights
    from recon.errors import ReconError

    try:
        resolve_weights(DEFAULT_WEIGHTS)
        return "estm"
    except ReconError:
        print(f"note: the shipped depth weights ({DEFAULT_WEIGHTS}) are missing, so depth comes from the classical "
              "plane sweep (pass --weights PATH to use a checkpoint from `recon train`)")
        return "planesweep"


def config_from_args(args, input_path: str, out: str):
    from recon.pipeline import RunConfig

    return RunConfig(
        input=input_path, out=out, format=getattr(args, "format", "auto"), poses=args.poses, mapper=args.mapper,
        start=getattr(args, "start", 0), stride=getattr(args, "stride", 1), max_frames=getattr(args, "max_frames", None),
        keyframe_threshold=args.keyframe_threshold, mode=pick_mode(args.mode, args.weights), weights=args.weights,
        window=args.window,
        memory_size=args.memory, depth_range=tuple(args.depth_range) if args.depth_range else None,
        fit=args.fit, device=args.device, voxel_size=args.voxel_size, fusion_depth_max=args.depth_max,
        min_confidence=args.min_confidence, gt_mesh=args.gt_mesh, gt_poses=args.gt_poses)


def execute(config, force, quiet: bool) -> dict:
    """Run the pipeline with progress bars and print the summary; returns report.json's content."""
    from recon.pipeline import Pipeline

    pipeline = Pipeline(config, progress=lambda label, total: progress_bar(label, total, quiet=quiet))
    report = pipeline.run(force=tuple(force))
    print_summary(report, pipeline.out)
    return report


def print_summary(report: dict, out) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title="recon run summary")
    table.add_column("section")
    table.add_column("figures")
    for stage, seconds in report.get("timing", {}).items():
        table.add_row(f"time: {stage}", f"{seconds:.1f} s")
    table.add_row("peak memory", f"{report['memory']['peak_rss_mb']:.0f} MB")
    if "depth" in report:
        d = report["depth"]
        table.add_row("depth", f"abs_rel {d['abs_rel']:.4f}  rmse {d['rmse']:.3f}  a1 {d['a1']:.3f}  "
                               f"({d['frames']} frames, align {d['align']})")
    if "temporal" in report:
        t = report["temporal"]
        table.add_row("temporal", f"mae {t['mae_mean']:.3f} +- {t['mae_std']:.3f}  flicker {t['flicker']:.4f}")
    if "mesh" in report:
        m = report["mesh"]
        table.add_row("mesh", f"F-score {m['fscore']:.3f}  acc {m['acc']:.3f}  comp {m['comp']:.3f}  "
                              f"prec {m['prec']:.3f}  recall {m['recall']:.3f}")
    if "poses" in report:
        q = report["poses"]
        table.add_row("poses", f"ATE {q['ate_rmse']:.4f}  registered {q['registered']:.1%}")
    table.add_row("scale", "metric" if report.get("metric_scale") else "unknown (arbitrary units)")
    console.print(table)
    print(f"report: {out / 'report.html'}")


def run(args):
    execute(config_from_args(args, args.input, args.out), args.force, args.quiet)
    return 0
