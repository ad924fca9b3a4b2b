"""Where one ESTM frame's time goes on a GPU, and what compiling (CUDA graphs there) gains.

    python experiments/gpu_frame_profile.py --config paper --device cuda --out DIR

1. eager bf16 under torch.profiler: the bench's time per frame, the kernel launches per frame and the
   table of the ops that take the GPU's time (docs/depth.md "On a GPU");
2. `recon bench depth`'s measure, eager then with `--compile`, in this one process so both figures
   share a machine state.
Writes profile.txt and bench.json under --out.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from apps.bench.depth import measure  # noqa: E402


def profile(config: str, device: str, precision: str, frames: int) -> str:
    from torch.profiler import ProfilerActivity, profile as torch_profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device == "cuda" else [])
    measure(config, frames=2, device=device, baseline=False, precision=precision)  # warm the allocator, cuDNN
    start = time.perf_counter()
    with torch_profile(activities=activities) as prof:
        result = measure(config, frames=frames, device=device, baseline=False, precision=precision)
    wall = time.perf_counter() - start
    events = prof.key_averages()
    per_frame = frames + 3  # the warm-up frames run under the profiler too
    launches = sum(e.count for e in events if e.key in ("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunchKernelExC"))
    lines = [f"{config} {precision} on {device}: bench {result['s_per_frame'] * 1e3:.1f} ms/frame (profiled), "
             f"{wall / per_frame * 1e3:.1f} ms wall per frame incl. setup; "
             f"kernel launches {launches / per_frame:.0f}/frame",
             events.table(sort_by="self_cuda_time_total" if device == "cuda" else "self_cpu_time_total",
                          row_limit=25)]
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default="paper")
    p.add_argument("--device", default="cuda")
    p.add_argument("--precision", default="bf16")
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--no-profile", action="store_true")
    p.add_argument("--out", required=True)
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not args.no_profile:
        text = profile(args.config, args.device, args.precision, args.frames)
        (out / "profile.txt").write_text(text)
        print(text.splitlines()[0], flush=True)
    rows = []
    for compile in (False, True):
        started = time.perf_counter()
        rows.append({**measure(args.config, frames=args.frames, device=args.device, precision=args.precision,
                               compile=compile, baseline=not compile),
                     "wall_s_incl_compile": round(time.perf_counter() - started, 1)})
        print("compiled" if compile else "eager", rows[-1]["s_per_frame"], flush=True)
    (out / "bench.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
