"""`recon depth`: one depth map (+ confidence) per frame of a scan, from the EST network or plane sweep."""
from __future__ import annotations

import argparse
import logging

from apps import options
from apps.common import open_selected_scan
from apps.progress import progress_bar

log = logging.getLogger(__name__)


def register(subparsers):
    subparsers.add_parser(
        "depth", help="estimate a depth map per frame (EST network with temporal memory, or plane sweep)",
        description="Predict depth and confidence for every selected frame and write <name>.png (mm) / .conf.png "
                    "plus depth.json to --out, at the network's resolution unless --full-res-depth. Learned modes "
                    "use the shipped weights unless --weights names others; planesweep needs none.",
        arguments=add_arguments)


def add_arguments(p) -> None:
    options.add_input(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder for the depth maps")
    options.add_keyframes(p)
    options.add_depth(p, with_device=True)
    options.add_depth_storage(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from depth.inference import estimate_depth
    from recon.keyframes import select_keyframes

    opts = options.depth_options(args, options.pick_mode(args.mode, args.weights))
    scan = open_selected_scan(args.scan, args)
    keys = select_keyframes(scan.camera_to_world, options.keyframe_config(args))
    if len(keys) < len(scan):
        log.info("%d keyframes of %d frames (distance %g)", len(keys), len(scan), args.keyframe_distance)
        scan = scan.subset(keys)
    with progress_bar(f"depth ({opts.mode})", len(scan), quiet=getattr(args, "quiet", False)) as advance:
        summary = estimate_depth(scan, args.out, opts, progress=lambda i, n: advance())
    skipped = f", {len(summary['skipped'])} skipped" if summary["skipped"] else ""
    print(f"wrote {len(summary['frames'])} depth maps to {args.out} ({opts.mode}, "
          f"{summary['seconds_per_frame']:.2f} s/frame{skipped})")
    return 0
