"""Where a network's depth goes wrong on the demo room: Abs Rel and scale by true distance and by frame.

    python experiments/depth_by_distance.py compact-preview [more weights ...]

ESTM (memory 2) over the demo room every 4th frame (the held-out scan of experiments/select_checkpoint.py),
sweeping the weights' trained range as the product does. Prints, per band of GT depth, the share of
pixels, Abs Rel and the median prediction / GT ratio (> 1: predicted too far), then per frame.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BANDS_M = ((0, 1), (1, 2), (2, 3), (3, 4), (4, 6), (6, 10))


def main(weights: list[str]) -> None:
    from apps.commands.demo import ensure_example
    from depth.checkpoint import trained_depth_range
    from depth.estimator import DepthEstimator
    from depth.options import DepthOptions
    from recon.readers import open_scan

    scan = open_scan(ensure_example()).select(0, 4)
    for w in weights:
        estimator = DepthEstimator.from_weights(w, "cpu")
        gt_all, pred_all, frames = [], [], []
        for r in estimator.run(scan, DepthOptions(mode="estm", device="cpu", depth_range=trained_depth_range(w))):
            gt = scan.depth(r.index)
            valid = gt > 0
            g, p = gt[valid], r.depth[valid]
            gt_all.append(g)
            pred_all.append(p)
            frames.append(f"{r.index}: {np.mean(np.abs(p - g) / g):.3f} x{np.median(p / g):.2f}")
        g, p = np.concatenate(gt_all), np.concatenate(pred_all)
        print(f"{w}: Abs Rel {np.mean(np.abs(p - g) / g):.3f}")
        for lo, hi in BANDS_M:
            band = (g >= lo) & (g < hi)
            if band.any():
                print(f"  GT {lo}-{hi} m: {band.mean():5.1%} of pixels, Abs Rel {np.mean(np.abs(p[band] - g[band]) / g[band]):.3f}, "
                      f"median ratio {np.median(p[band] / g[band]):.2f}")
        print("  per frame (Abs Rel, median ratio): " + ", ".join(frames))


if __name__ == "__main__":
    main(sys.argv[1:] or ["compact"])
