"""`recon poses INPUT --out DIR`: camera poses for a video, an image folder or a recorded scan, by SfM."""
from __future__ import annotations

from apps import options


def register(subparsers):
    p = subparsers.add_parser(
        "poses", help="SfM poses (pycolmap) for a video, image folder or scan -> canonical scan",
        description="Runs pycolmap SfM on the images of INPUT (a recorded scan's own poses are ignored, so the "
                    "result can be scored with `recon eval poses`). DIR gets the canonical scan (scan.json, "
                    "undistorted images/), frames/ and colmap/ (database + models, for the COLMAP GUI) and "
                    "poses_report.json. Without --scale/--known-distance/--reference the scale is normalised, "
                    "not metric; the scan says which.")
    p.add_argument("input", help="video file (mp4/mov/avi), folder of images, or any readable scan")
    p.add_argument("--out", required=True, help="output folder")
    g = p.add_argument_group("frames")
    g.add_argument("--stride", type=int, default=1, metavar="N", help="use every N-th frame (default 1)")
    g.add_argument("--max-frames", type=int, default=None, metavar="N", help="use at most N frames (default all)")
    g.add_argument("--min-motion", type=float, default=None, metavar="PX",
                   help="keep a frame only once the image moved PX pixels (median) since the last kept one")
    g.add_argument("--blur-ratio", type=float, default=0.35, metavar="R",
                   help="drop frames sharper than less than R x their neighbours' median (0 keeps all; default 0.35)")
    g.add_argument("--max-size", type=int, default=640, metavar="PX", help="long side of working images (default 640)")
    options.add_sfm(p)
    s = p.add_argument_group("SfM details")
    s.add_argument("--no-fallback", action="store_true", help="do not try the other mapper when the first fails")
    s.add_argument("--features", type=int, default=2048, metavar="N", help="SIFT features per image (default 2048)")
    s.add_argument("--overlap", type=int, default=10, metavar="N", help="sequential matching window (default 10)")
    c = p.add_argument_group("scale (default: normalised so the median scene depth is --target-depth)")
    x = c.add_mutually_exclusive_group()
    x.add_argument("--scale", type=float, default=None, metavar="FACTOR", help="metres per SfM unit")
    x.add_argument("--known-distance", nargs=3, metavar=("FRAME_A", "FRAME_B", "METRES"), default=None,
                   help="metres between the cameras of two frames (names as in the output scan)")
    x.add_argument("--reference", default=None, metavar="SCAN",
                   help="scan with metric poses for the same frame names: Sim(3)-align to it")
    c.add_argument("--target-depth", type=float, default=2.0, metavar="M",
                   help="normalisation: median sparse-point depth after scaling (default 2.0)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from apps.common import print_json
    from poses.ingest import IngestConfig
    from recon.readers import open_scan
    from poses.scale import ScaleConfig
    from poses.sfm import PosesConfig, SfMConfig, estimate_poses
    from recon.errors import ReconError

    known = None
    if args.known_distance:
        try:
            known = (args.known_distance[0], args.known_distance[1], float(args.known_distance[2]))
        except ValueError:
            raise ReconError(f"--known-distance: {args.known_distance[2]!r} is not a number of metres") from None
    config = PosesConfig(
        ingest=IngestConfig(stride=args.stride, fps=args.fps, max_frames=args.max_frames, min_motion_px=args.min_motion,
                            blur_ratio=args.blur_ratio, max_size=args.max_size),
        sfm=SfMConfig(mapper=args.mapper, fallback=not args.no_fallback, camera_model=args.camera_model,
                      max_num_features=args.features, sequential_overlap=args.overlap),
        scale=ScaleConfig(factor=args.scale, known_distance=known, target_median_depth=args.target_depth))
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
