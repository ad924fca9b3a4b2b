"""Recompute a checkpoint's BatchNorm statistics over many synthetic training clips ("precise BN")
and write the result as a new checkpoint, to score like any other.

    python experiments/precise_bn.py lite-preview --clips 200 --out runs/precise/lite-preview_bn200.pt

The clips come from the training stream (`recon.synthetic.iter_training_mix`, the checkpoint's trained depth
range, augmented as `recon train` does) from a seed of their own, never from the held-out rooms.
Measured 2026-12-04 (docs/depth.md): no gain on `lite-preview`; on a `compact` checkpoint whose last steps had
moved its statistics, part of the loss back. Training does not do it.
"""
from __future__ import annotations

import argparse
import functools
import itertools
import sys
import time
from collections.abc import Iterable
from pathlib import Path

import torch
from torch import nn

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from recon.errors import ReconError  # noqa: E402


@torch.no_grad()
def recalibrate_batchnorm(model: nn.Module, batches: Iterable[dict]) -> int:
    """Replace the running statistics of every BatchNorm that trains by their plain mean over `batches`
    (clip batches as `depth.train.clip_loss` takes them, on the CPU). At batch size 1 the running statistics
    are a momentum-0.1 average over the last one or two clips. Returns the number of batches seen; the
    model is left in eval mode, its weights untouched."""
    model.train()
    norms = [m for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm) and m.training]
    before = [(m.momentum, {k: v.clone() for k, v in m.state_dict().items()}) for m in norms]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # cumulative average
    seen = 0
    try:
        for b in batches:
            model(b["images"], b["K"], b["camera_to_world"], b["depth_range"])
            seen += 1
    finally:
        for m, (momentum, stats) in zip(norms, before):
            m.momentum = momentum
            if not seen:  # nothing came (or the first batch failed): the statistics stay as they were
                m.load_state_dict(stats)
        model.eval()
    if not seen:
        raise ReconError("recalibrate_batchnorm: no batches")
    return seen


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", help="a shipped name or a checkpoint file")
    p.add_argument("--clips", type=int, default=200, help="training clips to average over (default 200)")
    p.add_argument("--seed", type=int, default=4242, help="seed of the clip stream (default 4242)")
    p.add_argument("--scale-jitter", type=float, default=0.4, help="as recon train's (default 0.4)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", required=True, help="checkpoint file to write")
    args = p.parse_args(argv)

    from torch.utils.data import DataLoader

    from apps.commands.train import training_stream
    from depth.checkpoint import build_model, load_checkpoint, save_checkpoint
    from depth.data import ClipOptions, StreamingClips

    torch.set_num_threads(args.threads)
    ck = load_checkpoint(args.checkpoint)
    model = build_model(ck)
    depth_range = tuple(ck.metadata.get("data", {}).get("depth_range") or (0.25, 10.0))
    clip = ClipOptions(width=ck.config.image_width, height=ck.config.image_height, scale_jitter=args.scale_jitter)
    stream = StreamingClips(functools.partial(training_stream, args.seed, depth_range, False), clip, seed=args.seed)
    t0 = time.time()
    seen = recalibrate_batchnorm(model, itertools.islice(DataLoader(stream, 1), args.clips))
    metadata = dict(ck.metadata, batchnorm_recalibrated={"clips": seen, "seed": args.seed,
                                                         "scale_jitter": args.scale_jitter, "from": args.checkpoint})
    save_checkpoint(args.out, model, ck.config, metadata=metadata, fp16=True)
    print(f"{args.out}: {args.checkpoint} with BatchNorm statistics over {seen} clips ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
