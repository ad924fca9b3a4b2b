"""Depth filter ablation (issue 13): the same depth maps fused with the filter's parts switched on one by one.

    python experiments/filter_ablation.py --cache /tmp/filter_ablation --markdown /tmp/filter_ablation.md

Scans: the held-out rooms of checkpoint selection (`experiments.select_checkpoint.heldout_scans`: synthetic
seeds 910001/910002, the demo room, ICL-NUIM) and 7-Scenes redkitchen every 10th frame at 320x256 (the
protocol of docs/results_7scenes.md; reported, never tuned on). Depth comes once per scan and mode (ESTM
with the given weights, memory 2, the plane sweep, and on request the hybrid of the two; all over the weights'
trained range) into `--cache`
and is reused by every row and every later run with the same settings. Each row fuses the same maps
(`experiments.results_7scenes.mesh_scores`: 4 cm voxels, depth up to 4 m) and scores the mesh against the
fusion of the GT depth of the same frames: precision, recall and F at 5 cm, the share of depth pixels the
filter kept and its time, beside the depth stage's time for the same frames.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from depth.checkpoint import DEFAULT_WEIGHTS  # noqa: E402  (after the path set-up)
from fusion.filtering import NETWORK_CHECKS, FilterConfig  # noqa: E402
from fusion.mesh import MeshCleanup  # noqa: E402

SEVENSCENES = ROOT.parent / "shared" / "data" / "7scenes-redkitchen"
MODES = {"estm": "estm_m2", "planesweep": "planesweep", "hybrid": "hybrid"}  # the depth table's rows (results_7scenes)

# name -> (filter, cleanup): each row adds one part to the one before it; "+ weights" is "+ edges" with the
# consistency score as TSDF weights. Checks are spelled out: `auto` would skip them on the plane sweep.
ROWS = {
    "none": (FilterConfig(checks=()), None),
    "consistency": (FilterConfig(checks=("consistency",)), None),
    "+ edges": (FilterConfig(checks=NETWORK_CHECKS), None),
    "+ cleanup": (FilterConfig(checks=NETWORK_CHECKS), MeshCleanup(min_component_area=0.05)),
    "+ weights": (FilterConfig(checks=NETWORK_CHECKS, weights=True), None),
}
DEFAULT_ROWS = {"estm": "+ edges", "planesweep": "none", "hybrid": "none"}  # what `recon run` does by default (--filter auto)

# The rows the defaults were chosen from (docs/evaluation.md; `--rows selection --scans iclnuim_s5,synthetic_910002`):
# the first filter's thresholds (5 %, 80 degrees) against the chosen ones (10 %, 85 degrees), with and without the
# old default cleanup, and each check alone.
OLD_CLEANUP, OLD_FILTER = MeshCleanup(min_component_area=0.05), FilterConfig(checks=NETWORK_CHECKS, max_rel_diff=0.05,
                                                                                edge_max_angle=80.0)
SELECTION_ROWS = {
    "none": (FilterConfig(checks=()), None),
    "none + cleanup 0.05": (FilterConfig(checks=()), OLD_CLEANUP),
    "5 %, 80 deg + cleanup 0.05": (OLD_FILTER, OLD_CLEANUP),
    "10 %, 85 deg": (FilterConfig(checks=NETWORK_CHECKS), None),
    "10 %, 85 deg + cleanup 0.05": (FilterConfig(checks=NETWORK_CHECKS), OLD_CLEANUP),
    "10 %, 85 deg, 1 view": (FilterConfig(checks=NETWORK_CHECKS, min_views=1), None),
    "edges 85 deg alone": (FilterConfig(checks=("edges",)), None),
    "consistency 10 % alone": (FilterConfig(checks=("consistency",)), None),
}


def ablation_scans(cache: Path) -> dict:
    """The held-out scans of checkpoint selection, then 7-Scenes (when its folder is there)."""
    from experiments.select_checkpoint import heldout_scans
    from recon.readers import open_scan

    scans = heldout_scans(cache)
    if SEVENSCENES.is_dir():
        scans["7scenes_s10"] = open_scan(SEVENSCENES).select(0, 10).resized(320, 256)
    return scans


def depth_folder(scan, cache: Path, mode: str, weights: str) -> tuple[Path, float]:
    """Depth maps of one scan and mode in `cache` (computed once, then reused) and the depth stage's seconds."""
    from depth.inference import estimate_depth
    from experiments.results_7scenes import TableOptions, row_options

    row = MODES[mode]
    summary = estimate_depth(scan, cache / row, row_options(row, TableOptions(weights=weights)), resume=True)
    return cache / row, float(summary["seconds"])


