"""Stretch or crop frames to the network size? ESTM (memory 2) both ways on ICL-NUIM (640x480, held out).

    python experiments/compare_fit.py [--weights compact] [--out runs/fit_compare]

Prints Abs Rel, delta<1.25, flicker, coverage and Abs Rel on covered pixels for each fit
(evaluation range 0-10 m, every 5th frame, sweep range from the weights). Never 7-Scenes.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ICL = ROOT.parent / "shared" / "data" / "iclnuim-livingroom1"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default="compact")
    p.add_argument("--out", default="runs/fit_compare")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    import torch

    from depth.inference import estimate_depth
    from depth.options import FITS, DepthOptions
    from depth.metrics import evaluate_depth_folder
    from recon.readers import open_scan
    from experiments.results_7scenes import covered_abs_rel

    if not ICL.is_dir():
        print(f"no ICL-NUIM sequence at {ICL}", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    scan = open_scan(ICL).select(0, 5)
    results = {}
    for fit in FITS:
        out = Path(args.out) / fit
        estimate_depth(scan, out, DepthOptions(mode="estm", fit=fit, weights=args.weights), resume=True)
        m = evaluate_depth_folder(out, scan, 1e-3, 10.0)
        results[fit] = {k: m[k] for k in ("abs_rel", "a1", "flicker", "coverage")}
        results[fit]["abs_rel_covered"] = covered_abs_rel(out, scan, 1e-3, 10.0)
        print(fit, json.dumps({k: round(v, 4) for k, v in results[fit].items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
