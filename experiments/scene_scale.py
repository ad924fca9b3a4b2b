"""How much a network's depth depends on the absolute size of the scene (held-out scans only, never 7-Scenes).

    python experiments/scene_scale.py lite-preview compact --scales 0.6,0.8,1,1.3,1.7 --frames 40

Every camera translation is multiplied by s before ESTM (memory 2) runs and the depth it returns is divided
by s again, so a network that took depth from multi-view geometry alone would score the same at every s;
what changes is how far the scene looks from its appearance (the ContextNet's monocular prior) and where it
falls among the trained depth planes. Prints Abs Rel, within 5 cm, the scale bias and the mean confidence (peak
plane probability) per network, scan and s.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def scores(estimator, scan, scale: float, weights: str) -> dict[str, float]:
    """Mean per-frame Abs Rel, within 5 cm, median ratio and confidence of ESTM on `scan` seen `scale` times larger."""
    from depth.metrics import depth_metrics, on_gt_grid
    from depth.options import DepthOptions
    from poses.scale import transform_scan

    opts = DepthOptions(mode="estm", weights=weights, device="cpu", depth_range=estimator.trained_depth_range)
    rows = []
    for fd in estimator.run(transform_scan(scan, scale), opts):
        gt = scan.depth(fd.index)
        m = depth_metrics(on_gt_grid(fd.depth, gt) / scale, gt)
        if m is not None:
            rows.append({**m, "confidence": float(fd.confidence.mean())})
    return {k: float(np.mean([r[k] for r in rows])) for k in ("abs_rel", "within_5cm", "median_ratio", "confidence")}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("weights", nargs="+", help="shipped names or checkpoint paths")
    p.add_argument("--scales", default="0.6,0.8,1,1.3,1.7")
    p.add_argument("--scans", default="synthetic_910001,synthetic_910002,demo_s4,iclnuim_s5")
    p.add_argument("--frames", type=int, default=40, help="first N frames of each scan")
    p.add_argument("--cache", default="runs/select/scans", help="where the held-out synthetic rooms are rendered")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)

    import torch

    from depth.estimator import DepthEstimator
    from experiments.select_checkpoint import heldout_scans

    torch.set_num_threads(args.threads)
    scans = heldout_scans(Path(args.cache))
    scales = [float(s) for s in args.scales.split(",")]
    print("| weights | scan | GT median depth | s | depth seen (median) | Abs Rel | within 5 cm | scale | confidence |")
    print("|---|---|---|---|---|---|---|---|---|")
    for weights in args.weights:
        estimator = DepthEstimator.from_weights(weights, device="cpu")
        for key in args.scans.split(","):
            scan = scans[key].subset(range(min(args.frames, len(scans[key]))))
            median = float(np.median(np.concatenate([d[d > 0] for d in map(scan.depth, range(len(scan)))])))
            for s in scales:
                r = scores(estimator, scan, s, weights)
                print(f"| {weights} | {key} | {median:.2f} m | {s:g} | {median * s:.2f} m | {r['abs_rel']:.3f} | "
                      f"{r['within_5cm']:.1%} | {r['median_ratio']:.3f} | {r['confidence']:.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
