"""`recon bench fusion`: our TSDF fusion against a bare Open3D VoxelBlockGrid loop, same frames, same run.

Frames are loaded into memory first, so both loops measure integration, not disk reads.
Each loop runs `--repeats` times alternately and the best time counts (the machine is
shared and noisy). Mesh evaluation of the fused mesh (200k points) is timed as well.

The depth filter (fusion.filtering, default checks) is timed on the same frames at their resolution and at
the network's (320x256), against the depth stage (ESTM with the shipped weights) on the first
`--depth-frames` frames at 320x256 in the same run: the filter's share of the depth stage's time.
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
    parser.add_argument("--depth-frames", type=int, default=8, metavar="N",
                        help="frames of the ESTM depth stage timed for the filter's share (0: skip; default 8)")
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


def _filter_seconds(scan, depths, config) -> tuple[float, float]:
    """(seconds per frame, kept share) of the default depth filter over in-memory depth maps of `scan`."""
    from fusion.filtering import DepthFilter, FilterConfig
    from fusion.tsdf import DepthMap

    depth_filter = DepthFilter(scan, lambda i: DepthMap(depths[i]), FilterConfig(), (config.depth_min, config.depth_max))
    for i in range(len(depths)):
        depth_filter(i)
    return depth_filter.stats.seconds / len(depths), depth_filter.stats.as_dict()["kept_share"]


def _filter_timing(scan, frames, config, depth_frames: int) -> dict:
    """The filter at the frames' resolution and at the network's, and the ESTM depth stage at the network's."""
    import tempfile

    import cv2

    from depth.inference import estimate_depth
    from depth.options import DepthOptions

    out = {}
    out["filter_s_per_frame"], out["filter_kept_share"] = _filter_seconds(scan, [f[0] for f in frames], config)
    small = scan.resized(320, 256)
    depths = [cv2.resize(f[0], (320, 256), interpolation=cv2.INTER_NEAREST) for f in frames]
    out["filter_320x256_s_per_frame"], _ = _filter_seconds(small, depths, config)
    if depth_frames > 0:
        with tempfile.TemporaryDirectory(prefix="bench-depth-") as tmp:
            summary = estimate_depth(small.select(0, 1, depth_frames), tmp, DepthOptions(mode="estm", device="cpu"))
        out["depth_s_per_frame"] = summary["seconds_per_frame"]
        out["filter_share_of_depth"] = out["filter_320x256_s_per_frame"] / summary["seconds_per_frame"]
    return out


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
        **_filter_timing(scan, frames, config, args.depth_frames),
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
    table.add_row(f"depth filter, {result['width']}x{result['height']} (kept {result['filter_kept_share']:.1%})",
                  f"{1 / result['filter_s_per_frame']:.1f}",
                  f"{result['filter_s_per_frame'] * result['ours_fps']:.2f}x our integration")
    table.add_row("depth filter, 320x256", f"{1 / result['filter_320x256_s_per_frame']:.1f}", "")
    if "depth_s_per_frame" in result:
        table.add_row("depth stage (ESTM), 320x256", f"{1 / result['depth_s_per_frame']:.2f}",
                      f"filter = {result['filter_share_of_depth']:.1%} of it")
    Console().print(table)
    print(f"mesh extraction + cleanup: {extract_s:.2f} s ({result['mesh_faces']} faces); "
          f"mesh evaluation of 200k points: {eval_s:.2f} s")
    return 0
