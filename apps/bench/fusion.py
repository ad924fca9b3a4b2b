"""`recon bench fusion`: our TSDF fusion against a bare Open3D VoxelBlockGrid loop, same frames, same run.

Frames are loaded into memory first, so both loops measure integration, not disk reads.
Each loop runs `--repeats` times alternately and the best time counts (the machine is
shared and noisy). Mesh evaluation of the fused mesh (200k points) is timed as well.
"""
from __future__ import annotations

import time

import numpy as np

from apps.common import print_json
from recon.errors import ReconError

DEFAULT_SCAN = "../shared/data/7scenes-redkitchen"


def add_arguments(parser):
    parser.add_argument("--scan", default=DEFAULT_SCAN, help=f"scan to integrate (default {DEFAULT_SCAN})")
    parser.add_argument("--max-frames", type=int, default=None, help="use the first N frames (default all)")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs of each loop (best counts)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _bare_loop(frames, K, config) -> float:
    """What a user would write with Open3D alone: same grid, same parameters."""
    import open3d as o3d
    import open3d.core as o3c

    dev = o3c.Device("CPU:0")
    grid = o3d.t.geometry.VoxelBlockGrid(("tsdf", "weight", "color"), (o3c.float32, o3c.float32, o3c.float32),
                                         ((1), (1), (3)), config.voxel_size, config.block_resolution,
                                         config.initial_blocks, dev)
    Kt = o3c.Tensor(K, o3c.float64)
    start = time.perf_counter()
    for depth, rgb, pose in frames:
        d = o3d.t.geometry.Image(o3c.Tensor(depth))
        c = o3d.t.geometry.Image(o3c.Tensor(rgb.astype(np.float32) / 255))
        ext = o3c.Tensor(np.linalg.inv(pose), o3c.float64)
        blocks = grid.compute_unique_block_coordinates(d, Kt, ext, 1.0, config.depth_max, config.trunc_voxels)
        grid.integrate(blocks, d, c, Kt, Kt, ext, 1.0, config.depth_max, config.trunc_voxels)
    return time.perf_counter() - start


def _our_loop(frames, intrinsics, config):
    from fusion.tsdf import TSDFIntegrator

    integrator = TSDFIntegrator(config)
    start = time.perf_counter()
    for depth, rgb, pose in frames:
        integrator.integrate(depth, rgb, intrinsics, pose)
    return time.perf_counter() - start, integrator


def run(args) -> int:
    from pathlib import Path

    from fusion.evaluate import mesh_metrics
    from fusion.tsdf import TSDFConfig
    from recon.readers import open_scan

    if not Path(args.scan).exists():
        raise ReconError(f"{args.scan}: benchmark scan not found (pass --scan)")
    scan = open_scan(args.scan)
    if args.max_frames:
        scan = scan.select(0, 1, args.max_frames)
    config = TSDFConfig(device="cpu")
    t0 = time.perf_counter()
    frames = [(scan.depth(i), scan.image(i), scan.frames[i].camera_to_world) for i in range(len(scan))]
    load_s = time.perf_counter() - t0
    bare, ours, integrator = [], [], None
    for rep in range(max(1, args.repeats)):
        if rep % 2:  # alternate which loop goes first, so warm-up favours neither
            t, integrator = _our_loop(frames, scan.intrinsics, config)
            bare.append(_bare_loop(frames, scan.intrinsics.K, config))
        else:
            bare.append(_bare_loop(frames, scan.intrinsics.K, config))
            t, integrator = _our_loop(frames, scan.intrinsics, config)
        ours.append(t)
    t0 = time.perf_counter()
    mesh = integrator.extract_mesh()
    extract_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    metrics = mesh_metrics(mesh, mesh)
    eval_s = time.perf_counter() - t0
    n = len(frames)
    result = {
        "scan": str(args.scan), "frames": n, "width": scan.intrinsics.width, "height": scan.intrinsics.height,
        "voxel_size": config.voxel_size, "bare_fps": n / min(bare), "ours_fps": n / min(ours),
        "overhead": min(ours) / min(bare), "load_fps": n / load_s, "extract_s": extract_s,
        "mesh_faces": int(len(mesh.faces)), "mesh_eval_s": eval_s, "mesh_eval_fscore": metrics["fscore"],
    }
    if args.json:
        print_json(result)
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"TSDF fusion, {n} frames {result['width']}x{result['height']}, {config.voxel_size} m voxels")
    for col in ("loop", "frames/s", "vs bare"):
        table.add_column(col)
    table.add_row("bare Open3D VoxelBlockGrid", f"{result['bare_fps']:.1f}", "1.00x")
    table.add_row("recon fusion (TSDFIntegrator)", f"{result['ours_fps']:.1f}", f"{result['overhead']:.2f}x")
    table.add_row("reading frames from disk", f"{result['load_fps']:.1f}", "")
    Console().print(table)
    print(f"mesh extraction + cleanup: {extract_s:.2f} s ({result['mesh_faces']} faces); "
          f"mesh evaluation of 200k points: {eval_s:.2f} s")
    return 0
