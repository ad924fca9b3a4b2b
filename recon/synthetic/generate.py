"""Synthetic scans: scene + trajectory + renderer -> a canonical `Scan` with exact GT depth and mesh.

Three uses: test fixtures and demo input (`render_scan`, `write_synthetic_scan`,
optionally with an .mp4 video and a nerfstudio `transforms.json`), and training
data (`iter_training_scans`, short clips with a useful baseline, streamed in memory).
Random streams are split by purpose ([seed, 1..2] scene, [seed, 3] camera,
[seed, 4] path, [seed, 5] sensor effects), so e.g. switching effects on does not
change the room or the path.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import trimesh

from recon import io as rio
from recon.errors import ReconError
from recon.keyframes import KeyframeConfig, select_keyframes
from recon.scan import Frame, Intrinsics, Scan, ScanMetadata, save_scan
from recon.writers import nerfstudio_transforms

from .effects import SensorEffects, apply_image_effects, camera_gains, image_motion_px
from .render import Renderer
from .scene import Scene, SceneConfig, generate_scene
from .textures import TextureLibrary, linear_to_srgb, texture_library
from .trajectory import TrajectoryConfig, handheld_trajectory

MAX_IMAGE_SIDE = 4096
MIN_IMAGE_SIDE = 16
VIDEO_FILE = "video.mp4"
TRANSFORMS_FILE = "transforms.json"


@dataclass(frozen=True)
class SynthConfig:
    """One synthetic capture: which room (seed), how many frames, camera and sensor."""

    seed: int = 0
    frames: int = 90
    width: int = 320
    height: int = 256
    fps: float = 30.0
    hfov_deg: float | None = None  # None: drawn per seed from hfov_range_deg, like different phones
    hfov_range_deg: tuple[float, float] = (55.0, 75.0)
    effects: SensorEffects = field(default_factory=SensorEffects)
    scene: SceneConfig = field(default_factory=SceneConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    texture_size: int = 256
    shadows: bool = True  # hard shadows from the main ceiling light (one more ray cast per frame)

    def validate(self) -> "SynthConfig":
        if not isinstance(self.frames, (int, np.integer)) or self.frames < 1:
            raise ReconError(f"synthetic scan needs at least one frame, got {self.frames}")
        for name, value in (("width", self.width), ("height", self.height)):
            if not isinstance(value, (int, np.integer)) or not MIN_IMAGE_SIDE <= value <= MAX_IMAGE_SIDE:
                raise ReconError(f"image {name} must be an integer in [{MIN_IMAGE_SIDE}, {MAX_IMAGE_SIDE}], "
                                 f"got {value}")
        if not 1 <= self.fps <= 240:
            raise ReconError(f"fps must be in [1, 240], got {self.fps}")
        if self.hfov_deg is not None and not 20 <= self.hfov_deg <= 150:
            raise ReconError(f"horizontal field of view must be in [20, 150] degrees, got {self.hfov_deg}")
        self.effects.validate()
        return self


def camera_intrinsics(config: SynthConfig, rng: np.random.Generator) -> Intrinsics:
    """Pinhole camera with square pixels and a principal point within 1 % of the image centre."""
    hfov = config.hfov_deg if config.hfov_deg is not None else rng.uniform(*config.hfov_range_deg)
    fx = config.width / 2 / math.tan(math.radians(hfov) / 2)
    cx = (config.width - 1) / 2 + rng.uniform(-0.01, 0.01) * config.width
    cy = (config.height - 1) / 2 + rng.uniform(-0.01, 0.01) * config.height
    return Intrinsics(fx, fx, cx, cy, config.width, config.height)


def scene_mesh(scene: Scene, library: TextureLibrary) -> trimesh.Trimesh:
    """The scene as a trimesh with face colors (mean albedo) and a per-face `material` attribute."""
    n = scene.num_faces
    mesh = trimesh.Trimesh(vertices=scene.vertices.reshape(-1, 3), faces=np.arange(3 * n).reshape(n, 3),
                           process=False)
    mean = library.mean_linear[[m.texture for m in scene.materials]] * np.array([m.tint for m in scene.materials])
    colors = np.round(np.clip(linear_to_srgb(np.clip(mean, 0, 1)), 0, 1) * 255).astype(np.uint8)
    mesh.visual.face_colors = np.concatenate([colors[scene.face_material], np.full((n, 1), 255, np.uint8)], 1)
    mesh.face_attributes["material"] = scene.face_material.copy()
    mesh.merge_vertices()  # shares corners between faces; keeps the faces and their order
    return mesh


def _render_frames(renderer: Renderer, poses: np.ndarray, previous_poses: np.ndarray, intrinsics: Intrinsics,
                   fps: float, effects: SensorEffects,
                   rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Color (uint8 RGB) and depth (float32 m) for each pose; exposure metered on the first frame.

    `previous_poses[i]` is where the camera was one video frame before `poses[i]` (for motion blur).
    """
    images, depths = [], []
    gains = camera_gains(effects, len(poses), fps, rng)
    exposure = None
    for i, pose in enumerate(poses):
        radiance, depth = renderer.render_linear(pose, intrinsics)
        if exposure is None:
            exposure = renderer.auto_exposure(radiance)
        image = renderer.tone_map(radiance, exposure * gains[i])
        motion = image_motion_px(previous_poses[i], pose, depth, intrinsics) if effects.motion_blur > 0 else None
        images.append(apply_image_effects(image, effects, rng, motion))
        depths.append(depth)
    return images, depths


