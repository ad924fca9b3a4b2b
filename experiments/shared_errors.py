"""Do neighbouring views share their depth errors? TSDF fusion averages views, so only errors that differ between
views can cancel; an error every view of a wall shares survives into the mesh.

    python experiments/shared_errors.py runs/select_bf16/compact_bf16 runs/select_k37/compact_k37_010429 --cache runs/select_k35/scans

For each held-out scan and each selection row's stored ESTM maps (`ROW_DIR/<scan>/estm_m2`): frame a's signed
relative error is reprojected into frame b = a + gap (pixels both see at the same surface, GT under 4 m, the
fusion range) and correlated with b's own. Also printed: how much averaging the two views shrinks the error,
mean |(e_a + e_b) / 2| over mean (|e_a| + |e_b|) / 2 (1: no gain, 0.71 for independent errors of equal size).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

GAPS = (1, 3, 6)
FUSION_MAX_M = 4.0


def pair_errors(pred_a, gt_a, pred_b, gt_b, K, a_to_world, b_to_world) -> tuple[np.ndarray, np.ndarray] | None:
    """Signed relative errors of a (reprojected into b) and of b on the pixels both see at the same surface."""
    from recon.geometry import reproject_depth

    warped_pred = reproject_depth(pred_a, K, a_to_world, b_to_world, gt_b.shape)
    warped_gt = reproject_depth(gt_a, K, a_to_world, b_to_world, gt_b.shape)
    same = (warped_pred > 0) & (warped_gt > 0) & (pred_b > 0) & (gt_b > 0) & (gt_b < FUSION_MAX_M)
    same &= np.abs(warped_gt - gt_b) < 0.05 * gt_b  # not an occlusion
    if same.sum() < 500:
        return None
    return ((warped_pred[same] - warped_gt[same]) / warped_gt[same], (pred_b[same] - gt_b[same]) / gt_b[same])


def scan_row(scan, gts: list, preds: list) -> list[str]:
    cells = []
    for gap in GAPS:
        corr, gain = [], []
        for a in range(len(scan) - gap):
            b = a + gap
            pair = pair_errors(preds[a], gts[a], preds[b], gts[b], scan.intrinsics.K,
                               scan.frames[a].camera_to_world, scan.frames[b].camera_to_world)
            if pair is not None:
                ea, eb = pair
                corr.append(np.corrcoef(ea, eb)[0, 1])
                gain.append(np.mean(np.abs(ea + eb) / 2) / np.mean((np.abs(ea) + np.abs(eb)) / 2))
        cells.append(f"gap {gap}: corr {np.mean(corr):.3f}, averaged {np.mean(gain):.3f}" if corr else f"gap {gap}: -")
    return cells


def main(argv=None) -> None:
    from experiments.select_checkpoint import stored_maps

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rows", nargs="+", type=Path, metavar="ROW_DIR", help="selection rows' folders")
    parser.add_argument("--cache", type=Path, default=ROOT / "runs" / "select" / "scans",
                        help="held-out scan cache of experiments/select_checkpoint.py (made when missing)")
    args = parser.parse_args(argv)
    for scan_name, scan, row, gts, preds in stored_maps(args.rows, args.cache):
        print(f"{scan_name:18s} {row.name:28s} " + " | ".join(scan_row(scan, gts, preds)), flush=True)

if __name__ == "__main__":
    main()
