"""Zero-shot depth and mesh evaluation of the shipped weights on the 7-Scenes sequence (issue 6).

    python examples/evaluate_7scenes.py                       # ../shared/data/7scenes-redkitchen, every 10th frame
    python examples/evaluate_7scenes.py --stride 20 --markdown docs/results_7scenes.md
    python examples/evaluate_7scenes.py --max-frames 5 --weights /tmp/random.pt --no-mesh   # smoke run

Frames are read at 320x256 (the paper's protocol; the 640x480 frames are stretched, intrinsics
follow), every `--stride`-th frame. Each row runs `depth.inference.estimate_depth` and is scored
with `depth.metrics.evaluate_depth_folder` (what `recon eval depth` runs) over 0-10 m. The sweep
range is the network's training range, read from the checkpoint's metadata (fallback 0.25-6 m),
never from the 7-Scenes ground truth. The ESTM (memory 2) depth and the GT depth of the same
frames are fused with the same TSDF settings and compared (`recon eval mesh` protocol).
7-Scenes is a validation set only: nothing here trains or tunes on it.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from depth.checkpoint import DEFAULT_WEIGHTS, trained_depth_range  # noqa: E402  (after the path set-up)
from experiments.results_7scenes import DEFAULT_ROWS  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data" / "7scenes-redkitchen"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="7-Scenes zero-shot depth table + mesh scores")
    p.add_argument("--data", default=str(DEFAULT_DATA), help="7-Scenes folder (default ../shared/data/7scenes-redkitchen)")
    p.add_argument("--weights", default=DEFAULT_WEIGHTS, help=f"checkpoint name or path (default: {DEFAULT_WEIGHTS})")
    p.add_argument("--concat-weights", default=None, help="a concat-fusion checkpoint, for its extra row")
    p.add_argument("--stride", type=int, default=10)
    p.add_argument("--start", type=int, default=0)
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--rows", default=",".join(DEFAULT_ROWS),
                   help="comma-separated rows (planesweep, independent, joint, estm_m1, estm_m2, estm_m3, hybrid, estm_mirror, hybrid_mirror, estm_adapted)")
    p.add_argument("--depth-range", type=float, nargs=2, default=None, metavar=("MIN", "MAX"),
                   help="sweep range; default: the checkpoint's training range")
    p.add_argument("--out", default="runs/eval_7scenes", help="where depth maps and meshes go")
    p.add_argument("--no-mesh", action="store_true")
    p.add_argument("--resume", action="store_true",
                   help="reuse finished row folders under --out (depth.json names weights, not their content: "
                        "do not resume after the weights file changed)")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    p.add_argument("--json", default=None, metavar="PATH", help="write all figures as JSON")
    p.add_argument("--markdown", default=None, metavar="PATH", help="write the tables as Markdown")
    args = p.parse_args(argv)

    import torch

    from recon.readers import open_scan
    from experiments.results_7scenes import TableOptions, depth_table, markdown_table, mesh_markdown, write_results

    if args.threads:
        torch.set_num_threads(args.threads)
    data = Path(args.data)
    if not data.is_dir():
        print(f"skipped: 7-Scenes data not found at {data}", file=sys.stderr)
        return 0
    rows = tuple(r.strip() for r in args.rows.split(",") if r.strip())
    depth_range = tuple(args.depth_range) if args.depth_range else None
    if depth_range is None and any(r != "planesweep" for r in rows):
        depth_range = trained_depth_range(args.weights)
    depth_range = depth_range or (0.25, 6.0)
    scan = open_scan(data).select(args.start, args.stride, args.max_frames).resized(320, 256)
    opts = TableOptions(weights=args.weights, concat_weights=args.concat_weights, rows=rows,
                        depth_range=depth_range, mesh=not args.no_mesh, resume=args.resume,
                        extra={"data": str(data), "stride": args.stride, "start": args.start,
                               "threads": torch.get_num_threads(), "load_average": os.getloadavg()[0]})
    print(f"7-Scenes {data.name}: {len(scan)} frames (every {args.stride}th from {args.start}) at 320x256, "
          f"sweep range {depth_range[0]}-{depth_range[1]} m, evaluation range 0-10 m, weights {args.weights}, "
          f"{torch.get_num_threads()} torch thread(s)")
    t0 = time.time()
    results = depth_table(scan, args.out, opts)
    results["wall_s"] = time.time() - t0
    table = markdown_table(results)
    print()
    print(table)
    if "mesh" in results:
        print()
        print(mesh_markdown(results["mesh"], results.get("mesh_baselines")))
    if args.json:
        write_results(results, args.json)
    if args.markdown:
        text = table + ("\n\n" + mesh_markdown(results["mesh"], results.get("mesh_baselines")) if "mesh" in results else "") + "\n"
        Path(args.markdown).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
