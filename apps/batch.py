"""Batch runs: every scan of a dataset through the pipeline, on a local process pool or on Ray.

One run folder per scan under the output folder, then a summary (CSV, JSON, HTML index)
with each scan's status and metrics and their means. A scan whose report already exists
for the same options is skipped; a scan that fails is recorded with its reason and never
stops the others.
"""
from __future__ import annotations

import csv
import dataclasses
import html
import io
import json
import logging
import math
import os
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Callable, Iterable
from urllib.parse import quote

from recon.errors import ReconError
from recon.io import check_file_name, write_bytes_atomic, write_json_atomic
from apps.pipeline import STAGES, VIDEO_SUFFIXES, Pipeline, RunConfig

log = logging.getLogger("recon")

RAY_LOG_DRAIN_S = 1.0  # how long the workers' last lines get to reach the driver before Ray shuts down
SUMMARY_KEYS = (("depth", "abs_rel"), ("depth", "a1"), ("temporal", "flicker"), ("mesh", "fscore"),
                ("mesh", "acc"), ("mesh", "comp"), ("poses", "ate_rmse"))


def discover_inputs(dataset: str | Path) -> list[Path]:
    """Scans under a folder (each sub-folder a reader recognises, or a video file), or the paths in a list file."""
    from recon.readers import detect_format

    dataset = Path(dataset)
    if dataset.is_file():
        lines = [ln.strip() for ln in dataset.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
        paths = [(dataset.parent / ln) if not Path(ln).is_absolute() else Path(ln) for ln in lines]
        if not paths:
            raise ReconError(f"{dataset}: the list file names no scan")
        return paths
    if not dataset.is_dir():
        raise ReconError(f"{dataset}: no such folder or list file")
    found = []
    for child in sorted(dataset.iterdir()):
        if child.name.startswith("."):
            continue
        if child.is_file() and child.suffix.lower() in VIDEO_SUFFIXES:
            found.append(child)
        elif child.is_dir():
            try:
                detect_format(child)
                found.append(child)
            except ReconError:
                log.info("batch: %s is not a scan, skipped", child)
    if not found:
        raise ReconError(f"{dataset}: no scan found (sub-folders in a known format, or video files)")
    return found


def run_one(config: RunConfig) -> dict:
    """Run (or resume) one scan; never raises: failures come back as a record with the reason."""
    name = Path(config.out).name
    started = time.perf_counter()
    try:
        report_path = Path(config.out) / "report.json"
        pipeline = Pipeline(config)
        pipeline._load_state()
        if report_path.is_file() and all(pipeline.is_current(s) for s in STAGES):  # each stage's fingerprint
            return {"name": name, "status": "skipped", "seconds": 0.0, "report": json.loads(report_path.read_text())}
        report = pipeline.run()
        return {"name": name, "status": "done", "seconds": time.perf_counter() - started, "report": report}
    except ReconError as exc:
        return {"name": name, "status": "failed", "seconds": time.perf_counter() - started, "error": str(exc)}
    except Exception as exc:  # a bug in one scan's run must not take the batch down
        last = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return {"name": name, "status": "failed", "seconds": time.perf_counter() - started, "error": last}


def _no_token_notice(record: logging.LogRecord) -> bool:
    """Ray turns on token authentication for a local instance and warns that it did: keep it, drop the notice."""
    return "Token authentication is enabled" not in record.getMessage()


def scan_threads(cpus_per_scan: float | None, workers: int) -> int:
    """Threads each scan's process computes with: its share of the cores (`--cpus-per-scan`, or the cores
    over `--workers`), so scans running at once do not oversubscribe the machine, and a scan gets the same
    thread count, hence the same floating-point sums, under either engine."""
    if cpus_per_scan is None:
        return max(1, (os.cpu_count() or 1) // max(1, workers))
    return max(1, int(cpus_per_scan))


def limit_threads(threads: int) -> None:
    """torch, OpenCV and OpenMP (Open3D reads OMP_NUM_THREADS when it first runs in parallel) in this worker."""
    os.environ["OMP_NUM_THREADS"] = str(threads)
    import cv2
    import torch

    torch.set_num_threads(threads)
    cv2.setNumThreads(threads)


def run_one_logged(config: RunConfig, level: int = logging.INFO, threads: int = 1) -> dict:
    """`run_one` in a worker process (a Ray task) with `threads` threads: the pipeline's stage lines go to the
    worker's stderr, which Ray forwards to the driver prefixed by the task's name."""
    limit_threads(threads)
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(message)s"))
    recon_log = logging.getLogger("recon")
    recon_log.handlers[:] = [handler]
    recon_log.setLevel(level)
    recon_log.propagate = False
    return run_one(config)


def _configs(inputs: Iterable[Path], out: Path, template: RunConfig) -> list[RunConfig]:
    names: set[str] = set()
    configs = []
    for path in inputs:
        resolved = path.resolve()  # `scans/room/..` names the folder it is, not `..`
        name = check_file_name(resolved.stem if resolved.is_file() else resolved.name, f"{path}: scan name")
        while name in names:
            name += "_"
        names.add(name)
        configs.append(dataclasses.replace(template, input=dataclasses.replace(template.input, path=str(path)),
                                           out=str(out / name)))
    return configs


def run_local(configs: list[RunConfig], workers: int, threads: int | None,
              on_result: Callable[[dict], None]) -> list[dict]:
    """A process pool on this machine (one scan per process with `threads` threads); one worker runs the
    scans in this process (None: with its threads as they are)."""
    results = []
    if workers <= 1:
        if threads is not None:
            limit_threads(threads)
        for c in configs:
            results.append(run_one(c))
            on_result(results[-1])
        return results
    import multiprocessing

    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                             initializer=limit_threads, initargs=(threads,)) as pool:
        futures = [pool.submit(run_one, c) for c in configs]
        for fut in as_completed(futures):
            results.append(fut.result())
            on_result(results[-1])
    return results


def run_ray(configs: list[RunConfig], address: str | None, cpus_per_scan: float | None, gpus_per_scan: float,
            on_result: Callable[[dict], None]) -> list[dict]:
    """Ray tasks with CPU/GPU requests, on a local Ray instance or the cluster at `address`."""
    # Ray merges lines of different workers that are alike but for words with digits (every scan's
    # `fusion: done in 3.1 s`) and holds the repeats back for 5 s: one scan's line stood for all, and lines
    # held at shutdown were lost. Each scan's own lines matter here. Ray reads this when first imported.
    os.environ.setdefault("RAY_DEDUP_LOGS", "0")
    try:
        import ray
    except ImportError:
        raise ReconError("--engine ray needs Ray: pip install 'recon-est[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        notices = logging.getLogger("ray._private.authentication.authentication_token_setup")
        if _no_token_notice not in notices.filters:
            notices.addFilter(_no_token_notice)
        ray.init(address=address, include_dashboard=False, log_to_driver=True, ignore_reinit_error=True,
                 logging_level=logging.WARNING)
    try:
        cpus = 1.0 if cpus_per_scan is None else cpus_per_scan
        task = ray.remote(num_cpus=cpus, num_gpus=gpus_per_scan, max_retries=0)(run_one_logged)
        threads = scan_threads(cpus, 1)
        level = logging.getLogger("recon").getEffectiveLevel()
        # Named after its scan, a task's forwarded lines read `(scan pid=…) depth: done in 3.1 s`.
        pending = [task.options(name=Path(c.out).name).remote(c, level, threads) for c in configs]
        results = []
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            results.append(ray.get(done[0]))
            on_result(results[-1])
        return results
    finally:
        if started_here:
            time.sleep(RAY_LOG_DRAIN_S)  # forwarded lines still in flight are dropped by shutdown (ray#31931)
            ray.shutdown()


def write_summary(results: list[dict], out: Path) -> dict:
    """summary.json, summary.csv and index.html across scans, with means over the scans that have each figure."""
    rows = []
    for r in sorted(results, key=lambda r: r["name"]):
        row = {"name": r["name"], "status": r["status"], "seconds": round(r["seconds"], 2), "error": r.get("error", "")}
        report = r.get("report", {})
        for section, key in SUMMARY_KEYS:
            row[f"{section}.{key}"] = report.get(section, {}).get(key)
        rows.append(row)
    means = {}
    for section, key in SUMMARY_KEYS:
        vals = [r[f"{section}.{key}"] for r in rows if isinstance(r[f"{section}.{key}"], (int, float))
                and math.isfinite(r[f"{section}.{key}"])]
        means[f"{section}.{key}"] = sum(vals) / len(vals) if vals else None
    counts = {s: sum(r["status"] == s for r in rows) for s in ("done", "skipped", "failed")}
    summary = {"scans": rows, "mean": means, "counts": counts}
    write_json_atomic(out / "summary.json", summary)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]) if rows else ["name"])
    writer.writeheader()
    writer.writerows(rows)
    write_bytes_atomic(out / "summary.csv", buf.getvalue().encode())
    head = "".join(f"<th>{html.escape(k)}</th>" for k in (rows[0] if rows else {}))
    body = []
    for r in rows:
        cells = []
        for k, v in r.items():
            text = f"{v:.4f}" if isinstance(v, float) else html.escape(str(v if v is not None else ""))
            if k == "name" and r["status"] != "failed":
                text = f"<a href=\"{html.escape(report_link(r['name']))}\">{text}</a>"
            cells.append(f"<td>{text}</td>")
        body.append(f"<tr>{''.join(cells)}</tr>")
    mean_cells = "".join(f"<td>{'' if v is None else f'{v:.4f}'}</td>" for v in means.values())
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>Batch summary</title><style>"
            f"body{{font-family:sans-serif}} td,th{{border:1px solid #ddd;padding:2px 6px;font-size:13px}}"
            f"table{{border-collapse:collapse}}</style></head><body><h1>Batch summary</h1>"
            f"<p>{counts['done']} done, {counts['skipped']} skipped (already done), {counts['failed']} failed</p>"
            f"<table><tr>{head}</tr>{''.join(body)}</table><h2>Means</h2><table><tr>"
            f"{''.join(f'<th>{html.escape(k)}</th>' for k in means)}</tr><tr>{mean_cells}</tr></table></body></html>")
    write_bytes_atomic(out / "index.html", page.encode())
    return summary


