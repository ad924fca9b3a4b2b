"""The hybrid's meshes at confidence thresholds, beside the plane sweep's, on the held-out scans.

    python experiments/hybrid_confidence.py --cache /tmp/guided

Reads the depth folders `experiments/guided_sweep.py` left in `--cache` (each scan's `hybrid` and
`planesweep`, with its GT-depth fusion) and fuses them unfiltered, the hybrid also with
`--min-confidence` at each threshold. Refined pixels carry their NCC score (>= 0.5), the network's pixels
its peak plane probability, so a threshold keeps the refined pixels and the network's surest ones.
Prints precision / recall / F at 5 cm per scan and row (docs/depth.md, "Hybrid depth").
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cache", default="/tmp/guided")
    p.add_argument("--thresholds", default="0.3,0.5,0.7")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    from experiments.results_7scenes import TableOptions, mesh_scores
    from experiments.select_checkpoint import heldout_scans
    from fusion.filtering import FilterConfig
    from fusion.mesh import load_mesh

    cache = Path(args.cache)
    rows = [("planesweep", None), ("hybrid", None)] + [("hybrid", float(t)) for t in args.thresholds.split(",")]
    for name, scan in heldout_scans(cache).items():
        run = cache / "runs" / name
        if not (run / "hybrid" / "depth.json").is_file():
            print(f"{name}: no hybrid maps in {run} (run experiments/guided_sweep.py first)")
            continue
        reference = load_mesh(run / "mesh_gt_fusion.ply")
        for row, threshold in rows:
            opts = TableOptions(mesh_row=row, depth_filter=FilterConfig(checks=()), min_confidence=threshold)
            m = mesh_scores(scan, run, opts, reference=reference, log=lambda line: None)
            label = row + (f" min-confidence {threshold:g}" if threshold is not None else "")
            print(f"{name} {label:28s} P {m['prec']:.3f} R {m['recall']:.3f} F {m['fscore']:.3f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
