"""Inference-time ablations of trained weights on held-out data (never 7-Scenes): how many source
frames, how long a memory.

    python experiments/depth_ablation.py --weights compact --out runs/ablation [--rows 3,4] [--threads 1]

Each row runs ESTM with one change on every held-out scan of experiments/select_checkpoint.py
(unseen synthetic rooms, the demo room, ICL-NUIM), scores the depth (Abs Rel, delta<1.25, flicker)
and the fused mesh (F-score at 5 cm against the fusion of the GT depth), and prints one Markdown
table with the means over the scans. Writes summary.json.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# row name -> (sources, memory)
ROWS = {"2 sources, memory 2 (default)": (2, 2), "3 sources, memory 2": (3, 2), "4 sources, memory 2": (4, 2),
        "2 sources, memory 0 (independent)": (2, 0), "2 sources, memory 1": (2, 1), "2 sources, memory 3": (2, 3)}


def score_row(scan, folder: Path, sources: int, memory: int, weights: str) -> dict:
    from depth.inference import estimate_depth
    from depth.metrics import evaluate_depth_folder
    from depth.options import DepthOptions
    from fusion.evaluate import mesh_metrics
    from fusion.tsdf import TSDFConfig, fuse_scan
    from recon.keyframes import SourceConfig

    opts = DepthOptions(mode="estm", weights=weights, memory_size=memory, sources=SourceConfig(num_sources=sources))
    summary = estimate_depth(scan, folder, opts, resume=True)
    m = evaluate_depth_folder(folder, scan, 1e-3, 10.0)
    fusion = TSDFConfig(device="cpu")
    reference = fuse_scan(scan, "gt", fusion)
    mesh = mesh_metrics(fuse_scan(scan, folder, fusion), reference, scan=scan)
    return {"abs_rel": m["abs_rel"], "a1": m["a1"], "flicker": m["flicker"], "mesh_fscore": mesh["fscore"],
            "seconds_per_frame": summary["seconds_per_frame"]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default="compact")
    p.add_argument("--out", default="runs/ablation")
    p.add_argument("--rows", default=None, help="comma-separated row numbers (1-based) to run (default all)")
    p.add_argument("--threads", type=int, default=None)
    args = p.parse_args(argv)
    import torch

    from experiments.select_checkpoint import heldout_scans

    if args.threads:
        torch.set_num_threads(args.threads)
    out = Path(args.out)
    scans = heldout_scans(out / "scans")
    picked = [list(ROWS)[int(i) - 1] for i in args.rows.split(",")] if args.rows else list(ROWS)
    results = {row: {name: score_row(scan, out / name / f"s{ROWS[row][0]}_m{ROWS[row][1]}", *ROWS[row], args.weights)
                     for name, scan in scans.items()} for row in picked}
    (out / "summary.json").write_text(json.dumps(results, indent=2))
    keys = ("abs_rel", "a1", "flicker", "mesh_fscore", "seconds_per_frame")
    print(f"weights {args.weights}; means over {', '.join(scans)}")
    print("| row | Abs Rel | δ<1.25 | flicker | mesh F | s/frame |\n|---|---|---|---|---|---|")
    for row, per in results.items():
        mean = {k: statistics.mean(v[k] for v in per.values()) for k in keys}
        print(f"| {row} | {mean['abs_rel']:.4f} | {mean['a1']:.1%} | {mean['flicker']:.4f} | "
              f"{mean['mesh_fscore']:.3f} | {mean['seconds_per_frame']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
