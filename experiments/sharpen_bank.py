"""A bank of (image, network depth, confidence, GT depth) samples from the training stream, for training an
edge sharpener on top of frozen weights without running the EST network at every step.

    python experiments/sharpen_bank.py compact --clips 400 --seed 7100 --out runs/sharpen_bank/7100.pt

Each clip of the synthetic training stream (the one `recon train --synthetic --close-ups` draws; the seed
picks new rooms) runs through the frozen network jointly, as in training; each of its three targets
gives one sample at the network size: image (3, H, W) uint8, D3 (H, W), the D1 confidence (h, w), GT depth
(H, W) with 0 = invalid, and the clip's depth range. Shards are rewritten every 25 clips, so a stopped run
keeps what it made. Held-out and 7-Scenes data are never read.
"""
from __future__ import annotations

import argparse
import functools
import itertools
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", help="a shipped name or a checkpoint file (frozen)")
    p.add_argument("--clips", type=int, default=400)
    p.add_argument("--seed", type=int, default=7100)
    p.add_argument("--scale-jitter", type=float, default=0.4)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", required=True, help="file to write (torch.save of a list of samples)")
    args = p.parse_args(argv)

    from torch.utils.data import DataLoader

    from apps.commands.train import training_stream
    from depth.checkpoint import build_model, load_checkpoint
    from depth.data import ClipOptions, StreamingClips

    torch.set_num_threads(args.threads)
    ck = load_checkpoint(args.checkpoint)
    model = build_model(ck).eval()
    depth_range = tuple(ck.metadata.get("data", {}).get("depth_range") or (0.25, 10.0))
    clip = ClipOptions(width=ck.config.image_width, height=ck.config.image_height, scale_jitter=args.scale_jitter,
                       reverse_share=0.5)
    stream = StreamingClips(functools.partial(training_stream, args.seed, depth_range, True), clip, seed=args.seed)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    samples, t0 = [], time.time()
    for n, batch in enumerate(itertools.islice(DataLoader(stream, 1), args.clips), 1):
        with torch.no_grad():
            outputs = model(batch["images"], batch["K"], batch["camera_to_world"], batch["depth_range"])
        for t, o in enumerate(outputs, 1):
            samples.append({"image": (batch["images"][0, t] * 255).round().to(torch.uint8),
                            "depth": o.depths[-1][0, 0].half(), "confidence": o.confidence[0, 0].half(),
                            "gt": batch["depth"][0, t].half(), "depth_range": batch["depth_range"][0].clone()})
        if n % 25 == 0 or n == args.clips:
            torch.save(samples, out.with_suffix(".tmp"))
            out.with_suffix(".tmp").replace(out)
            print(f"{n} clips, {len(samples)} samples, {time.time() - t0:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
