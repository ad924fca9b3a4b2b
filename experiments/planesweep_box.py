"""Same-process A/B of the plane sweep's window means: PyTorch's avg_pool2d against `depth.planesweep._box`
(two depthwise 1D convolutions), alternating, on the analytic scene at 320x256 (64 planes, 2 sources).

    python experiments/planesweep_box.py --threads 1 --repeats 4
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--repeats", type=int, default=4)
    args = p.parse_args(argv)

    import torch
    import torch.nn.functional as F

    import depth.planesweep as ps
    from recon.plane_scene import plane_scan

    torch.set_num_threads(args.threads)
    scan = plane_scan(3, 320, 256, step=0.08)
    gray = ps.to_gray(torch.stack([torch.from_numpy(scan.image(i)).permute(2, 0, 1).float() / 255 for i in range(3)]))
    poses, K = torch.from_numpy(scan.camera_to_world).float(), torch.from_numpy(scan.intrinsics.K).float()
    filters = {"avg_pool2d": lambda x, k: F.avg_pool2d(x, k, 1, k // 2, count_include_pad=False), "_box": ps._box}
    seconds = {name: [] for name in filters}
    for _ in range(args.repeats):
        for name, box in filters.items():
            ps._box = box
            start = time.perf_counter()
            ps.plane_sweep_depth(gray[1], gray[[0, 2]], K, poses[1], poses[[0, 2]], (0.25, 10.0))
            seconds[name].append(time.perf_counter() - start)
    for name, values in seconds.items():
        print(f"{name:10s} s/frame {min(values):.2f}-{max(values):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
