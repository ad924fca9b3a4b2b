"""Depth accuracy of each stage of the network (D0 hybrid volume, D1 after the EST transformer, D2 and D3 after
the RefineNet's two stages) on held-out scans, to see which part moves the depth.

    python experiments/stage_accuracy.py lite-preview compact --scans iclnuim_s5,synthetic_910001

ESTM (memory 2) over every frame of each scan as `experiments/select_checkpoint.py` prepares them (never
7-Scenes); each stage's map resampled onto the scan's pixels (bilinear), scored on GT pixels in 0.1-10 m:
Abs Rel, the share within 5 cm, the median ratio prediction / GT ("scale"), and Abs Rel and the share
within 5 cm once every frame is divided by its own ratio (what is left when the scale is right).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def stage_maps(estimator, scan, opts) -> dict[int, list]:
    """Frame index -> [D0..D3] on the scan's pixels, from one ESTM pass."""
    from depth import estimator as est_module

    maps, step = {}, est_module.DepthEstimator._step

    def keep_stages(run, memory, i, mode):
        out = step(run, memory, i, mode)
        if not run.mirrored:
            maps[i] = [est_module.to_scan_pixels(d, run.net_scan, run.output_size)[0, 0].numpy() for d in out.depths]
        return out

    est_module.DepthEstimator._step = staticmethod(keep_stages)
    try:
        list(estimator.run(scan, opts))
    finally:
        est_module.DepthEstimator._step = staticmethod(step)
    return maps


def stage_scores(scan, maps: dict[int, list]):
    import cv2
    import numpy as np

    rows = np.zeros((4, 5))
    for i, stages in maps.items():
        gt = cv2.resize(scan.depth(i), stages[0].shape[::-1], interpolation=cv2.INTER_NEAREST)
        ok = (gt > 0.1) & (gt < 10)
        g = gt[ok]
        for k, d in enumerate(stages):
            p = d[ok]
            r = float(np.median(p / g))
            rows[k] += [np.mean(np.abs(p - g) / g), np.mean(np.abs(p - g) < 0.05), r,
                        np.mean(np.abs(p / r - g) / g), np.mean(np.abs(p / r - g) < 0.05)]
    return rows / len(maps)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("weights", nargs="+", help="shipped names or checkpoint files")
    p.add_argument("--scans", default="iclnuim_s5,synthetic_910001", help="held-out scan names (select_checkpoint.py)")
    p.add_argument("--cache", default="runs/select/scans", help="where the held-out synthetic scans are kept")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)

    import torch

    from depth.checkpoint import trained_depth_range
    from depth.estimator import DepthEstimator
    from depth.options import DepthOptions
    from experiments.select_checkpoint import heldout_scans

    torch.set_num_threads(args.threads)
    scans = heldout_scans(Path(args.cache))
    print("| weights | scan | stage | Abs Rel | within 5 cm | scale | Abs Rel, scale divided out | within 5 cm, same |")
    print("|---|---|---|---|---|---|---|---|")
    for weights in args.weights:
        estimator = DepthEstimator.from_weights(weights, device="cpu")
        opts = DepthOptions(mode="estm", device="cpu", weights=weights, depth_range=trained_depth_range(weights))
        for name in args.scans.split(","):
            rows = stage_scores(scans[name], stage_maps(estimator, scans[name], opts))
            for k, (rel, w5, ratio, rel_s, w5_s) in enumerate(rows):
                print(f"| {weights} | {name} | D{k} | {rel:.3f} | {w5:.1%} | {ratio:.3f} | {rel_s:.3f} | {w5_s:.1%} |",
                      flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
