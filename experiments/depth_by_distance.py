"""Where a network's depth goes wrong: Abs Rel, the share within 5 cm and scale by true distance.

    python experiments/depth_by_distance.py compact-preview [more weights ...]
    python experiments/depth_by_distance.py --maps runs/select_k37/compact_k37_010429 runs/select_bf16/compact_bf16

With weights: ESTM (memory 2) over the demo room every 4th frame (the held-out scan of
experiments/select_checkpoint.py), sweeping the weights' trained range as the product does; also per frame.
With `--maps`: the ESTM maps a selection run left (`ROW_DIR/<scan>/estm_m2`) on every held-out scan, nothing
recomputed. Prints, per band of GT depth, the share of pixels, Abs Rel, the share within 5 cm and the median
prediction / GT ratio (> 1: predicted too far). Fusion takes depth up to 4 m and weighs near pixels more, so
the bands under 2 m decide most of a mesh, while Abs Rel over 0-10 m also counts what fusion never sees.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BANDS_M = ((0, 1), (1, 2), (2, 3), (3, 4), (4, 6), (6, 10))


def band_rows(gt: np.ndarray, pred: np.ndarray) -> list[str]:
    """One line per band of `gt` (valid pixels only, metres) with its share, Abs Rel, within 5 cm and scale."""
    lines = [f"  all: Abs Rel {np.mean(np.abs(pred - gt) / gt):.3f}"]
    for lo, hi in BANDS_M:
        band = (gt >= lo) & (gt < hi)
        if band.any():
            g, p = gt[band], pred[band]
            lines.append(f"  GT {lo}-{hi} m: {band.mean():5.1%} of pixels, Abs Rel {np.mean(np.abs(p - g) / g):.3f}, "
                         f"within 5 cm {np.mean(np.abs(p - g) < 0.05):5.1%}, median ratio {np.median(p / g):.2f}")
    return lines


def run_weights(weights: list[str]) -> None:
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
        print(w)
        print("\n".join(band_rows(np.concatenate(gt_all), np.concatenate(pred_all))))
        print("  per frame (Abs Rel, median ratio): " + ", ".join(frames))


def run_maps(rows: list[Path], cache: Path) -> None:
    from experiments.select_checkpoint import stored_maps

    for scan_name, _, row, gts, preds in stored_maps(rows, cache):
        valid = [np.isfinite(gt) & (gt > 1e-3) & (gt < 10.0) for gt in gts]  # the selection's evaluation range
        print(f"{scan_name} {row.name}")
        print("\n".join(band_rows(np.concatenate([g[v] for g, v in zip(gts, valid)]),
                                  np.concatenate([p[v] for p, v in zip(preds, valid)]))))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("weights", nargs="*", help="weights to run on the demo room (default: compact)")
    parser.add_argument("--maps", nargs="+", type=Path, metavar="ROW_DIR",
                        help="score the maps of these selection rows on every held-out scan instead")
    parser.add_argument("--cache", type=Path, default=ROOT / "runs" / "select" / "scans",
                        help="held-out scan cache of experiments/select_checkpoint.py (made when missing)")
    args = parser.parse_args(argv)
    if args.maps:
        run_maps(args.maps, args.cache)
    else:
        run_weights(args.weights or ["compact"])


if __name__ == "__main__":
    main()
