"""Pick a training checkpoint on held-out data only: unseen synthetic rooms, the demo room and ICL-NUIM
(never 7-Scenes).

    python experiments/select_checkpoint.py runs/lite_v2/step_003000.pt compact --out runs/select --baselines

Each checkpoint (a file, or a shipped name such as the incumbent `compact`) runs ESTM (memory 2) on
every held-out scan through `experiments.results_7scenes.depth_table` (the same code as the 7-Scenes
table); `--baselines` adds plane sweep and independent rows for the comparison the shipping rules
need (experiments/ship_weights.py), `--hybrid` each checkpoint's hybrid row (ESTM refined by a narrow
sweep), `--mirror` the same rows with the mirrored pass. Every row's depth is also fused (TSDF, 4 cm voxels)
and scored against the fusion of the scan's GT depth: mesh precision, recall and F-score at 5 cm. "scale"
is the median prediction / GT ratio (1 = no scale bias); "edge F" whether the depth has the scene's
occluding edges (`depth.metrics.edge_counts`), "near 5 cm" the share of pixels more than 5 cm too near (what the
culled mesh score charges), "mesh F unculled" the mesh F without the protocol's visibility culling (`--rescore`
adds all three to rows scored before them). Every row
sweeps its own trained depth range (the plane sweep and independent rows the first checkpoint's).
Held-out synthetic rooms: seeds 910001 to 910004 (training rooms come from other seeds,
validation clips from 900001/900051), 30 frames at 3 fps with realistic sensor effects, 320x256;
910003 and 910004 since 2026-12-05, to dilute the demo room's swings: rows scored before lack them,
and experiments/ship_weights.py compares rows on the scans both have. `--rows-from lite-preview` starts a
fresh machine's summary from the rows a shipped file recorded when it shipped (runs/ does not always survive).
The demo room (seed 7, clean): every 4th frame, 320x240. ICL-NUIM living room 1: every 5th frame at
320x256. Writes summary.json and prints a table.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HELDOUT_SEEDS = (910001, 910002, 910003, 910004)
ICL = ROOT.parent / "shared" / "data" / "iclnuim-livingroom1"


def heldout_scans(cache: Path):
    from recon.readers import open_scan
    from recon.synthetic import SensorEffects, SynthConfig, write_synthetic_scan

    scans = {}
    for seed in HELDOUT_SEEDS:
        folder = cache / f"synthetic_{seed}"
        if not (folder / "scan.json").is_file():
            write_synthetic_scan(SynthConfig(seed=seed, frames=30, fps=3.0, width=320, height=256,
                                             effects=SensorEffects.realistic()), folder)
        scans[f"synthetic_{seed}"] = open_scan(folder)
    from apps.commands.demo import ensure_example

    scans["demo_s4"] = open_scan(ensure_example()).select(0, 4)  # the room `recon demo` shows, every 4th frame
    if ICL.is_dir():
        scans["iclnuim_s5"] = open_scan(ICL).select(0, 5).resized(320, 256)
    return scans


def stored_maps(rows: list[Path], cache: Path):
    """For each held-out scan and each selection row folder that has its ESTM maps (`ROW/<scan>/estm_m2`):
    (scan name, scan, row, GT maps, predicted maps on the GT grid), nothing recomputed."""
    from depth.metrics import on_gt_grid
    from recon.io import load_depth_map

    for scan_name, scan in heldout_scans(cache).items():
        gts = [scan.depth(i) for i in range(len(scan))]
        for row in rows:
            folder = row / scan_name / "estm_m2"
            if folder.is_dir():
                preds = [on_gt_grid(load_depth_map(folder, f.name), gt) for f, gt in zip(scan.frames, gts)]
                yield scan_name, scan, row, gts, preds


def unculled_fscore(folder: Path, row: str) -> float:
    """Mesh F of the row's fused mesh without the protocol's visibility culling: surfaces behind the GT in every
    view count too (a network that errs far is not spared them)."""
    import trimesh

    from fusion.evaluate import mesh_metrics

    meshes = [trimesh.load(folder / f"mesh_{name}.ply", process=False) for name in (row, "gt_fusion")]
    return mesh_metrics(*meshes)["fscore"]


def rescore(summary: dict, scans: dict, out: Path) -> None:
    """Edge F, the too-near share and unculled mesh F of rows scored before they existed, from the depth maps and
    meshes their run left under `out`."""
    from depth.metrics import evaluate_depth_folder
    from recon.errors import ReconError

    for key, per in summary.items():
        name, _, row = key.partition(":")
        for scan_name, scores in per.items():
            folder = out / name / scan_name / (row or name)
            missing = [k for k in ("edge_f", "near_5cm") if k not in scores]
            if missing and scan_name in scans and folder.is_dir():
                try:
                    metrics = evaluate_depth_folder(folder, scans[scan_name])
                    scores.update({k: metrics[k] for k in missing})
                except ReconError as e:  # a folder a later run overwrote with fewer frames
                    print(f"{key} {scan_name}: no {' or '.join(missing)} ({e})")
            mesh_row = row or name
            if "mesh_fscore_unculled" not in scores and (out / name / scan_name / f"mesh_{mesh_row}.ply").is_file():
                scores["mesh_fscore_unculled"] = unculled_fscore(out / name / scan_name, mesh_row)


def main(argv=None) -> int:
    from recon.keyframes import SourceConfig

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoints", nargs="*")
    p.add_argument("--out", default="runs/select")
    p.add_argument("--baselines", action="store_true", help="also run planesweep and independent (first checkpoint)")
    p.add_argument("--hybrid", action="store_true", help="also run every checkpoint's hybrid mode (ESTM refined by a narrow sweep)")
    p.add_argument("--mirror", action="store_true", help="also run ESTM with the mirrored pass (mirror_pass)")
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--precision", choices=("fp32", "bf16"), default="fp32",
                   help="network arithmetic of every row (default fp32, as every stored figure; rows of another "
                        "precision are named CHECKPOINT_bf16)")
    p.add_argument("--sources", type=int, default=SourceConfig.num_sources, metavar="N",
                   help="sources per frame (default %(default)s; rows of another count are named CHECKPOINT_sN)")
    p.add_argument("--baseline", type=float, default=SourceConfig.source_baseline, metavar="M",
                   help="ideal source translation (default %(default)s; rows of another are named CHECKPOINT_bM)")
    p.add_argument("--rows-from", nargs="+", default=[], metavar="WEIGHTS",
                   help="first add the held-out rows these shipped files record (their own, the plane sweep's, the "
                        "incumbent's; rows already in summary.json are kept), so a fresh machine can apply the shipping "
                        "rules without scoring them again")
    p.add_argument("--rescore", action="store_true",
                   help="add edge F, near_5cm and unculled mesh F to every summary row whose depth folders and meshes are "
                        "still under --out, then print")
    args = p.parse_args(argv)

    import torch

    from depth.checkpoint import trained_depth_range
    from experiments.results_7scenes import TableOptions, depth_table, mesh_scores
    from experiments.ship_weights import shipped_rows

    if args.threads:
        torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scans = heldout_scans(out / "scans")
    summary_path = out / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    modes = ("estm_m2",) + (("hybrid",) if args.hybrid else ())
    rows = modes + (("estm_mirror", "hybrid_mirror")[:len(modes)] if args.mirror else ())
    sources = SourceConfig(num_sources=args.sources, source_baseline=args.baseline).validate()
    suffix = ("" if args.precision == "fp32" else f"_{args.precision}") \
        + ("" if args.sources == SourceConfig.num_sources else f"_s{args.sources}") \
        + ("" if args.baseline == SourceConfig.source_baseline else f"_b{args.baseline:g}")
    jobs = [(Path(c).stem + suffix, c, rows) for c in args.checkpoints]
    if args.baselines and args.checkpoints:  # the plane sweep needs no weights: one folder serves every checkpoint
        jobs.append(("planesweep", args.checkpoints[0], ("planesweep",)))
        jobs.append((Path(args.checkpoints[0]).stem + "_baselines", args.checkpoints[0], ("independent",)))
    for weights in args.rows_from:
        for key, per in shipped_rows(weights).items():
            summary.setdefault(key, per)
    if args.rescore:
        rescore(summary, scans, out)
    if args.rescore or args.rows_from:
        summary_path.write_text(json.dumps(summary, indent=2))
    for name, ck, rows in jobs:
        for scan_name, scan in scans.items():
            # each checkpoint sweeps its own trained range, as the product uses it; the plane sweep the first's
            opts = TableOptions(weights=ck, rows=rows, depth_range=trained_depth_range(ck), mesh=False,
                                precision=args.precision, sources=sources)
            res = depth_table(scan, out / name / scan_name, opts, log=lambda s: print(f"{name} {scan_name}: {s}"))
            for row, m in res["rows"].items():
                key = "planesweep" if row == "planesweep" else f"{name}:{row}"
                summary.setdefault(key, {})[scan_name] = {k: m[k] for k in
                                                          ("abs_rel", "abs", "rmse", "a1", "within_5cm", "near_5cm", "edge_f", "flicker", "coverage", "abs_rel_covered",
                                                           "median_ratio", "seconds_per_frame")}
                mesh = mesh_scores(scan, out / name / scan_name, TableOptions(mesh_row=row),
                                   log=lambda s: print(f"{name} {scan_name}: {s}"))
                summary[key][scan_name].update({f"mesh_{k}": mesh[k] for k in ("prec", "recall", "fscore")})
                summary[key][scan_name]["mesh_fscore_unculled"] = unculled_fscore(out / name / scan_name, row)
            summary_path.write_text(json.dumps(summary, indent=2))
    names = list(scans)
    print("| checkpoint / row | " + " | ".join(f"{n} Abs Rel / δ<1.25 / within 5 cm / mesh F / scale" for n in names)
          + " | mean Abs Rel | mean mesh F | mean edge F | mean near 5 cm | mean mesh F unculled |")
    print("|---|" + "---|" * (len(names) + 5))
    nan = float("nan")
    for key, per in summary.items():
        cells = [f"{per[n]['abs_rel']:.4f} / {per[n]['a1']:.1%} / {per[n].get('within_5cm', nan):.1%}"
                 f" / {per[n].get('mesh_fscore', nan):.3f} / {per[n].get('median_ratio', nan):.3f}" if n in per else "-"
                 for n in names]
        scored = [n for n in names if n in per]
        mean = {k: sum(per[n].get(k, nan) for n in scored) / max(len(scored), 1)
                for k in ("abs_rel", "mesh_fscore", "edge_f", "near_5cm", "mesh_fscore_unculled")}
        print(f"| {key} | " + " | ".join(cells) + f" | {mean['abs_rel']:.4f} | {mean['mesh_fscore']:.3f} | "
              f"{mean['edge_f']:.3f} | {mean['near_5cm']:.1%} | {mean['mesh_fscore_unculled']:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
