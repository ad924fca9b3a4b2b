"""Reconstruct one input (video, image folder or recorded scan) through the Python API.

    python examples/reconstruct.py INPUT OUT_DIR [--mode estm|joint|independent|planesweep] [--export glb ...]

The same as `recon run INPUT --out OUT_DIR` (and `recon export`), for use from a notebook or another
program: each stage can also be called alone (Pipeline.stage_scan, stage_depth, stage_fusion, ...).
"""
import argparse
import json

from apps.export import FORMATS, export_run
from apps.pipeline import InputConfig, Pipeline, RunConfig
from depth.options import DepthOptions


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input")
    p.add_argument("out")
    p.add_argument("--mode", default=DepthOptions.mode,
                   help="estm (the shipped network with temporal memory), joint, independent, planesweep "
                        "(default %(default)s)")
    p.add_argument("--weights", default=None, help="a checkpoint instead of the shipped weights")
    p.add_argument("--export", nargs="*", default=[], choices=FORMATS, help="also write the run in these formats")
    args = p.parse_args()
    config = RunConfig(InputConfig(args.input), args.out, depth=DepthOptions(mode=args.mode, weights=args.weights))
    report = Pipeline(config.validate()).run()
    print(json.dumps({k: report[k] for k in ("depth", "mesh", "poses", "timing") if k in report}, indent=1))
    print(f"mesh: {args.out}/mesh.ply  report: {args.out}/report.html")
    for fmt in args.export:
        print(f"{fmt}: {export_run(args.out, fmt)}")


if __name__ == "__main__":
    main()