def run_rows(scan, folder: Path, rows: dict, log=print) -> dict:
    """Every row (filter, cleanup[, min confidence]) on one depth folder: {row: mesh scores + filter stats}
    against the GT-depth fusion."""
    from experiments.results_7scenes import TableOptions, mesh_scores
    from fusion.mesh import load_mesh

    out_dir = folder.parent
    opts = TableOptions(mesh_row=folder.name)
    reference_path = out_dir / "mesh_gt_fusion.ply"
    reference = load_mesh(reference_path) if reference_path.is_file() else None
    results = {}
    for name, (depth_filter, cleanup, *min_confidence) in rows.items():
        log(f"  {name}")
        row_opts = dataclasses.replace(opts, depth_filter=depth_filter, cleanup=cleanup,
                                       min_confidence=min_confidence[0] if min_confidence else None)
        results[name] = mesh_scores(scan, out_dir, row_opts, log=lambda line: log(f"    {line}"), reference=reference)
        if reference is None:
            reference = load_mesh(reference_path)
    return results


def ablation(cache: Path, modes: tuple[str, ...], weights: str, rows: dict = ROWS, curve_scans: tuple[str, ...] = (),
             only: tuple[str, ...] = (), log=print) -> dict:
    """{scan: {mode: {"depth_seconds", "rows": {row: scores}[, "curve"]}}} for every ablation scan; the confidence
    curve for the network's depth of `curve_scans`."""
    results: dict = {}
    for name, scan in ablation_scans(cache).items():
        if only and name not in only:
            continue
        for mode in modes:
            t0 = time.time()
            folder, seconds = depth_folder(scan, cache / "runs" / name, mode, weights)
            log(f"{name} {mode}: {len(scan)} frames, depth {seconds:.0f} s ({time.time() - t0:.0f} s now)")
            entry = {"frames": len(scan), "depth_seconds": seconds, "rows": run_rows(scan, folder, rows, log)}
            if mode == "estm" and name in curve_scans:
                entry["curve"] = confidence_curve(scan, folder, log)
            results.setdefault(name, {})[mode] = entry
    return results


CURVE_QUANTILES = (0.0, 0.2, 0.4, 0.6, 0.8)  # thresholds at these shares of the pixels, ranked by confidence


def confidence_values(scan, folder: Path, depth_filter: FilterConfig) -> np.ndarray:
    """Every fused pixel's confidence as `depth_filter` serves it: the maps' own, else the consistency score."""
    from fusion.filtering import filtered_depth
    from fusion.tsdf import TSDFConfig

    source = filtered_depth(scan, folder, depth_filter, TSDFConfig())
    values = []
    for i in range(len(scan)):
        frame = source(i)
        values.append(frame.confidence[frame.depth_m > 0])
    return np.concatenate(values)


def depth_only(folder: Path) -> Path:
    """A sibling of `folder` linking its depth maps but not their confidence maps: the filter then serves the
    consistency score as the confidence, as it does for depth that has none."""
    from recon.io import CONFIDENCE_SUFFIX

    bare = folder.parent / f"depth_only_{folder.name}"
    bare.mkdir(exist_ok=True)
    for f in folder.iterdir():
        if f.is_file() and not f.name.endswith((CONFIDENCE_SUFFIX, ".conf.npy")) and not (bare / f.name).exists():
            (bare / f.name).symlink_to(f.resolve())
    return bare


