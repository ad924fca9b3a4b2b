"""`--mode hybrid` against its alternatives on the held-out scans: is a narrow sweep around the network's
depth the better way to make it precise enough for 5 cm meshes?

    python experiments/guided_sweep.py --weights compact-preview --cache /tmp/guided --threads 2 \
        [--band 0.2 --steps 17] [--min-score 0.5] [--agreement]

Rows per held-out scan (`experiments.select_checkpoint.heldout_scans`, never 7-Scenes): ESTM (memory 2);
`sweep_merge`, the earlier hybrid (the full plane sweep's depth where it kept a pixel, ESTM's elsewhere);
and the hybrid's refinement (`depth.hybrid.refine_frames`: each pixel tries depths within a factor
1 +- band of ESTM's, scored by the plane sweep's NCC, and takes the best where the match reaches
`--min-score`; with `--agreement` only where the sources' own best depths agree as well), run on
ESTM's stored maps so that variants cost no network pass. Columns: Abs Rel, within 5 cm, mesh
precision / recall / F at 5 cm (unfiltered, against the GT-depth fusion), the share of pixels the
narrow sweep moved. Results in docs/depth.md, "Hybrid depth".
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def sweep_merge(scan, network: Path, sweep: Path, out: Path) -> None:
    """The earlier hybrid, for comparison: the full sweep's depth where it kept a pixel, the network's elsewhere."""
    from recon.io import load_depth_map, save_depth_map

    out.mkdir(parents=True, exist_ok=True)
    shutil.copy(network / "depth.json", out / "depth.json")
    for name in scan.names:
        net = load_depth_map(network, name)
        swept = cv2.resize(load_depth_map(sweep, name), net.shape[::-1], interpolation=cv2.INTER_NEAREST)
        save_depth_map(out, name, np.where(swept > 0, swept, net).astype(np.float32))


def refine_stored(scan, network: Path, out: Path, opts) -> float:
    """`depth.hybrid.refine_frames` over ESTM's stored maps (millimetre PNGs; the mode refines them in
    memory, which moved no figure of docs/depth.md by more than 0.002) into `out`. Returns seconds per frame."""
    import time

    from depth.hybrid import refine_frames
    from depth.options import FrameDepth
    from recon.io import load_confidence_map, load_depth_map, save_depth_map

    summary = json.loads((network / "depth.json").read_text())
    index = {n: i for i, n in enumerate(scan.names)}
    stored = (FrameDepth(index[f["name"]], f["name"], load_depth_map(network, f["name"]),
                         load_confidence_map(network, f["name"]), [index[s] for s in f["sources"]])
              for f in summary["frames"])
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    for frame in refine_frames(scan, stored, opts):
        save_depth_map(out, frame.name, frame.depth, frame.confidence)
    seconds = (time.perf_counter() - started) / len(summary["frames"])
    (out / "depth.json").write_text(json.dumps({**summary, "mode": "hybrid (from stored ESTM maps)"}))
    return seconds


def refined_share(scan, network: Path, hybrid: Path) -> float:
    """Share of the hybrid's pixels whose depth the narrow sweep moved off the network's."""
    from recon.io import load_depth_map

    return float(np.mean([(load_depth_map(hybrid, n) != load_depth_map(network, n)).mean() for n in scan.names]))


def score(scan, out_dir: Path, row: str, weights: str) -> dict:
    from depth.checkpoint import trained_depth_range
    from depth.metrics import evaluate_depth_folder
    from experiments.results_7scenes import TableOptions, mesh_scores
    from fusion.filtering import FilterConfig
    from fusion.mesh import load_mesh

    lo, hi = trained_depth_range(weights)
    depth = evaluate_depth_folder(out_dir / row, scan, lo, hi)
    ref_path = out_dir / "mesh_gt_fusion.ply"
    reference = load_mesh(ref_path) if ref_path.is_file() else None
    mesh = mesh_scores(scan, out_dir, TableOptions(mesh_row=row, depth_filter=FilterConfig(checks=())),
                       reference=reference, log=lambda s: None)
    return {"abs_rel": depth["abs_rel"], "within_5cm": depth.get("within_5cm", float("nan")),
            "prec": mesh["prec"], "recall": mesh["recall"], "F": mesh["fscore"]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default="compact-preview")
    p.add_argument("--cache", default="/tmp/guided")
    p.add_argument("--band", type=float, default=0.5)
    p.add_argument("--steps", type=int, default=33)
    p.add_argument("--agreement", action="store_true", help="refine only where the sources agree (refine_agreement)")
    p.add_argument("--min-score", type=float, default=0.3, help="NCC a refined pixel's match needs (refine_min_score)")
    p.add_argument("--scans", default="")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    from depth.options import PlaneSweepOptions
    from experiments.filter_ablation import depth_folder
    from experiments.select_checkpoint import heldout_scans

    cache = Path(args.cache)
    results = {}
    for name, scan in heldout_scans(cache).items():
        if args.scans and name not in args.scans.split(","):
            continue
        run = cache / "runs" / name
        net, _ = depth_folder(scan, run, "estm", args.weights)
        sweep, _ = depth_folder(scan, run, "planesweep", args.weights)
        sweep_merge(scan, net, sweep, run / "sweep_merge")
        tag = (f"hybrid_b{args.band:g}_s{args.steps}" + ("_agree" if args.agreement else "")
               + (f"_score{args.min_score:g}" if args.min_score != PlaneSweepOptions.refine_min_score else ""))
        opts = PlaneSweepOptions(refine_band=args.band, refine_steps=args.steps, refine_agreement=args.agreement,
                                 refine_min_score=args.min_score)
        refine_seconds = refine_stored(scan, net, run / tag, opts)
        rows = {}
        for row in (net.name, "sweep_merge", tag):
            rows[row] = score(scan, run, row, args.weights)
            rows[row]["refined"] = refined_share(scan, net, run / tag) if row == tag else 0.0
            m = rows[row]
            print(f"{name} {row:24s} abs_rel {m['abs_rel']:.4f} within5 {m['within_5cm']:.3f} "
                  f"P {m['prec']:.3f} R {m['recall']:.3f} F {m['F']:.3f} refined {m['refined']:.1%}", flush=True)
        rows[tag]["refine_seconds_per_frame"] = refine_seconds
        results[name] = rows
    (cache / f"summary_{tag}.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
