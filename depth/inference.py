"""The depth stage: depth (+ confidence) for every frame of a canonical scan, written to a folder.

Modes: `estm`, `joint`, `independent` (the network, `depth.estimator`), `planesweep` (the
classical baseline, `depth.planesweep`, no weights needed) and `hybrid` (ESTM's depth refined by a
narrow plane sweep around it: `depth.hybrid`). Each frame's sources are chosen by
pose distance (`recon.keyframes.select_sources`). Files and resuming: `depth.store`.
"""
from __future__ import annotations

import logging
import os
import time
from dataclasses import asdict, replace
from typing import Callable, Iterator

from recon.io import load_depth_map
from recon.scan import Scan

from .adapt import adapted_copy
from .checkpoint import DEFAULT_WEIGHTS, weights_digest
from .device import resolve_precision
from .estimator import DepthEstimator, TemporalMemory
from .hybrid import refine_frames
from .options import DepthOptions, FrameDepth, check_scan, frame_sources, scan_depth_range
from .planesweep import run_planesweep
from .store import DepthStore
from .views import describe_view, network_view

log = logging.getLogger(__name__)


def _settings(scan: Scan, opts: DepthOptions, config_name: str | None) -> dict:
    """What determines the output maps; a resumed run reuses files only when these match."""
    learned = opts.mode != "planesweep"
    swept = opts.mode in ("planesweep", "hybrid")
    return {"mode": opts.mode, "depth_range": list(scan_depth_range(scan, opts.depth_range)),
            "memory_size": opts.memory_size, "sources": asdict(opts.sources), "joint_group": opts.joint_group,
            "precision": opts.precision if learned else None, "fit": opts.fit if learned else None,
            "config": config_name,
            "full_resolution": opts.full_resolution, "mirror_pass": opts.mirror_pass,
            "weights": str(opts.weights) if learned and opts.weights else None,
            "weights_digest": weights_digest(opts.weights) if learned else None,
            "planesweep": asdict(opts.planesweep) if swept else None, "names": scan.names,
            **({"adapt": asdict(opts.adapt)} if learned and opts.adapt.steps else {})}


def _with_network(opts: DepthOptions, estimator: DepthEstimator | None) -> tuple[DepthOptions, DepthEstimator]:
    """Load the weights (the shipped default unless named) and fill in what they decide."""
    if estimator is None:
        opts = replace(opts, weights=opts.weights or DEFAULT_WEIGHTS)
        estimator = DepthEstimator.from_weights(opts.weights, opts.device, opts.config)
    if opts.memory_size is None:
        opts = replace(opts, memory_size=estimator.config.memory_size)
    opts = replace(opts, precision=resolve_precision(opts.precision, estimator.device))  # depth.json says which ran
    if opts.depth_range is None and estimator.trained_depth_range is not None:
        opts = replace(opts, depth_range=estimator.trained_depth_range)
    return opts, estimator


def _adapted(scan: Scan, opts: DepthOptions, estimator: DepthEstimator) -> tuple[DepthEstimator, dict]:
    """An estimator whose network is fine-tuned on `scan` (`depth.adapt`); the given one stays as it was."""
    cfg = estimator.config
    net_scan = network_view(scan, cfg.image_width, cfg.image_height, opts.fit)
    model, summary = adapted_copy(estimator.model, net_scan, scan_depth_range(scan, opts.depth_range), opts.adapt,
                                  bf16=opts.precision == "bf16")
    log.info("depth: network adapted to the scan in %d steps (%.0f s), photometric loss %.4f -> %.4f",
             summary["steps"], summary["seconds"], summary["loss_start"], summary["loss_end"])
    return DepthEstimator(model, estimator.device, estimator.trained_depth_range), summary


def _results(scan: Scan, opts: DepthOptions, estimator: DepthEstimator | None, memory: TemporalMemory | None,
             skip: frozenset[int]) -> Iterator[FrameDepth]:
    """Every frame but `skip`, in processing order, from the mode's method(s)."""
    if opts.mode == "planesweep":
        return run_planesweep(scan, opts, skip)
    if opts.mode == "hybrid":
        return refine_frames(scan, estimator.run(scan, replace(opts, mode="estm"), memory, skip), opts.planesweep)
    return estimator.run(scan, opts, memory, skip)


def estimate_depth(scan: Scan, out_dir: str | os.PathLike, opts: DepthOptions = DepthOptions(),
                   estimator: DepthEstimator | None = None, progress: Callable[[int, int], None] | None = None,
                   resume: bool = False) -> dict:
    """Run the depth stage over `scan`, writing `<name>.png/.conf.png` and `depth.json` to `out_dir`.

    Learned modes load `opts.weights` (a shipped name or checkpoint path; default the shipped
    weights) unless a ready `estimator` is given. With `resume`, a finished run with the same
    settings is returned as is and an interrupted one keeps the frames it finished (`depth.store`).
    Returns the summary written to depth.json.
    """
    opts.validate()
    check_scan(scan)  # before anything is written
    if opts.mode != "planesweep":
        opts, estimator = _with_network(opts, estimator)
    store = DepthStore(out_dir, _settings(scan, opts, estimator.config.name if estimator else None))
    if resume and (previous := store.complete()):
        log.info("depth: %s is complete, reusing it", out_dir)
        return previous
    skip, memory = frozenset(), TemporalMemory(opts.memory_size) if opts.mode in ("estm", "hybrid") else None
    if resume and opts.mode in ("planesweep", "independent"):
        skip = store.finished_frames(scan.names)
    elif resume and opts.mode in ("estm", "hybrid"):
        skip, memory = store.finished_prefix(scan.names, list(frame_sources(scan, opts.sources)), opts.memory_size,
                                             estimator.device)
    started = time.perf_counter()
    adaptation = None
    if opts.mode != "planesweep" and opts.adapt.steps:  # before anything is written: it may refuse the scan
        estimator, adaptation = _adapted(scan, opts, estimator)
    store.begin()
    results = _results(scan, opts, estimator, memory, skip)
    frames = {}
    for r in results:
        store.save(r, memory)
        frames[r.index] = {"name": r.name, "sources": [scan.frames[j].name for j in r.sources],
                           "valid_fraction": float((r.depth > 0).mean())}
        if progress:
            progress(r.index + 1, len(scan))
    sources = frame_sources(scan, opts.sources) if skip else {}
    for i in skip:
        frames[i] = {"name": scan.names[i], "sources": [scan.frames[j].name for j in sources[i]],
                     "valid_fraction": float((load_depth_map(out_dir, scan.names[i]) > 0).mean()), "reused": True}
    frames = [frames[i] for i in sorted(frames)]
    seconds = time.perf_counter() - started
    summary = {**{k: v for k, v in store.settings.items() if k != "names"}, "settings": store.settings,
               "frames": frames, "skipped": [n for n in scan.names if n not in {f["name"] for f in frames}],
               "seconds": seconds, "seconds_per_frame": seconds / max(len(frames) - len(skip), 1),
               **({"adaptation": adaptation} if adaptation else {})}
    if estimator is not None:  # the network's input: its size turned to the frames' orientation, the fit's effect
        cfg = estimator.config
        summary["view"] = describe_view(scan.intrinsics.size, cfg.image_width, cfg.image_height, opts.fit)
    store.finish(summary)
    log.info("depth: %d frames in %.1f s (%s)", len(frames), seconds, opts.mode)
    return summary
