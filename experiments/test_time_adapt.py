"""Does adapting the network to the scan itself help? `recon depth --adapt-steps` (`depth.adapt`) on held-out scans.

    python experiments/test_time_adapt.py --weights compact --cache runs/select_k35/scans --out runs/tta --steps 60

For each held-out selection scan, ESTM (memory 2; or `--mode hybrid`) runs as shipped and after test-time
adaptation (the `estm_m2` and `estm_adapted` rows of `experiments.results_7scenes`, or `hybrid` and
`hybrid_adapted`), each scored as selection scores it: Abs Rel, mesh F culled and unculled. The GT depth is
read only by the scores. `--data FOLDER --stride N` runs one other scan instead (every N-th frame at
320x256): how 7-Scenes is reported with settings fixed on the held-out scans, never chosen on it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

ROWS = {"estm": {"as shipped": "estm_m2", "adapted": "estm_adapted"},
        "hybrid": {"as shipped": "hybrid", "adapted": "hybrid_adapted"}}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default="compact")
    p.add_argument("--cache", type=Path, default=Path("runs/select_k35/scans"))
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scans", default="", help="comma list of scan names (default: all)")
    p.add_argument("--steps", type=int, default=60)
    p.add_argument("--lr", type=float, default=1e-5)
    p.add_argument("--seed", type=int, default=0, help="order of the adaptation clips")
    p.add_argument("--anchor", type=float, default=0.0, help="weight of the pull back to the unadapted depth")
    p.add_argument("--precision", default="fp32", choices=("fp32", "bf16"))
    p.add_argument("--mode", default="estm", choices=tuple(ROWS), help="the depth mode run as shipped and adapted")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--data", type=Path, default=None, help="one scan folder instead of the held-out scans")
    p.add_argument("--stride", type=int, default=10, help="with --data: every N-th frame")
    args = p.parse_args(argv)

    import torch

    from depth.checkpoint import trained_depth_range
    from depth.options import AdaptOptions
    from experiments.results_7scenes import TableOptions, depth_table, mesh_scores
    from experiments.select_checkpoint import heldout_scans, unculled_fscore
    from recon.readers import open_scan

    torch.set_num_threads(args.threads)
    wanted = set(filter(None, args.scans.split(",")))
    pair = ROWS[args.mode]
    opts = TableOptions(weights=args.weights, rows=tuple(pair.values()), depth_range=trained_depth_range(args.weights),
                        precision=args.precision, mesh=False,
                        adapt=AdaptOptions(steps=args.steps, lr=args.lr, seed=args.seed, anchor=args.anchor))
    scans = {args.data.name: open_scan(args.data).select(0, args.stride).resized(320, 256)} if args.data \
        else heldout_scans(args.cache)
    results = {}
    for scan_name, scan in scans.items():
        if wanted and scan_name not in wanted:
            continue
        folder = args.out / scan_name
        rows = depth_table(scan, folder, opts, log=lambda s: print(f"{scan_name}: {s}", flush=True))["rows"]
        for name, row in pair.items():
            mesh = mesh_scores(scan, folder, TableOptions(mesh_row=row), log=lambda s: None)
            results.setdefault(scan_name, {})[name] = {
                "abs_rel": rows[row]["abs_rel"], "mesh_f": mesh["fscore"], "mesh_f_unculled": unculled_fscore(folder, row),
                "seconds_per_frame": rows[row]["seconds_per_frame"]}
            r = results[scan_name][name]
            print(f"{scan_name} {name}: Abs Rel {r['abs_rel']:.4f}  mesh F {r['mesh_f']:.3f} / "
                  f"{r['mesh_f_unculled']:.3f} unculled", flush=True)
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "summary.json").write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
