"""ESTM inference time of `lite` against its plane count, in one process so the noisy machine hits all alike.

    python experiments/plane_count_speed.py --planes 64 48 32 --threads 1 --precision bf16

Random weights (the cost does not depend on them), the analytic plane scene, the counts alternating; prints
the median seconds per frame of the repeats for each count.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default="lite")
    p.add_argument("--planes", type=int, nargs="+", default=[64, 48, 32])
    p.add_argument("--precision", choices=("fp32", "bf16"), default="bf16")
    p.add_argument("--frames", type=int, default=7)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    import torch

    from depth.config import get_config
    from depth.estimator import DepthEstimator
    from depth.model import ESTNet
    from depth.options import DepthOptions
    from recon.plane_scene import plane_scan

    torch.set_num_threads(args.threads)
    cfg = get_config(args.config)
    estimators = {}
    for planes in args.planes:
        torch.manual_seed(0)
        estimators[planes] = DepthEstimator(ESTNet(replace(cfg, num_planes=planes)).eval(), torch.device("cpu"))
    scan = plane_scan(args.frames, cfg.image_width, cfg.image_height, step=0.06)
    opts = DepthOptions(mode="estm", device="cpu", precision=args.precision)
    for estimator in estimators.values():  # warm-up
        list(estimator.run(scan, opts))
    seconds: dict[int, list[float]] = {planes: [] for planes in estimators}
    for _ in range(args.repeats):
        for planes, estimator in estimators.items():
            start = time.perf_counter()
            list(estimator.run(scan, opts))
            seconds[planes].append((time.perf_counter() - start) / args.frames)
    for planes, values in seconds.items():
        print(f"{args.config} {planes} planes {args.precision}: {statistics.median(values):.3f} s/frame "
              f"({', '.join(f'{v:.3f}' for v in values)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