def confidence_curve(scan, folder: Path, log=print) -> dict:
    """Mesh precision and recall as the confidence threshold rises: the network's own confidence without the
    filter and with the default filter (what `recon run` does), and the consistency score (the default filter
    on the same maps without their confidence): {curve: [{quantile, threshold, scores}]}."""
    curves = {}
    for name, depth_filter, maps in (("network", FilterConfig(checks=()), folder),
                                     ("network, filtered", FilterConfig(), folder),
                                     ("consistency", FilterConfig(), depth_only(folder))):
        values = confidence_values(scan, maps, depth_filter)
        thresholds = [None] + [float(np.quantile(values, q)) for q in CURVE_QUANTILES[1:]]
        rows = {f"{name} >= {t:.3f}" if t is not None else f"{name}: all": (depth_filter, MeshCleanup(), t)
                for t in thresholds}
        scored = run_rows(scan, maps, rows, log)
        curves[name] = [{**scored[r], "quantile": q, "min_confidence": t}
                        for q, t, r in zip(CURVE_QUANTILES, thresholds, rows)]
    return curves


def markdown(results: dict) -> str:
    """One table: a block of rows per scan and depth source, `recon run`'s default in bold."""
    lines = ["| scan | depth | filter | precision | recall | F | kept pixels | filter s | filter / depth time |",
             "|---|---|---|---|---|---|---|---|---|"]
    for scan, modes in results.items():
        for mode, entry in modes.items():
            for row, m in entry["rows"].items():
                f = m["filter"]
                share = f["seconds"] / entry["depth_seconds"] if entry["depth_seconds"] else float("nan")
                label = f"**{row}** (default)" if DEFAULT_ROWS.get(mode) == row else row
                lines.append(f"| {scan} | {mode} | {label} | {m['prec']:.3f} | {m['recall']:.3f} | {m['fscore']:.3f} | "
                             f"{f['kept_share']:.1%} | {f['seconds']:.1f} | {share:.1%} |")
    return "\n".join(lines)


def curve_markdown(results: dict) -> str:
    """The confidence curves: mesh precision / recall as the threshold keeps fewer pixels."""
    lines = ["| scan | confidence | pixels kept by the threshold | threshold | precision | recall | F |",
             "|---|---|---|---|---|---|---|"]
    for scan, modes in results.items():
        for name, points in modes.get("estm", {}).get("curve", {}).items():
            for p in points:
                threshold = "-" if p["min_confidence"] is None else f"{p['min_confidence']:.3f}"
                lines.append(f"| {scan} | {name} | {1 - p['quantile']:.0%} | {threshold} | {p['prec']:.3f} | "
                             f"{p['recall']:.3f} | {p['fscore']:.3f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cache", default="/tmp/filter_ablation", help="depth maps and meshes (reused when present)")
    p.add_argument("--weights", default=DEFAULT_WEIGHTS, help=f"network weights (default {DEFAULT_WEIGHTS})")
    p.add_argument("--modes", default="estm,planesweep", help="depth sources, comma-separated (estm, planesweep, hybrid)")
    p.add_argument("--rows", choices=("ablation", "selection", "curve"), default="ablation",
                   help="ablation: the table of docs/evaluation.md; selection: the rows the defaults were chosen "
                        "from; curve: only the confidence curves")
    p.add_argument("--scans", default="", help="only these scans, comma-separated (default: all)")
    p.add_argument("--curve", default="iclnuim_s5,synthetic_910001,7scenes_s10",
                   help="scans whose ESTM depth also gets the confidence curve, comma-separated ('' for none)")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    p.add_argument("--json", default=None, metavar="PATH")
    p.add_argument("--markdown", default=None, metavar="PATH")
    args = p.parse_args(argv)

    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    modes = tuple(m.strip() for m in args.modes.split(",") if m.strip())
    curve_scans = tuple(c.strip() for c in args.curve.split(",") if c.strip())
    only = tuple(s.strip() for s in args.scans.split(",") if s.strip())
    rows = {"ablation": ROWS, "selection": SELECTION_ROWS, "curve": {}}[args.rows]
    results = ablation(Path(args.cache), modes, args.weights, rows=rows, curve_scans=curve_scans, only=only)
    table = markdown(results) + ("\n\n" + curve_markdown(results) if curve_scans else "")
    print(table)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2, default=float))
    if args.markdown:
        Path(args.markdown).write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
