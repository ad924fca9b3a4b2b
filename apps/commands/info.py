"""`recon info`: what a scan, a video or a photo folder contains, or the list of readable formats."""
from apps import options
from apps.common import open_selected_scan, print_json


def register(subparsers):
    subparsers.add_parser("info", help="describe a scan (frames, intrinsics, scale, depth), a video or a photo folder",
                          description="Read a scan in any supported format, a video or a folder of photos, and "
                                      "summarise it.", arguments=add_arguments)
    subparsers.add_parser("formats", help="list the scan formats `--format` accepts",
                          description="The scan formats `--format` accepts, with what each reads.",
                          arguments=lambda p: p.set_defaults(func=run_formats))


def add_arguments(p) -> None:
    options.add_input(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run_formats(args):
    from recon.readers import READERS

    for r in READERS:
        print(f"{r.NAME:12s} {(r.__doc__ or '').strip().splitlines()[0]}")
    return 0


def run(args):
    from pathlib import Path

    from poses.ingest import describe_capture, scan_format

    if args.format == "auto" and scan_format(Path(args.scan)) is None:  # what `recon run` poses by SfM
        return _print(describe_capture(args.scan), args.json)
    return _print(scan_info(open_selected_scan(args.scan, args)), args.json)


def scan_info(scan) -> dict:
    import numpy as np

    centres = scan.camera_to_world[:, :3, 3]
    length = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum()) if len(scan) > 1 else 0.0
    info = {"path": str(scan.root), "format": scan.metadata.source_format, "frames": len(scan),
            "intrinsics": scan.intrinsics.to_dict(), "metric_scale": scan.metadata.metric_scale,
            "has_depth": scan.has_depth, "trajectory_length": length,
            "first_frame": scan.frames[0].name, "last_frame": scan.frames[-1].name,
            "distorted": scan.distortion is not None, "gt_mesh": scan.metadata.gt_mesh,
            "missing_images": int(scan.metadata.extra.get("missing_images", 0))}  # listed, skipped by the reader
    return info


def _print(info: dict, as_json: bool) -> int:
    if as_json:
        print_json(info)
    else:
        width = max(map(len, info)) + 1
        for k, v in info.items():
            print(f"{k:{width}s} {v}")
    return 0