def _depth_range(depths: list[np.ndarray]) -> tuple[float, float]:
    valid = np.concatenate([d[d > 0] for d in depths]) if depths else np.zeros(0)
    if valid.size == 0:
        return (0.1, 10.0)
    return (math.floor(float(valid.min()) * 10) / 10, math.ceil(float(valid.max()) * 10) / 10)


def _scan(frames: list[Frame], intrinsics: Intrinsics, depths: list[np.ndarray], extra: dict) -> Scan:
    meta = ScanMetadata(metric_scale=True, source=f"synthetic room, seed {extra['seed']}", source_format="synthetic",
                        depth_range=_depth_range(depths), extra=extra)
    return Scan(intrinsics, frames, meta).validate()


def render_scan(config: SynthConfig) -> tuple[Scan, trimesh.Trimesh]:
    """Render a synthetic capture in memory: the scan (frames hold image/depth arrays) and its GT mesh."""
    config.validate()
    library = texture_library(config.texture_size)
    scene = generate_scene(config.seed, library, config.scene)
    renderer = Renderer(scene, library, shadows=config.shadows)
    intrinsics = camera_intrinsics(config, np.random.default_rng([config.seed, 3]))
    poses = handheld_trajectory(scene.free_space, config.frames, config.fps, np.random.default_rng([config.seed, 4]),
                                config.trajectory, config.scene.camera_clearance_m)
    previous = np.concatenate([poses[:1], poses[:-1]])
    images, depths = _render_frames(renderer, poses, previous, intrinsics, config.fps, config.effects,
                                    np.random.default_rng([config.seed, 5]))
    frames = [Frame(name=f"frame_{i:06d}", camera_to_world=pose, timestamp=i / config.fps, source_index=i,
                    image_array=img, depth_array=depth)
              for i, (pose, img, depth) in enumerate(zip(poses, images, depths))]
    extra = {"seed": int(config.seed), "generator": "recon.synthetic", "fps": config.fps,
             "hfov_deg": round(math.degrees(2 * math.atan(config.width / 2 / intrinsics.fx)), 3),
             "effects": dataclasses.asdict(config.effects), "scene": scene.summary}
    return _scan(frames, intrinsics, depths, extra), scene_mesh(scene, library)


