"""Which side of the depth error costs the mesh: depth too near (a surface in front of the true one) or too far?

    python experiments/error_sides.py runs/select_bf16/compact_bf16 runs/select_k43/compact_k43_10300_bf16 --cache runs/select_k35/scans --out runs/error_sides

For each held-out scan and each selection row's stored ESTM maps (`ROW_DIR/<scan>/estm_m2`): the share of pixels
(GT under 4 m, the fusion range) more than 5 and 15 cm too near and too far, then two oracle fusions, each with one
side's pixels (more than 5 cm off) replaced by the GT depth and everything else as predicted, fused and scored as
selection fuses (default filter, 4 cm voxels). The mesh F each oracle reaches says what that side of the error costs.
Each F is given twice: as every table scores it, with the visibility culling of the evaluation protocol (mesh
behind the GT surface in every view does not count), and without it (every predicted surface counts).
Diagnosis only: the oracle reads the GT.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FUSION_MAX_M = 4.0
OFF_M = 0.05


def error_shares(gt: np.ndarray, pred: np.ndarray) -> dict:
    """Shares of the valid pixels under FUSION_MAX_M that are too near / too far by more than 5 and 15 cm.
    gt, pred: (N, H, W) metres on one grid."""
    ok = np.isfinite(gt) & (gt > 0) & (gt < FUSION_MAX_M) & np.isfinite(pred) & (pred > 0)
    err = (pred - gt)[ok]
    return {f"{side}_{cm}cm": float(np.mean(sign * err > cm / 100)) for side, sign in (("near", -1), ("far", 1))
            for cm in (5, 15)}


def oracle_maps(scan, src: Path, dst: Path, side: str) -> None:
    """Copy the row's maps from `src` to `dst` with the pixels more than OFF_M too near (side "near") or too far
    ("far") set to the GT depth; side "none" copies them as they are."""
    from recon.io import load_confidence_map, load_depth_map, save_depth_map

    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    shutil.copy(src / "depth.json", dst / "depth.json")
    for i, frame in enumerate(scan.frames):
        depth, gt = load_depth_map(src, frame.name), scan.depth(i)
        if depth.shape != gt.shape:
            raise SystemExit(f"{src}: maps of {depth.shape} on a scan of {gt.shape}; rerun selection at the scan's size")
        valid = np.isfinite(gt) & (gt > 0)
        off = depth - gt if side == "far" else gt - depth
        fixed = valid & (off > OFF_M) if side != "none" else np.zeros_like(valid)
        save_depth_map(dst, frame.name, np.where(fixed, gt, depth), load_confidence_map(src, frame.name))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("rows", nargs="+", type=Path, metavar="ROW_DIR")
    p.add_argument("--cache", type=Path, required=True, help="held-out scan cache of experiments/select_checkpoint.py")
    p.add_argument("--out", type=Path, required=True, help="folder for the oracle maps and meshes")
    p.add_argument("--scans", default="", help="comma list of held-out scan names (default: all)")
    args = p.parse_args(argv)

    from experiments.results_7scenes import TableOptions, mesh_scores
    from experiments.select_checkpoint import stored_maps, unculled_fscore

    wanted = set(filter(None, args.scans.split(",")))
    print("| scan | row | too near > 5 / 15 cm | too far > 5 / 15 cm | mesh F, culled / not: as predicted | "
          "near fixed | far fixed |")
    print("|---|---|---|---|---|---|---|")
    for scan_name, scan, row, gts, preds in stored_maps(args.rows, args.cache):
        if wanted and scan_name not in wanted:
            continue
        shares = error_shares(np.stack(gts), np.stack(preds))
        scores = {}
        for side in ("none", "near", "far"):  # "none": the row's own maps, fused here so its files stay untouched
            out = args.out / row.name / f"{scan_name}_{side}_fixed"
            oracle_maps(scan, row / scan_name / "estm_m2", out / "estm_m2", side)
            culled = mesh_scores(scan, out, TableOptions(), log=lambda s: None)["fscore"]
            scores[side] = f"{culled:.3f} / {unculled_fscore(out, 'estm_m2'):.3f}"
        print(f"| {scan_name} | {row.name} | {shares['near_5cm']:.1%} / {shares['near_15cm']:.1%} | "
              f"{shares['far_5cm']:.1%} / {shares['far_15cm']:.1%} | {scores['none']} | {scores['near']} | "
              f"{scores['far']} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
