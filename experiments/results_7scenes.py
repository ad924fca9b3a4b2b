"""Zero-shot results table of the depth stage on one real RGB-D sequence (issue 6).

One function runs every depth mode on the same frames (plane sweep, independent, joint,
ESTM with memory 1/2/3, optionally a concat-fusion checkpoint), scores each with the
`recon eval depth` machinery (`depth.metrics.evaluate_depth_folder`), fuses the ESTM depth and
the ground-truth depth of the same frames with the same TSDF settings and scores the first
against the second (`recon eval mesh` machinery, `fusion.evaluate.mesh_metrics`).
`examples/evaluate_7scenes.py` is the command-line front; the figures in
docs/results_7scenes.md come from it. Nothing here looks at the ground truth before scoring:
the depth range is a fixed input (the range the network was trained on, by default).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

from depth.checkpoint import DEFAULT_WEIGHTS
from depth.options import AdaptOptions
from fusion.filtering import FilterConfig
from fusion.mesh import MeshCleanup
from recon.errors import ReconError
from recon.keyframes import SourceConfig
from recon.scan import Scan

# ESTDepth (Long et al., CVPR 2021), Table 2: 7-Scenes, zero-shot after ScanNet training.
PAPER_7SCENES = {"abs_rel": 0.1465, "abs": 0.2528, "sq_rel": 0.0729, "rmse": 0.3382, "a1": 0.8036}

COLUMNS = (("abs_rel", "Abs Rel", "{:.4f}"), ("abs", "Abs", "{:.4f}"), ("sq_rel", "Sq Rel", "{:.4f}"),
           ("rmse", "RMSE", "{:.4f}"), ("a1", "δ<1.25", "{:.2%}"), ("within_5cm", "within 5 cm", "{:.1%}"),
           ("near_5cm", "over 5 cm near", "{:.1%}"), ("edge_f", "edge F", "{:.3f}"),
           ("mae_std", "mae_std", "{:.4f}"),
           ("flicker", "flicker", "{:.4f}"), ("coverage", "coverage", "{:.1%}"),
           ("abs_rel_covered", "Abs Rel (covered px)", "{:.4f}"),
           ("seconds_per_frame", "s/frame", "{:.2f}"))

DEFAULT_ROWS = ("planesweep", "independent", "joint", "estm_m1", "estm_m2", "estm_m3")


@dataclass
class TableOptions:
    """What to run. `depth_range` is the sweep range (metres); `eval_range` the scoring range."""

    weights: str = DEFAULT_WEIGHTS
    concat_weights: str | None = None  # a checkpoint trained with fusion="concat": adds an `estm concat` row
    rows: tuple[str, ...] = DEFAULT_ROWS
    depth_range: tuple[float, float] | None = None  # None: the weights' trained range (every row alike)
    eval_range: tuple[float, float] = (1e-3, 10.0)
    size: tuple[int, int] = (320, 256)
    device: str = "cpu"
    precision: str = "fp32"  # every stored figure and the shipping rules' rows are fp32 (bf16 moves Abs Rel ~0.003)
    sources: SourceConfig = field(default_factory=SourceConfig)  # how many sources each frame gets, and how far
    mesh: bool = True
    mesh_row: str = "estm_m2"
    mesh_baselines: tuple[str, ...] = ("planesweep", "hybrid", "estm_mirror", "hybrid_mirror", "estm_adapted",
                                       "hybrid_adapted")  # also fused and scored, when run
    voxel_size: float = 0.04
    mesh_depth_max: float = 4.0
    depth_filter: FilterConfig = field(default_factory=FilterConfig)  # what `recon run` fuses with by default
    cleanup: MeshCleanup | None = field(default_factory=MeshCleanup)
    min_confidence: float | None = None  # fusion drops depth below this confidence (the filter's, when it checks)
    resume: bool = True
    adapt: AdaptOptions = AdaptOptions(steps=60)  # the `*_adapted` rows' test-time adaptation (`depth.adapt`)
    extra: dict = field(default_factory=dict)


def row_options(row: str, opts: TableOptions):
    """The DepthOptions of a table row name. Every row sweeps the same range: the weights' trained one
    unless `opts.depth_range` says otherwise."""
    from depth.checkpoint import trained_depth_range
    from depth.options import DepthOptions

    rng = tuple(opts.depth_range) if opts.depth_range else trained_depth_range(opts.weights)
    common = dict(depth_range=rng, device=opts.device, precision=opts.precision, sources=opts.sources)
    if row == "planesweep":
        return DepthOptions(mode="planesweep", **common)
    if row in ("independent", "joint"):
        return DepthOptions(mode=row, weights=opts.weights, **common)
    if row in ("hybrid", "hybrid_mirror", "hybrid_adapted"):
        return DepthOptions(mode="hybrid", weights=opts.weights, mirror_pass=row == "hybrid_mirror",
                            adapt=opts.adapt if row == "hybrid_adapted" else AdaptOptions(), **common)
    if row == "estm_mirror":
        return DepthOptions(mode="estm", weights=opts.weights, mirror_pass=True, **common)
    if row.startswith("estm_m"):
        return DepthOptions(mode="estm", weights=opts.weights, memory_size=int(row[len("estm_m"):]), **common)
    if row == "estm_adapted":
        return DepthOptions(mode="estm", weights=opts.weights, adapt=opts.adapt, **common)
    if row == "estm_concat":
        return DepthOptions(mode="estm", weights=opts.concat_weights, **common)
    raise ValueError(f"unknown table row {row!r}")


def label(row: str) -> str:
    named = {"estm_concat": "estm, concat fusion (memory 2)", "estm_mirror": "estm (memory 2), mirrored pass",
             "hybrid_mirror": "hybrid, mirrored pass", "estm_adapted": "estm (memory 2), adapted to the scan",
             "hybrid_adapted": "hybrid, adapted to the scan"}
    if row not in named and row.startswith("estm_m"):
        return f"estm (memory {row[len('estm_m'):]})"
    return named.get(row, row)


def depth_table(scan: Scan, out_dir: str | Path, opts: TableOptions = TableOptions(),
                log: Callable[[str], None] = print) -> dict:
    """Run every row on `scan` (already selected and resized), score it; meshes too. Returns a JSON-able dict."""
    from depth.inference import estimate_depth
    from depth.metrics import evaluate_depth_folder

    out_dir = Path(out_dir)
    rows = list(opts.rows) + (["estm_concat"] if opts.concat_weights else [])
    results: dict = {"frames": len(scan), "names": [scan.names[0], scan.names[-1]], "size": list(opts.size),
                     "depth_range": list(row_options("planesweep", opts).depth_range), "eval_range": list(opts.eval_range),
                     "weights": opts.weights, "rows": {}, **opts.extra}
    for row in rows:
        depth_opts = row_options(row, opts)
        t0 = time.time()
        summary = estimate_depth(scan, out_dir / row, depth_opts, resume=opts.resume)
        metrics = evaluate_depth_folder(out_dir / row, scan, *opts.eval_range)
        metrics.pop("per_frame", None)
        metrics["abs_rel_covered"] = covered_abs_rel(out_dir / row, scan, *opts.eval_range)
        metrics["seconds_per_frame"] = summary.get("seconds_per_frame", float("nan"))
        metrics["skipped"] = len(summary.get("skipped", []))
        results["rows"][row] = metrics
        log(f"{label(row):32s} abs_rel {metrics['abs_rel']:.4f}  a1 {metrics['a1']:.3f}  "
            f"flicker {metrics['flicker']:.4f}  {metrics['seconds_per_frame']:.2f} s/frame  ({time.time() - t0:.0f} s)")
    if opts.mesh and opts.mesh_row in results["rows"]:
        results["mesh"] = mesh_scores(scan, out_dir, opts, log)
        results["mesh_baselines"] = {row: mesh_scores(scan, out_dir, replace(opts, mesh_row=row), log)
                                     for row in opts.mesh_baselines if row in results["rows"]}
    return results


def covered_abs_rel(pred_dir: Path, scan: Scan, min_depth: float, max_depth: float) -> float:
    """Abs Rel on the pixels that have a prediction only (the protocol's Abs Rel counts holes as the
    lower bound): tells a sparse method's accuracy apart from its coverage."""
    import numpy as np

    from depth.metrics import depth_metrics, on_gt_grid
    from recon.io import load_depth_map

    values = []
    for i in range(len(scan)):
        gt = scan.depth(i)
        pred = on_gt_grid(load_depth_map(pred_dir, scan.frames[i].name), gt)
        m = depth_metrics(pred, np.where(pred > 0, gt, 0).astype(np.float32), min_depth, max_depth)
        if m is not None:
            values.append(m["abs_rel"])
    return float(np.mean(values)) if values else float("nan")