def _check_output_folder(out_dir: Path) -> None:
    """Fail before rendering if the output cannot be written (not after minutes of work)."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ReconError(f"{out_dir}: exists and is not a folder")
    parent = out_dir.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ReconError(f"{out_dir}: cannot create the output folder ({parent} is not a folder)")
    try:
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as exc:
        raise ReconError(f"{out_dir}: output folder is not writable ({exc.strerror or exc})") from None


def write_video(scan: Scan, folder: Path, fps: float) -> None:
    """`video.mp4` (mp4v) of the scan's frames plus `transforms.json` with their poses (nerfstudio).

    transforms.json follows nerfstudio: OpenGL camera axes, and pixel centres at +0.5, so cx, cy are
    the canonical (integer-centre) values plus 0.5. Its frames point at the scan's images and depth.
    """
    intr = scan.intrinsics
    path = folder / VIDEO_FILE
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (intr.width, intr.height))
    if not writer.isOpened():
        raise ReconError(f"{path}: OpenCV cannot write mp4v video at {intr.width}x{intr.height}")
    try:
        for i in range(len(scan)):
            writer.write(cv2.cvtColor(scan.image(i), cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    doc = nerfstudio_transforms(scan, [f"images/{f.name}.jpg" for f in scan.frames])
    for i, (entry, f) in enumerate(zip(doc["frames"], scan.frames)):
        entry.update({"timestamp": f.timestamp, "video_frame": i})
        if f.has_depth:
            entry["depth_file_path"] = f"depth/{f.name}.png"
    doc.update({"depth_unit_scale_factor": 0.001, "video_path": VIDEO_FILE, "fps": fps})
    rio.write_json_atomic(folder / TRANSFORMS_FILE, doc)


def write_synthetic_scan(config: SynthConfig, out_dir: str | os.PathLike, video: bool = False) -> Path:
    """Render and write a canonical scan folder with `gt_mesh.ply` (and `video.mp4` + `transforms.json`).

    The folder appears only when complete (an existing one is replaced then).
    """
    config.validate()
    if video and (config.width % 2 or config.height % 2):
        raise ReconError(f"--video needs an even image size (mp4v), got {config.width}x{config.height}")
    out_dir = Path(out_dir)
    _check_output_folder(out_dir)
    scan, mesh = render_scan(config)
    try:
        with tempfile.TemporaryDirectory(prefix="synth-mesh-") as tmp, rio.atomic_dir(out_dir) as staging:
            mesh_path = Path(tmp) / "gt_mesh.ply"
            mesh.export(mesh_path)
            save_scan(scan, staging, image_ext=".jpg", gt_mesh_src=mesh_path)
            if video:
                write_video(scan, staging, config.fps)
    except OSError as exc:
        raise ReconError(f"{out_dir}: could not write the synthetic scan ({exc})") from None
    return out_dir


def iter_training_scans(seed: int = 0, clip_frames: int = 5, width: int = 320, height: int = 256,
                        keyframe_distance: float | tuple[float, float] = 0.1, clips_per_scene: int = 8,
                        effects: SensorEffects = SensorEffects(), scene: SceneConfig = SceneConfig(),
                        trajectory: TrajectoryConfig = TrajectoryConfig(), fps: float = 30.0,
                        hfov_range_deg: tuple[float, float] = (55.0, 75.0), shadows: bool = True,
                        sizes: tuple[tuple[int, int], ...] | None = None) -> Iterator[Scan]:
    """Endless short in-memory clips for training: a new room every `clips_per_scene` clips.

    Each clip is `clip_frames` consecutive keyframes of one handheld walk, a keyframe being taken
    whenever the camera moved `keyframe_distance` (the DESIGN's pose distance) since the last one,
    so neighbours have a baseline a multi-view network can triangulate from. `sizes`: image sizes
    (width, height) each room draws one of (aspect ratios, portrait and landscape); default
    width x height. A (min, max) `keyframe_distance`: each room draws its own from that range, so the
    same depth shows a different parallax from room to room.
    """
    distances = keyframe_distance if isinstance(keyframe_distance, tuple) else (keyframe_distance,) * 2
    if clip_frames < 1 or clips_per_scene < 1 or not 0 <= distances[0] <= distances[1]:
        raise ReconError("training clips need clip_frames >= 1, clips_per_scene >= 1, 0 <= keyframe_distance "
                         "(a (min, max) range: min <= max)")
    base = SynthConfig(seed=seed, frames=clip_frames, width=width, height=height, fps=fps, effects=effects,
                       scene=scene, trajectory=trajectory, hfov_range_deg=hfov_range_deg, shadows=shadows).validate()
    library = texture_library(base.texture_size)
    for scene_index in itertools.count():
        scene_seed = int(np.random.SeedSequence([seed, scene_index]).generate_state(1)[0] & 0x7FFFFFFF)
        config = dataclasses.replace(base, seed=scene_seed)
        if sizes:
            w, h = sizes[int(np.random.default_rng([scene_seed, 6]).integers(len(sizes)))]
            config = dataclasses.replace(config, width=int(w), height=int(h)).validate()
        room = generate_scene(scene_seed, library, scene)
        renderer = Renderer(room, library, shadows=shadows)
        intrinsics = camera_intrinsics(config, np.random.default_rng([scene_seed, 3]))
        distance = float(np.random.default_rng([scene_seed, 7]).uniform(*distances))
        # About 8 frames per keyframe at walking pace; a longer walk than needed costs nothing (poses only).
        walk_frames = int(clip_frames * clips_per_scene * 10 * max(1.0, distance / 0.1))
        poses = handheld_trajectory(room.free_space, walk_frames, fps, np.random.default_rng([scene_seed, 4]),
                                    trajectory, scene.camera_clearance_m)
        keyframes = select_keyframes(poses, KeyframeConfig(keyframe_distance=distance))
        effects_rng = np.random.default_rng([scene_seed, 5])
        for clip in range(min(clips_per_scene, len(keyframes) // clip_frames)):
            indices = keyframes[clip * clip_frames:(clip + 1) * clip_frames]
            previous = poses[np.maximum(np.array(indices) - 1, 0)]
            images, depths = _render_frames(renderer, poses[indices], previous, intrinsics, fps, effects, effects_rng)
            frames = [Frame(name=f"frame_{i:06d}", camera_to_world=poses[i], timestamp=i / fps, source_index=i,
                            image_array=img, depth_array=depth) for i, img, depth in zip(indices, images, depths)]
            extra = {"seed": scene_seed, "generator": "recon.synthetic", "clip": clip,
                     "training_seed": int(seed), "scene": room.summary}
            yield _scan(frames, intrinsics, depths, extra)


# Image sizes of about 320x256 pixels in the aspect ratios phones and headsets record:
# 4:3, 16:9, 5:4 landscape and 3:4, 9:16 portrait.
TRAINING_SIZES = ((320, 240), (352, 198), (320, 256), (240, 320), (198, 352))


# Walks that pass close to walls and furniture and look at them (away from the room's middle, with wide
# look-arounds and more looking down), in rooms up to 12 m across: 3-7 times the share of depth under 1 m
# that room-centred walks show; near surfaces are where the network errs most (docs/depth.md).
CLOSE_UP_SCENE = SceneConfig(room_width_m=(3.0, 12.0), camera_clearance_m=0.3)
CLOSE_UP_WALK = TrajectoryConfig(pitch_deg=(-50.0, -3.0), look_at_room=-0.7, sweep_deg=(30.0, 70.0))


def iter_training_mix(seed: int, depth_range: tuple[float, float],
                      keyframe_distance: float | tuple[float, float] = 0.2,
                      hfov_range_deg: tuple[float, float] = (45.0, 90.0),
                      sizes: tuple[tuple[int, int], ...] = TRAINING_SIZES, clips_per_scene: int = 8,
                      close_ups: bool = False) -> Iterator[Scan]:
    """The depth network's training stream: clean clips alternating with clips that carry realistic
    sensor effects (noise, motion blur, exposure and white-balance drift, JPEG), cameras of 45-90
    degrees in several aspect ratios, and one fixed `depth_range` (so planes mean the same metres in
    every clip and at inference). Keyframes 0.2 apart: about the baseline inference picks for sources
    (a (min, max) range: each room draws its own).
    `close_ups`: every third clip from a close-up walk (CLOSE_UP_SCENE, CLOSE_UP_WALK) with sensor effects.
    """
    variants = [(0, SensorEffects(), SceneConfig(), TrajectoryConfig()),
                (50, SensorEffects.realistic(), SceneConfig(), TrajectoryConfig())]
    if close_ups:
        variants.append((100, SensorEffects.realistic(), CLOSE_UP_SCENE, CLOSE_UP_WALK))
    streams = [iter_training_scans(seed=seed + offset, keyframe_distance=keyframe_distance, effects=effects,
                                   scene=scene, trajectory=walk, hfov_range_deg=hfov_range_deg, sizes=sizes,
                                   clips_per_scene=clips_per_scene)
               for offset, effects, scene, walk in variants]
    for group in zip(*streams):
        for scan in group:
            scan.metadata = dataclasses.replace(scan.metadata, depth_range=tuple(depth_range))
            yield scan