def report_link(name: str) -> str:
    """A scan's report.html relative to index.html: `./` and percent-encoding keep any folder name (even
    `javascript:...`) a path, never a URL scheme or markup."""
    return f"./{quote(name, safe='')}/report.html"


def run_batch(dataset: str | Path, out: str | Path, template: RunConfig, engine: str = "local", workers: int = 1,
              address: str | None = None, cpus_per_scan: float | None = None, gpus_per_scan: float = 0.0,
              on_result: Callable[[dict], None] = lambda r: None) -> dict:
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ReconError(f"{out}: exists and is not a folder (--out names the batch folder)")
    template.validate()
    if cpus_per_scan is not None and not cpus_per_scan > 0:
        raise ReconError(f"--cpus-per-scan must be > 0, got {cpus_per_scan}")
    if template.evaluation.gt_mesh:  # one broken --gt-mesh is refused once, before any scan runs
        from fusion.mesh import load_mesh

        load_mesh(template.evaluation.gt_mesh)
    configs = _configs(discover_inputs(dataset), out, template)
    out.mkdir(parents=True, exist_ok=True)
    if engine == "local":
        in_process = workers <= 1 and cpus_per_scan is None
        results = run_local(configs, workers, None if in_process else scan_threads(cpus_per_scan, workers), on_result)
    elif engine == "ray":
        results = run_ray(configs, address, cpus_per_scan, gpus_per_scan, on_result)
    else:
        raise ReconError(f"unknown engine {engine!r} (local, ray)")
    return write_summary(results, out)
