"""`recon demo`: the whole pipeline on the embedded example, a synthetic room video with exact ground truth.

The example is generated deterministically on first run into examples/demo_room/
(scan with supplied poses, GT depth and mesh, plus video.mp4 for the SfM path: `--poses colmap`).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

EXAMPLE_DIR = Path(__file__).resolve().parents[2] / "examples" / "demo_room"
DEMO_SEED = 7
DEMO_FRAMES = 120
DEMO_SIZE = (320, 240)


def register(subparsers):
    about = ("Reconstruct the embedded example (a synthetic room video with supplied poses and exact ground "
             "truth), print a summary, write report.html. `--poses colmap` takes the video through SfM instead.")
    subparsers.add_parser("demo", help="run the whole pipeline on the embedded synthetic room", description=about,
                          arguments=add_arguments)


def add_arguments(p) -> None:
    from apps.commands.run import add_pipeline_args

    p.add_argument("--out", default="out/demo", help="run folder")
    add_pipeline_args(p, with_input=False)
    p.set_defaults(func=run, mode=None)


def ensure_example() -> Path:
    """The demo scan folder, rendered on first use (seeded, so every machine gets the same one)."""
    if (EXAMPLE_DIR / "scan.json").is_file() and (EXAMPLE_DIR / "video.mp4").is_file():
        return EXAMPLE_DIR
    from recon.synthetic import SynthConfig, write_synthetic_scan

    print(f"rendering the demo room into {EXAMPLE_DIR} (first run only)")
    write_synthetic_scan(SynthConfig(seed=DEMO_SEED, frames=DEMO_FRAMES, width=DEMO_SIZE[0], height=DEMO_SIZE[1]),
                         EXAMPLE_DIR, video=True)
    return EXAMPLE_DIR


def run(args):
    from apps.commands.run import config_from_args, execute

    example = ensure_example()
    sfm = args.poses == "colmap"  # the video through SfM, scored against the supplied poses
    config = config_from_args(args, str(example / "video.mp4" if sfm else example), args.out,
                              gt_poses=args.gt_poses or (str(example) if sfm else None))
    config.evaluation = dataclasses.replace(config.evaluation, gt_mesh=args.gt_mesh or str(example / "gt_mesh.ply"))
    execute(config, args.force, args.quiet)
    return 0
