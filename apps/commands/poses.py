"""`recon poses INPUT --out DIR`: camera poses for a video, an image folder or a recorded scan, by SfM."""
from __future__ import annotations

from apps import options


def register(subparsers):
    subparsers.add_parser(
        "poses", help="SfM poses (pycolmap) for a video, image folder or scan -> canonical scan",
        description="Runs pycolmap SfM on the images of INPUT (a recorded scan's own poses are ignored, so the "
                    "result can be scored with `recon eval poses`). DIR gets the canonical scan (scan.json, "
                    "undistorted images/), frames/ and colmap/ (database + models, for the COLMAP GUI) and "
                    "poses_report.json. Without --scale/--known-distance/--reference the scale is normalised, "
                    "not metric; the scan says which.", arguments=add_arguments)


def add_arguments(p) -> None:
    p.add_argument("input", help="video file (mp4/mov/avi), folder of images, or any readable scan")
    p.add_argument("--out", required=True, help="output folder")
    options.add_selection(p, start=False)
    options.add_sfm(p)
    p.add_argument("--reference", default=None, metavar="SCAN",
                   help="scale: Sim(3)-align to this scan's metric poses for the same frame names "
                        "(instead of --scale / --known-distance)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from apps.common import print_json
    from poses.sfm import estimate_poses
    from recon.errors import ReconError
    from recon.readers import open_scan

    if args.reference and (args.scale or args.known_distance):
        raise ReconError("--reference, --scale and --known-distance each set the scale: give one of them")
    config = options.poses_config(args)
    reference = open_scan(args.reference) if args.reference else None
    scan, report = estimate_poses(args.input, args.out, config, reference)
    if args.json:
        print_json(report)
        return 0
    sfm, scale = report["sfm"], report["scale"]
    print(f"registered {report['registered']} of {report['frames']} frames with the {sfm['mapper']} mapper")
    if report["unregistered"]:
        print(f"left out (no pose): {', '.join(report['unregistered'])}")
    print("time per step: " + ", ".join(f"{k} {v:.1f} s" for k, v in report["timings_s"].items()))
    lo, hi = scan.metadata.depth_range
    units = "m" if scan.metadata.metric_scale else "units"
    print(f"scale: {scale['method']} (factor {scale['factor']:.4g}) -> "
          f"{'METRIC' if scan.metadata.metric_scale else 'NOT metric'}; depth range {lo:.2f}-{hi:.2f} {units}")
    print(f"scan written to {args.out} (COLMAP database and model in {args.out}/colmap)")
    return 0
