"""A folder of photos of a synthetic room, as a phone user takes them walking round it.

The unordered counterpart of the rendered video: views `step_deg` apart on laps round the
room (`trajectory.orbit_poses`), written under shuffled camera-style names (IMG_NNNN.jpg) so
neither the names nor the file order tell the capture order. Beside the photos, a canonical scan
of the same views under the same names holds the ground truth (poses, depth, mesh) to score
SfM against.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from recon import io as rio
from recon.errors import ReconError
from recon.geometry import equivalent_focal_mm
from recon.scan import Frame, save_scan

from .generate import SynthConfig, _render_frames, _scan, camera_intrinsics, scene_mesh
from .render import Renderer
from .scene import generate_scene
from .textures import texture_library
from .trajectory import orbit_poses

PHOTOS = "photos"
GROUND_TRUTH = "ground_truth"


def orbit_centre(scene, renderer: Renderer, clearance: float) -> np.ndarray:
    """(x, y) a person photographing the room walks round: the floor object (or the middle of them all)
    seen from the most directions. The rooms' walls are plain, and a photo of bare wall registers nowhere;
    with two rooms, the middle of all the furniture can be the wall between them."""
    standing = np.array([(s.pose.x, s.pose.y) for s in scene.solids if s.pose.z == 0 and s.lo[2] == 0])
    if not len(standing):
        raise ReconError(f"synthetic room {scene.summary.get('seed')}: no furniture to photograph")
    candidates = np.concatenate([standing.mean(0, keepdims=True), np.unique(standing.round(2), axis=0)])
    angles = np.radians(np.arange(0, 360, 10))
    radii = np.arange(1.0, 3.51, 0.25)

    def directions_seen(centre: np.ndarray) -> int:
        target = np.array([*centre, 0.8])
        seen = 0
        for a in angles:
            spots = centre + radii[:, None] * np.array([np.cos(a), np.sin(a)])
            seen += any(scene.free_space.distance_at(xy) >= clearance and renderer.sees(np.array([*xy, 1.4]), target)
                        for xy in spots)
        return seen

    return max(candidates, key=directions_seen)


def write_photo_collection(synth: SynthConfig, out_dir: str | os.PathLike, step_deg: float = 25.0,
                           exif: bool = False, portrait_every: int = 0) -> Path:
    """Render `synth.frames` photos of room `synth.seed` with `synth`'s camera, `step_deg` degrees apart:
    `out_dir/photos/IMG_NNNN.jpg` (shuffled names) and `out_dir/ground_truth/` (canonical scan). With `exif`
    each photo carries its 35 mm-equivalent focal length in whole millimetres, as a phone writes it; with
    `portrait_every` N, every N-th photo is saved turned a quarter (a portrait shot; the ground truth keeps
    the landscape camera, whose centre is the same).

    The folder appears only when complete (an existing one is replaced then).
    """
    synth.validate()
    if not 1.0 <= step_deg <= 180.0:
        raise ReconError(f"photos of a collection are 1-180 degrees apart, got {step_deg}")
    library = texture_library(synth.texture_size)
    scene = generate_scene(synth.seed, library, synth.scene)
    intrinsics = camera_intrinsics(synth, np.random.default_rng([synth.seed, 3]))
    renderer = Renderer(scene, library, shadows=synth.shadows)
    clearance = synth.scene.camera_clearance_m
    poses = orbit_poses(scene.free_space, orbit_centre(scene, renderer, clearance), synth.frames, step_deg,
                        np.random.default_rng([synth.seed, 4]), synth.trajectory, clearance, sees=renderer.sees)
    images, depths = _render_frames(renderer, poses, poses, intrinsics, 1.0, synth.effects,
                                    np.random.default_rng([synth.seed, 5]))
    numbers = np.random.default_rng([synth.seed, 7]).choice(9000, size=synth.frames, replace=False) + 1000
    names = [f"IMG_{n:04d}" for n in numbers]
    frames = [Frame(name=name, camera_to_world=pose, source_index=i, image_array=img, depth_array=depth)
              for i, (name, pose, img, depth) in enumerate(zip(names, poses, images, depths))]
    extra = {"seed": int(synth.seed), "generator": "recon.synthetic.collection", "step_deg": step_deg,
             "capture_order": names, "scene": scene.summary}
    scan = _scan(frames, intrinsics, depths, extra)
    out_dir = Path(out_dir)
    with tempfile.TemporaryDirectory(prefix="synth-mesh-") as tmp, rio.atomic_dir(out_dir) as staging:
        mesh_path = Path(tmp) / "gt_mesh.ply"
        scene_mesh(scene, library).export(mesh_path)
        save_scan(scan, staging / GROUND_TRUTH, image_ext=".jpg", gt_mesh_src=mesh_path)
        (staging / PHOTOS).mkdir()
        focal_35mm = round(equivalent_focal_mm(intrinsics.fx, intrinsics.width, intrinsics.height)) if exif else None
        for i, (name, img) in enumerate(zip(names, images)):
            turned = portrait_every and i % portrait_every == 0
            rio.write_image(staging / PHOTOS / f"{name}.jpg", np.ascontiguousarray(np.rot90(img)) if turned else img,
                            95, focal_35mm=focal_35mm)
    return out_dir
