"""`recon depth`: one depth map (+ confidence) per frame of a scan, from the EST network or plane sweep."""
from __future__ import annotations

import argparse
import logging

from apps.common import add_scan_args, open_selected_scan

log = logging.getLogger(__name__)

MODES = ("estm", "joint", "independent", "planesweep")


def register(subparsers):
    p = subparsers.add_parser(
        "depth", help="estimate a depth map per frame (EST network with temporal memory, or plane sweep)",
        description="Predict depth and confidence for every selected frame and write <name>.npy/.png/.conf.npy "
                    "plus depth.json to --out. Learned modes need weights; planesweep needs none.")
    add_scan_args(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder for the depth maps")
    p.add_argument("--mode", choices=MODES, default="estm", help="inference mode (default estm)")
    p.add_argument("--weights", default="compact", metavar="NAME|PATH",
                   help="shipped weights name or checkpoint path (default: compact)")
    p.add_argument("--config", default=None, help="refuse a checkpoint of another network config (paper, compact)")
    p.add_argument("--window", choices=("offline", "online"), default="offline",
                   help="sources before and after each frame (offline) or before only (online)")
    p.add_argument("--memory", type=int, default=None, metavar="N", help="ESTM memory length (default: config, 2)")
    p.add_argument("--depth-range", type=float, nargs=2, default=None, metavar=("MIN", "MAX"),
                   help="depth range to sweep (default: the scan's metadata)")
    p.add_argument("--fit", choices=("stretch", "crop"), default="stretch",
                   help="fit frames to the network size: stretch the whole frame (default) or crop (scale to cover, keep the "
                        "aspect ratio; the cropped-off borders get no depth)")
    p.add_argument("--baseline", type=float, default=0.15,
                   help="translation a frame's sources should ideally have, in scan units (default 0.15)")
    p.add_argument("--keyframe-distance", type=float, default=0.0, metavar="D",
                   help="only frames whose pose distance from the previous keyframe reaches D (DESIGN's "
                        "keyframe rule, about 0.1); default 0: every selected frame")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--precision", choices=("fp32", "bf16"), default="fp32",
                   help="network arithmetic: bf16 autocast is faster on GPUs and bf16-capable CPUs (default fp32)")
    p.add_argument("--compile", action="store_true",
                   help="torch.compile the network: about a minute of compiling, then faster frames (GPU above all)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from depth.inference import DepthOptions, estimate_depth
    from depth.selection import select_keyframes

    scan = open_selected_scan(args.scan, args)
    if args.keyframe_distance > 0:
        keys = select_keyframes(scan.camera_to_world, args.keyframe_distance)
        log.info("%d keyframes of %d frames (distance %g)", len(keys), len(scan), args.keyframe_distance)
        scan = scan.subset(keys)
    opts = DepthOptions(mode=args.mode, window=args.window, memory_size=args.memory,
                        depth_range=tuple(args.depth_range) if args.depth_range else None,
                        source_baseline=args.baseline, device=args.device, config=args.config,
                        precision=args.precision, fit=args.fit, compile=args.compile)
    weights = None if args.mode == "planesweep" else args.weights
    with Progress(TextColumn("depth ({task.fields[mode]})"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeRemainingColumn(), disable=getattr(args, "quiet", False)) as bar:
        task = bar.add_task("depth", total=len(scan), mode=args.mode)
        summary = estimate_depth(scan, args.out, opts, weights=weights,
                                 progress=lambda i, n: bar.update(task, completed=i))
    skipped = f", {len(summary['skipped'])} skipped" if summary["skipped"] else ""
    print(f"wrote {len(summary['frames'])} depth maps to {args.out} ({args.mode}, "
          f"{summary['seconds_per_frame']:.2f} s/frame{skipped})")
    return 0