def mesh_scores(scan: Scan, out_dir: Path, opts: TableOptions, log: Callable[[str], None] = print,
                reference=None) -> dict:
    """Fuse the predicted depth of `opts.mesh_row` (through `opts.depth_filter`, cleaned with `opts.cleanup`) and
    score it against `reference` (a mesh), by default the fusion of the GT depth of the same frames."""
    from fusion.evaluate import mesh_metrics
    from fusion.filtering import filtered_depth
    from fusion.tsdf import TSDFConfig, fuse_scan

    cfg = TSDFConfig(voxel_size=opts.voxel_size, depth_max=opts.mesh_depth_max, device="cpu")
    t0 = time.time()
    if reference is None:
        reference = fuse_scan(scan, "gt", cfg)
        reference.export(out_dir / "mesh_gt_fusion.ply")
    source = filtered_depth(scan, out_dir / opts.mesh_row, opts.depth_filter, cfg)
    try:
        pred = fuse_scan(scan, source, replace(cfg, min_confidence=opts.min_confidence), cleanup=opts.cleanup)
    except ReconError as exc:  # no depth survived (a sparse method on few frames): nothing reconstructed
        log(f"mesh ({label(opts.mesh_row)}): {exc}")
        return {"acc": math.nan, "comp": math.nan, "chamfer": math.nan, "prec": 0.0, "recall": 0.0, "fscore": 0.0,
                "row": opts.mesh_row, "empty": True, "filter": source.stats.as_dict()}
    pred.export(out_dir / f"mesh_{opts.mesh_row}.ply")
    m = mesh_metrics(pred, reference, scan=scan)
    m.update({"row": opts.mesh_row, "voxel_size": opts.voxel_size, "depth_max": opts.mesh_depth_max,
              "filter": source.stats.as_dict()})
    log(f"mesh ({label(opts.mesh_row)}): acc {m['acc']:.4f} m  comp {m['comp']:.4f} m  "
        f"prec {m['prec']:.3f}  recall {m['recall']:.3f}  F {m['fscore']:.3f}  "
        f"kept {m['filter']['kept_share']:.1%} of the depth  ({time.time() - t0:.0f} s)")
    return m


