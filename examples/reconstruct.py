"""Reconstruct one input (video, image folder or recorded scan) through the Python API.

    python examples/reconstruct.py INPUT OUT_DIR [--mode planesweep]

The same as `recon run INPUT --out OUT_DIR`, for use from a notebook or another program:
each stage can also be called alone (Pipeline.stage_scan, stage_depth, stage_fusion, ...).
"""
import argparse
import json

from recon.pipeline import Pipeline, RunConfig


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input")
    p.add_argument("out")
    p.add_argument("--mode", default="planesweep", help="estm needs weights (--weights); planesweep needs none")
    p.add_argument("--weights", default=None)
    args = p.parse_args()
    report = Pipeline(RunConfig(input=args.input, out=args.out, mode=args.mode, weights=args.weights)).run()
    print(json.dumps({k: report[k] for k in ("depth", "mesh", "poses", "timing") if k in report}, indent=1))
    print(f"mesh: {args.out}/mesh.ply  report: {args.out}/report.html")


if __name__ == "__main__":
    main()
