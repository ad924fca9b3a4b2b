"""`recon bench train`: seconds per training step of the depth network, fp32 against bf16 autocast, same clips.

Each step is `depth.train.Trainer.train_step` (forward, multi-stage loss, backward, clip, Adam) on one
clip of the synthetic training stream at the config's size. The precisions alternate clip by clip
after a warm-up step each, and the median counts (the machine is shared). bf16 runs only where the
device computes it in hardware (`depth.device.computes_bf16`, which is what `recon train --amp auto`
asks); elsewhere it is emulated at about 8x the fp32 time and the row says so instead.
"""
from __future__ import annotations

import itertools
import statistics
import sys
import tempfile
import time

from apps.common import print_json


def add_arguments(parser):
    parser.add_argument("--config", default="compact", help="network config (default compact)")
    parser.add_argument("--steps", type=int, default=6, help="timed steps per precision (default 6)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1, as training runs)")
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="cpu")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _clips(cfg, count: int) -> list[dict]:
    """`count` augmented training clips (batch of one) from the synthetic stream, as `recon train --synthetic`."""
    from torch.utils.data import default_collate

    from apps.commands.train import training_stream
    from depth.data import ClipOptions, StreamingClips

    opts = ClipOptions(width=cfg.image_width, height=cfg.image_height, scale_jitter=0.4, reverse_share=0.5)
    stream = StreamingClips(training_stream(4242, (0.25, 10.0), True, shard=0), opts, seed=1)
    return [default_collate([clip]) for clip in itertools.islice(stream, count)]


def measure(config: str = "compact", steps: int = 6, device: str = "cpu") -> dict:
    import torch

    from depth.config import get_config
    from depth.device import computes_bf16, describe_device, resolve_device
    from depth.train import Trainer, TrainOptions
    from recon.errors import ReconError

    if steps < 1:
        raise ReconError(f"--steps must be at least 1, got {steps}")
    cfg = get_config(config)
    dev = resolve_device(device)
    native = computes_bf16(dev)
    precisions = ["fp32", "bf16"] if native else ["fp32"]
    clips = _clips(cfg, steps + 1)
    times = {p: [] for p in precisions}
    with tempfile.TemporaryDirectory() as tmp:
        trainers = {p: Trainer(TrainOptions(config=cfg.name, amp=None if p == "fp32" else p, device=dev.type, lr=1e-6,
                                            max_steps=10**9, log_every=10**9), tmp, cfg, dict)
                    for p in precisions}
        for i, clip in enumerate(clips):
            for p, trainer in trainers.items():
                start = time.perf_counter()
                trainer.train_step(trainer.model, clip)
                if dev.type == "cuda":
                    torch.cuda.synchronize(dev)
                if i:  # the first clip warms up
                    times[p].append(time.perf_counter() - start)
    rows = {p: {"s_per_step": round(statistics.median(t), 3), "steps_per_hour": round(3600 / statistics.median(t))}
            for p, t in times.items()}
    if not native:
        rows["bf16"] = {"s_per_step": None, "steps_per_hour": None, "note": "emulated on this device (about 8x fp32)"}
    out = {"config": cfg.name, "device": describe_device(dev), "size": [cfg.image_width, cfg.image_height],
           "computes_bf16": native, "amp_auto_picks": "bf16" if native else "fp32", "steps": steps, "rows": rows}
    if native:
        out["bf16_speedup"] = round(rows["fp32"]["s_per_step"] / rows["bf16"]["s_per_step"], 2)
    return out


def run(args) -> int:
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(max(1, args.threads))
    try:
        result = measure(args.config, args.steps, args.device)
    finally:
        torch.set_num_threads(threads)
    if args.json:
        print_json(result)
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"recon bench train: {result['config']} at {result['size'][0]}x{result['size'][1]}, "
                        f"{result['device']}, median of {result['steps']} steps")
    for column in ("precision", "s / step", "steps / hour", "note"):
        table.add_column(column)
    for name, row in result["rows"].items():
        auto = " (--amp auto)" if name == result["amp_auto_picks"] else ""
        table.add_row(name + auto, "-" if row["s_per_step"] is None else f"{row['s_per_step']:.2f}",
                      "-" if row["steps_per_hour"] is None else str(row["steps_per_hour"]), row.get("note", ""))
    Console(file=sys.stdout).print(table)
    if "bf16_speedup" in result:
        print(f"bf16 / fp32 speed-up: {result['bf16_speedup']:.2f}x")
    return 0