def _fmt(fmt: str, v) -> str:
    return fmt.format(v) if isinstance(v, (int, float)) and math.isfinite(v) else "-"


def markdown_table(results: dict, paper: bool = True) -> str:
    """The depth table (and the mesh line) as Markdown."""
    head = "| method | " + " | ".join(c[1] for c in COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(COLUMNS) + 1)]
    for row, m in results["rows"].items():
        lines.append(f"| {label(row)} | " + " | ".join(_fmt(f, m.get(k)) for k, _, f in COLUMNS) + " |")
    if paper:
        lines.append("| *paper, ESTM (ScanNet-trained, zero-shot)* | "
                     + " | ".join(_fmt(f, PAPER_7SCENES.get(k)) for k, _, f in COLUMNS) + " |")
    return "\n".join(lines)


def mesh_markdown(mesh: dict, baselines: dict | None = None) -> str:
    """The mesh scores as Markdown: the main row, then any baseline rows."""
    lines = ["| mesh | accuracy (m) | completeness (m) | chamfer (m) | precision @5 cm | recall @5 cm | F-score @5 cm |",
             "|---|---|---|---|---|---|---|"]
    for m in [mesh, *(baselines or {}).values()]:
        lines.append(f"| {label(m['row'])} fusion vs GT-depth fusion | {m['acc']:.4f} | {m['comp']:.4f} | "
                     f"{m['chamfer']:.4f} | {m['prec']:.3f} | {m['recall']:.3f} | {m['fscore']:.3f} |")
    return "\n".join(lines)


def write_results(results: dict, path: str | Path) -> None:
    Path(path).write_text(json.dumps(results, indent=2, default=float))
