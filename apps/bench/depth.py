"""`recon bench depth`: size and speed of the EST network at its input size (320x256 by default).

Reports parameters, MACs of one ESTM step (3-frame window + memory of N volumes, counted
with torch's FlopCounterMode on the meta device; MACs = FLOPs / 2), peak memory (RSS on
CPU, allocator peak on CUDA) and seconds per frame over an analytic synthetic sequence,
measured against the classical plane sweep on the same frames in the same run.
On a shared machine wall time depends on the other load: `cpu_s_per_frame` (process CPU
seconds) and the 1-minute load average are reported beside it.
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from recon.errors import ReconError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default="compact",
                        help="network config: lite, compact or paper, or weights (a shipped name such as lite-preview, "
                             "or a file) whose config is timed (default compact)")
    parser.add_argument("--mode", choices=("estm", "joint", "independent"), default="estm")
    parser.add_argument("--frames", type=int, default=8, help="frames timed after 3 warm-up frames (default 8)")
    parser.add_argument("--memory", type=int, default=None, metavar="N", help="ESTM memory length (default 2)")
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    parser.add_argument("--precision", choices=("fp32", "bf16", "auto"), default="fp32",
                        help="network arithmetic (default fp32; auto: what `recon depth` picks on this device)")
    parser.add_argument("--compile", action="store_true",
                        help="torch.compile the network (compiled during the warm-up frames, which are not timed)")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for torch (default 2)")
    parser.add_argument("--no-baseline", action="store_true", help="skip timing the plane-sweep baseline")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def count_gmacs(cfg, memory_size: int) -> float:
    """MACs (in G) of one ESTM step: features of 3 frames, one target, `memory_size` memories."""
    from depth.model import ESTNet

    with torch.device("meta"):  # shapes only: no pretrained weights to load
        net = ESTNet(cfg, pretrained=False).eval()
        images = torch.rand(1, 3, 3, cfg.image_height, cfg.image_width)
        K = torch.eye(3)[None]
        poses = torch.eye(4).repeat(1, 3, 1, 1)
        rng = torch.ones(1, 2)
        with torch.no_grad():
            entry = net(images, K, poses, rng, targets=[(1, (0, 2))])[0].memory
            counter = FlopCounterMode(display=False)
            with counter:
                net(images, K, poses, rng, targets=[(1, (0, 2))], memory=[entry] * memory_size)
    return counter.get_total_flops() / 2e9


def _peak_mb(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux reports KiB


def bench_config(config: str):
    """A named network config, else the config that weights (a shipped name or a file) were trained with: the
    shipped files may differ from the named configs (e.g. in plane count). Timing uses random weights either way."""
    from depth.checkpoint import load_checkpoint
    from depth.config import CONFIGS, get_config

    return get_config(config) if config in CONFIGS else load_checkpoint(config).config


def measure(config: str, mode: str = "estm", frames: int = 8, memory: int | None = None, device: str = "auto",
            baseline: bool = True, precision: str = "fp32", compile: bool = False) -> dict:
    from depth.device import resolve_device, resolve_precision
    from depth.inference import DepthEstimator, DepthOptions, run_planesweep
    from depth.model import ESTNet
    from depth.planesweep import PlaneSweepOptions
    from recon.plane_scene import plane_scan

    if frames < 1:
        raise ReconError(f"--frames must be at least 1, got {frames}")
    cfg = bench_config(config)
    dev = resolve_device(device)
    torch.manual_seed(0)
    model = ESTNet(cfg)
    params = sum(p.numel() for p in model.parameters())
    mem_n = cfg.memory_size if memory is None else memory
    gmacs = count_gmacs(cfg, mem_n)
    estimator = DepthEstimator(model, dev)
    scan = plane_scan(frames + 3, cfg.image_width, cfg.image_height, step=0.06)
    precision = resolve_precision(precision, dev)
    opts = DepthOptions(mode=mode, memory_size=mem_n, device=str(dev.type), precision=precision, compile=compile)
    # One continuous pass (the ESTM memory fills as in real use); the clock starts after 3 warm-up frames.
    start = cpu_start = None
    count = 0
    for r in estimator.run(scan, opts):
        if r.index == 2:
            if dev.type == "cuda":
                torch.cuda.synchronize(dev)
                torch.cuda.reset_peak_memory_stats(dev)
            start, cpu_start = time.perf_counter(), time.process_time()
        elif start is not None:
            count += 1
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
    seconds = (time.perf_counter() - start) / count
    cpu_seconds = (time.process_time() - cpu_start) / count
    out = {"config": cfg.name, "mode": mode, "precision": precision, "compile": compile, "device": torch.cuda.get_device_name(dev) if dev.type == "cuda"
           else f"cpu ({torch.get_num_threads()} threads)", "params_m": round(params / 1e6, 3),
           "gmacs": round(gmacs, 2), "peak_mem_mb": round(_peak_mb(dev), 1), "s_per_frame": round(seconds, 4),
           "cpu_s_per_frame": round(cpu_seconds, 4), "load_average": round(os.getloadavg()[0], 2),
           "image_size": [cfg.image_width, cfg.image_height], "num_planes": cfg.num_planes,
           "memory_size": mem_n, "frames": count}
    if baseline:
        ps_opts = DepthOptions(mode="planesweep", device=str(dev.type),
                               planesweep=PlaneSweepOptions(num_planes=cfg.num_planes, width=cfg.image_width))
        start = time.perf_counter()
        n = len(list(run_planesweep(scan, ps_opts, skip=frozenset(range(3)))))
        ps = (time.perf_counter() - start) / n
        out["planesweep_s_per_frame"] = round(ps, 4)
        out["ratio_to_planesweep"] = round(seconds / ps, 2)
    return out


def run(args: argparse.Namespace) -> int:
    threads = torch.get_num_threads()
    torch.set_num_threads(max(1, args.threads))
    try:
        result = measure(args.config, args.mode, args.frames, args.memory, args.device, not args.no_baseline,
                         args.precision, args.compile)
    finally:
        torch.set_num_threads(threads)
    if args.json:
        from apps.common import print_json

        print_json(result)
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"recon bench depth: {result['config']} ({result['mode']})")
    table.add_column("measure")
    table.add_column("value", justify="right")
    for k, v in result.items():
        table.add_row(k, str(v))
    Console(file=sys.stdout).print(table)
    return 0
