"""A/B of the 3D convolutions' memory layout, in one process so the noisy machine hits both alike.

    python experiments/conv3d_layout.py --config lite --threads 2

Times ESTM inference over the analytic plane scene (random weights; the cost does not depend on
them) with `depth.model.layers.Conv3d` convolving in channels-last (its `memory_format`, the shipped
code) and in the standard layout, alternating, and prints seconds per frame of each (the median of the repeats).
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from depth.config import get_config
from depth.inference import DepthEstimator, DepthOptions
from depth.model import ESTNet, layers
from recon.plane_scene import plane_scan


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="lite")
    p.add_argument("--frames", type=int, default=7)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    cfg = get_config(args.config)
    torch.manual_seed(0)
    estimator = DepthEstimator(ESTNet(cfg).eval(), torch.device("cpu"))
    scan = plane_scan(args.frames, cfg.image_width, cfg.image_height, step=0.06)
    variants = {"channels-last": torch.channels_last_3d, "standard": torch.contiguous_format}
    seconds: dict[str, list[float]] = {name: [] for name in variants}
    list(estimator.run(scan, DepthOptions(mode="estm", device="cpu")))  # warm-up
    for _ in range(args.repeats):
        for name, layout in variants.items():
            layers.Conv3d.memory_format = layout
            start = time.perf_counter()
            list(estimator.run(scan, DepthOptions(mode="estm", device="cpu")))
            seconds[name].append((time.perf_counter() - start) / args.frames)
    layers.Conv3d.memory_format = variants["channels-last"]
    for name, values in seconds.items():
        print(f"{args.config} {name}: {statistics.median(values):.3f} s/frame ({', '.join(f'{v:.3f}' for v in values)})")


if __name__ == "__main__":
    main()
