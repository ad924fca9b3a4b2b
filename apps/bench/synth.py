"""`recon bench synth`: synthetic rendering throughput against bare Open3D ray casting, same rays, same run.

The baseline casts the frames' rays with `RaycastingScene.cast_rays` and nothing else
(depth only); the renderer adds texturing, shading, a shadow cast and tone mapping. Each loop runs
`--repeats` times alternately and the best time counts (the machine is shared). Scene
generation, sensor effects and the training stream (clips/s) are timed as well.
"""
from __future__ import annotations

import itertools
import time

import numpy as np

from apps.common import print_json


def add_arguments(parser):
    parser.add_argument("--size", default="320x256", metavar="WxH", help="image size (default 320x256)")
    parser.add_argument("--frames", type=int, default=60, help="frames per timed loop (default 60)")
    parser.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    parser.add_argument("--clips", type=int, default=16, help="training clips to time (default 16)")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs of each loop (best counts)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _bare_cast(renderer, poses, intrinsics) -> float:
    start = time.perf_counter()
    for pose in poses:
        renderer.cast(pose, intrinsics)
    return time.perf_counter() - start


def _full_render(renderer, poses, intrinsics) -> float:
    start = time.perf_counter()
    for pose in poses:
        radiance, _depth = renderer.render_linear(pose, intrinsics)
        renderer.tone_map(radiance, 1.0)
    return time.perf_counter() - start


def run(args) -> int:
    from apps.common import parse_size
    from recon.synthetic import (Renderer, SensorEffects, SynthConfig, camera_intrinsics, generate_scene,
                                 handheld_trajectory, iter_training_scans, render_scan, texture_library)

    width, height = parse_size(args.size)
    config = SynthConfig(seed=args.seed, frames=max(1, args.frames), width=width, height=height).validate()
    t0 = time.perf_counter()
    library = texture_library(config.texture_size)
    library_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    scene = generate_scene(config.seed, library, config.scene)
    scene_s = time.perf_counter() - t0
    renderer = Renderer(scene, library)
    unshadowed = Renderer(scene, library, shadows=False)
    intrinsics = camera_intrinsics(config, np.random.default_rng([config.seed, 3]))
    poses = handheld_trajectory(scene.free_space, config.frames, config.fps, np.random.default_rng([config.seed, 4]),
                                config.trajectory, config.scene.camera_clearance_m)
    _full_render(renderer, poses[:2], intrinsics)  # warm-up: ray tables, BVH
    _full_render(unshadowed, poses[:2], intrinsics)
    bare, full, flat = [], [], []
    for rep in range(max(1, args.repeats)):
        loops = [(bare, _bare_cast, renderer), (full, _full_render, renderer), (flat, _full_render, unshadowed)]
        for times, loop, r in (loops if rep % 2 == 0 else loops[::-1]):
            times.append(loop(r, poses, intrinsics))
    t0 = time.perf_counter()
    render_scan(SynthConfig(seed=config.seed, frames=config.frames, width=width, height=height,
                            effects=SensorEffects.realistic()))
    effects_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    clips = list(itertools.islice(iter_training_scans(seed=config.seed, width=width, height=height), args.clips))
    clips_s = time.perf_counter() - t0
    n = config.frames
    result = {
        "width": width, "height": height, "frames": n, "triangles": scene.num_faces,
        "lights": int(len(scene.light_positions)), "bare_cast_fps": n / min(bare), "render_fps": n / min(full),
        "render_no_shadows_fps": n / min(flat),
        "render_vs_bare": min(full) / min(bare), "render_scan_with_effects_fps": n / effects_s,
        "scene_generation_s": scene_s, "texture_library_s": library_s,
        "training_clips_per_s": len(clips) / clips_s, "training_clip_frames": len(clips[0]) if clips else 0,
    }
    if args.json:
        print_json(result)
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"Synthetic rendering, {n} frames {width}x{height}, {scene.num_faces} triangles, "
                        f"{result['lights']} lights")
    for col in ("loop", "frames/s", "vs bare"):
        table.add_column(col)
    table.add_row("ray casting only (rays + Open3D cast_rays)", f"{result['bare_cast_fps']:.1f}", "1.00x")
    table.add_row("recon.synthetic Renderer (color + depth)", f"{result['render_fps']:.1f}",
                  f"{result['render_vs_bare']:.2f}x")
    table.add_row("  the same without shadows", f"{result['render_no_shadows_fps']:.1f}",
                  f"{min(flat) / min(bare):.2f}x")
    table.add_row("render_scan with sensor effects (scene + path + frames)",
                  f"{result['render_scan_with_effects_fps']:.1f}", "")
    Console().print(table)
    print(f"training stream: {result['training_clips_per_s']:.2f} clips/s of {result['training_clip_frames']} frames; "
          f"scene generation {scene_s * 1000:.0f} ms; texture library (once per process) {library_s:.2f} s")
    return 0
