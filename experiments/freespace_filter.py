"""Does a free-space test find the too-near pixels? A prototype on a selection row's stored ESTM maps.

    python experiments/freespace_filter.py runs/select_bf16/compact_bf16 --cache runs/select_k35/scans --out runs/freespace

A point of frame i that another frame j sees *through* (j's depth at the point's projection is more than
`tolerance` beyond the point) floats in j's free space: either i's depth is too near there or j's too far.
Too-near surfaces are what the fused mesh pays for (experiments/error_sides.py), and the consistency filter
keeps those whose error the nearest frames share. This test asks every `stride`-th frame instead, near or far,
and drops a pixel that at least `violations` of them see through. Reports the share of dropped pixels that
were too near by more than 5 cm and the mesh F, culled / unculled, of the maps so filtered and then fused as
selection fuses (default filter on top). Two reference rows per scan: `as predicted` (nothing dropped) and
`oracle` (exactly the pixels more than 5 cm too near dropped, read from the GT): the most any such filter can
reach by dropping rather than fixing.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def seen_through(points_world: np.ndarray, depth_j: np.ndarray, K: np.ndarray, j_to_world: np.ndarray,
                 tolerance: float) -> np.ndarray:
    """(N,) bool: frame j has depth beyond (1 + tolerance) x the point's own depth in j where the point projects."""
    from fusion.filtering import depth_at_projection

    z, seen, _ = depth_at_projection(points_world, depth_j, K, j_to_world)
    return (seen > 0) & (seen > z * (1.0 + tolerance))


def freespace_maps(scan, src: Path, dst: Path, setting: str) -> tuple[float, float]:
    """Write `src`'s maps to `dst` with the pixels the setting drops set to 0 ('stride:violations:tolerance': seen
    through by >= violations of every stride-th frame; 'oracle': > 5 cm too near; 'as predicted': none); returns
    (dropped share, share of the dropped that were > 5 cm too near)."""
    from recon.geometry import backproject, transform_points
    from recon.io import load_confidence_map, load_depth_map, save_depth_map

    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    shutil.copy(src / "depth.json", dst / "depth.json")
    maps = [load_depth_map(src, f.name).astype(np.float32) for f in scan.frames]
    h, w = maps[0].shape
    K = scan.intrinsics.resized(w, h).K if (scan.intrinsics.width, scan.intrinsics.height) != (w, h) else scan.intrinsics.K
    poses = [f.camera_to_world for f in scan.frames]
    valid_total = dropped_total = near_dropped = 0
    for i, depth in enumerate(maps):
        valid = (depth > 0) & (depth < 4.0)
        gt = scan.depth(i)
        if gt.shape != depth.shape:
            raise SystemExit(f"{src}: maps of {depth.shape} on a scan of {gt.shape}")
        too_near = valid & (gt > 0) & (gt - depth > 0.05)
        drop = np.zeros(depth.shape, bool)
        if setting == "oracle":
            drop = too_near
        elif setting != "as predicted":
            stride, violations, tolerance = (t(v) for t, v in zip((int, int, float), setting.split(":")))
            points = transform_points(poses[i], backproject(depth, K)[valid])
            count = np.zeros(len(points), np.int32)
            for j in range(i % stride, len(maps), stride):
                if j != i:
                    count += seen_through(points, maps[j], K, poses[j], tolerance)
            drop[valid] = count >= violations
        near_dropped += int((drop & too_near).sum())
        valid_total += int(valid.sum())
        dropped_total += int(drop.sum())
        save_depth_map(dst, scan.frames[i].name, np.where(drop, 0.0, depth).astype(np.float32),
                       load_confidence_map(src, scan.frames[i].name))
    return dropped_total / max(valid_total, 1), near_dropped / max(dropped_total, 1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("rows", nargs="+", type=Path, metavar="ROW_DIR")
    p.add_argument("--cache", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scans", default="")
    p.add_argument("--settings", default="1:3:0.2,1:2:0.2", help="comma list of stride:violations:tolerance")
    args = p.parse_args(argv)

    from experiments.results_7scenes import TableOptions, mesh_scores
    from experiments.select_checkpoint import heldout_scans, unculled_fscore

    wanted = set(filter(None, args.scans.split(",")))
    settings = ["as predicted", "oracle", *args.settings.split(",")]
    print("| scan | setting | dropped | of which > 5 cm too near | mesh F culled / unculled |", flush=True)
    print("|---|---|---|---|---|")
    for scan_name, scan in heldout_scans(args.cache).items():
        if wanted and scan_name not in wanted:
            continue
        for row in args.rows:
            src = row / scan_name / "estm_m2"
            for setting in settings:
                out = args.out / row.name / f"{scan_name}_{setting.replace(' ', '_').replace(':', '_')}"
                shares = freespace_maps(scan, src, out / "estm_m2", setting)
                culled = mesh_scores(scan, out, TableOptions(), log=lambda s: None)["fscore"]
                print(f"| {scan_name} | {setting} | {shares[0]:.1%} | {shares[1]:.1%} | "
                      f"{culled:.3f} / {unculled_fscore(out, 'estm_m2'):.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
