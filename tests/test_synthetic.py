"""Synthetic rooms: exact depth, multi-view consistency, handheld paths, determinism, outputs, bad input."""
import dataclasses
import itertools
import json
import math

import cv2
import numpy as np
import pytest
import trimesh

from recon.errors import ReconError
from recon.geometry import reprojection_disagreement
from recon.scan import load_scan
from recon.keyframes import pose_distance
from recon.synthetic import (Renderer, SensorEffects, SynthConfig, generate_scene, iter_training_mix,
                             iter_training_scans, render_scan, texture_library, write_synthetic_scan)
from recon.synthetic.generate import CLOSE_UP_SCENE, CLOSE_UP_WALK
from recon.synthetic.mesh import Pose2D, Solid

SMALL = SynthConfig(seed=3, frames=40, width=160, height=128)


@pytest.fixture(scope="module")
def rendered():
    return render_scan(SMALL)


def _ray_mesh_distances(origin, direction, triangles):
    """Moller-Trumbore against every triangle: ray parameters t of all hits (float64, no Open3D)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = b - a, c - a
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1 / np.where(ok, det, 1), 0)
    s = origin - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    return t[hit]


def test_depth_is_exact_z_of_the_first_surface_hit():
    """Depth at off-centre pixels equals the z (not the ray length) of an independent ray-triangle test."""
    library = texture_library()
    scene = generate_scene(5, library)
    renderer = Renderer(scene, library)
    scan, mesh = render_scan(dataclasses.replace(SMALL, seed=5, frames=1))
    pose, intr = scan.frames[0].camera_to_world, scan.intrinsics
    depth = renderer.render_depth(pose, intr)
    assert np.array_equal(depth, scan.depth(0))
    rng = np.random.default_rng(0)
    u, v = rng.integers(0, intr.width, 40), rng.integers(0, intr.height, 40)
    u[:4], v[:4] = [0, intr.width - 1, 0, intr.width - 1], [0, 0, intr.height - 1, intr.height - 1]  # corners
    dirs_cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones(len(u))], axis=1)
    dirs = dirs_cam @ pose[:3, :3].T
    for k in range(len(u)):
        t = _ray_mesh_distances(pose[:3, 3], dirs[k], mesh.triangles)
        # dirs have camera z = 1, so the nearest hit's parameter t is its z in the camera frame
        assert depth[v[k], u[k]] == pytest.approx(t.min(), abs=2e-4)
    corner_ray_length = np.linalg.norm(dirs_cam[0]) * depth[0, 0]
    assert corner_ray_length > 1.1 * depth[0, 0]  # so z and ray length really differ there


def test_gt_depth_is_consistent_across_views(rendered):
    scan, _ = rendered
    K = scan.intrinsics.K
    medians, overlaps = [], []
    for i in range(0, len(scan) - 5, 5):
        d0, d1 = scan.depth(i), scan.depth(i + 5)
        rel = reprojection_disagreement(d0, d1, K, scan.frames[i].camera_to_world, scan.frames[i + 5].camera_to_world)
        medians.append(np.median(rel))
        overlaps.append(rel.size / d1.size)
    assert max(medians) < 0.005
    assert min(overlaps) > 0.3  # the frames share most of their view, so the median means something
    # A 3 cm pose error is visible at this resolution: the check can fail.
    shifted = scan.frames[5].camera_to_world.copy()
    shifted[:3, 3] += shifted[:3, 0] * 0.03
    rel = reprojection_disagreement(scan.depth(0), scan.depth(5), K, scan.frames[0].camera_to_world, shifted)
    assert np.median(rel) > 2 * max(medians)


def test_room_is_closed_and_every_surface_faces_the_camera(rendered):
    scan, _ = rendered
    library = texture_library()
    scene = generate_scene(SMALL.seed, library, SMALL.scene)
    renderer = Renderer(scene, library)
    normals = scene.face_normals
    for i in range(0, len(scan), 10):
        assert np.all(scan.depth(i) > 0)  # closed shell: every ray hits something
        cast = renderer.cast(scan.frames[i].camera_to_world, scan.intrinsics)
        facing = np.einsum("ij,ji->i", normals[cast["face"]], cast["dirs"])
        assert np.all(facing < 0)


def test_no_two_parts_of_a_scene_overlap():
    """Furniture, clutter, fixtures: no box or cylinder reaches into another (touching is fine)."""
    library = texture_library()
    layouts = set()
    for seed in range(8):
        scene = generate_scene(seed, library)
        layouts.add(scene.summary["layout"])
        solids = scene.solids
        probes = [s.probe_points() for s in solids]
        lo = np.array([p.min(axis=0) for p in probes])
        hi = np.array([p.max(axis=0) for p in probes])
        near = np.all((lo[:, None] < hi[None] - 1e-4) & (lo[None] < hi[:, None] - 1e-4), axis=2)
        np.fill_diagonal(near, False)
        overlapping = [(i, j) for i, j in zip(*np.nonzero(near)) if solids[j].contains(probes[i], 1e-4).any()]
        assert overlapping == [], f"seed {seed}"
        assert len(solids) > 20
    assert layouts == {"rectangular", "L-shaped", "two rooms with a doorway"}
    # The probe can fail: a box 1 cm into its neighbour is caught, one touching it is not.
    table = Solid(Pose2D(), (0.0, 0.0, 0.0), (1.0, 1.0, 0.75))
    into = Solid(Pose2D(0.99, 0.5, 0.3, 0.4), (0.0, 0.0, 0.0), (0.3, 0.3, 0.3))
    touching = Solid(Pose2D(0.2, 0.2, 0.75), (-0.05, -0.05, 0.0), (0.05, 0.05, 0.2), radius=0.05)  # a mug
    assert table.contains(into.probe_points(), 1e-4).any()
    assert not table.contains(touching.probe_points(), 1e-4).any()


def test_a_doorway_as_wide_as_the_shared_wall_allows_still_builds():
    """Scene 1892720134 (training stream seed 800, room 127) leaves the door no slack: it once raised."""
    scene = generate_scene(1892720134, texture_library())
    assert scene.summary["layout"] == "two rooms with a doorway"


def test_camera_moves_like_handheld_video_in_free_space():
    library = texture_library()
    for seed in range(4):
        config = SynthConfig(seed=seed, frames=150, width=64, height=48)
        scan, _ = render_scan(config)
        poses = scan.camera_to_world
        scene = generate_scene(seed, library, config.scene)
        centres = poses[:, :3, 3]
        assert np.all((centres[:, 2] >= 1.2) & (centres[:, 2] <= 1.7))
        clearance = scene.free_space.distance_at(centres[:, :2])
        assert clearance.min() >= 0.9 * config.scene.camera_clearance_m  # never in furniture, never at a wall
        speed = np.linalg.norm(np.diff(centres[:, :2], axis=0), axis=1) * config.fps
        assert 0.15 <= np.median(speed) <= 0.6 and speed.max() < 0.75
        forward = poses[:, :3, 2]
        right = poses[:, :3, 0]
        pitch = np.degrees(np.arcsin(forward[:, 2]))
        roll = np.degrees(np.arcsin(right[:, 2]))
        assert np.all(np.abs(roll) < 6) and np.all((pitch > -40) & (pitch < 15))
        turn = np.degrees(np.arccos(np.clip(np.sum(forward[1:] * forward[:-1], axis=1), -1, 1)))
        assert turn.max() < 12  # smooth: no jumps between video frames
        hfov = math.degrees(2 * math.atan(scan.intrinsics.width / 2 / scan.intrinsics.fx))
        assert 55 <= hfov <= 75
        assert min(d.min() for d in (scan.depth(i) for i in range(0, len(scan), 15))) > 0.2


def test_same_seed_gives_identical_output_and_another_seed_does_not(rendered):
    scan, mesh = rendered
    again, mesh_again = render_scan(SMALL)
    assert np.array_equal(scan.camera_to_world, again.camera_to_world)
    for i in range(len(scan)):
        assert scan.depth(i).tobytes() == again.depth(i).tobytes()
        assert scan.image(i).tobytes() == again.image(i).tobytes()
    assert np.array_equal(mesh.vertices, mesh_again.vertices)
    other, _ = render_scan(dataclasses.replace(SMALL, seed=SMALL.seed + 1, frames=2))
    assert not np.array_equal(other.depth(0), scan.depth(0))


def test_textures_have_physical_scale_and_images_have_structure(rendered):
    library = texture_library()
    scene = generate_scene(SMALL.seed, library)
    edge_m = np.linalg.norm(scene.vertices[:, 1] - scene.vertices[:, 0], axis=1)
    edge_uv = np.linalg.norm(scene.uvs[:, 1] - scene.uvs[:, 0], axis=1)
    tile = np.array([m.tile_m for m in scene.materials])[scene.face_material]
    tiled = tile > 0
    # exact on flat faces; cylinder facets carry arc length, a fraction of a percent longer than the chord
    np.testing.assert_allclose(edge_uv[tiled] * tile[tiled], edge_m[tiled], rtol=0.01)
    brick = library.spec("brick")
    assert 1.0 <= brick.tile_m <= 1.2  # 2 x 2 mirrored photo of 8 courses: a brick is about 20 cm long
    scan, _ = rendered
    image = scan.image(0).astype(np.float32)
    assert 40 < image.mean() < 200  # exposed, not black or blown out
    assert cv2.Laplacian(image.mean(axis=2), cv2.CV_32F).std() > 2  # edges and texture, not a flat fill


def test_sensor_effects_change_only_the_image():
    clean, _ = render_scan(dataclasses.replace(SMALL, frames=12))
    noisy_config = dataclasses.replace(SMALL, frames=12, effects=SensorEffects.realistic())
    noisy, _ = render_scan(noisy_config)
    again, _ = render_scan(noisy_config)
    for i in range(len(noisy)):
        assert np.array_equal(noisy.depth(i), clean.depth(i))
        assert np.array_equal(noisy.image(i), again.image(i))  # seeded
    diff = np.abs(noisy.image(6).astype(np.float32) - clean.image(6).astype(np.float32)).mean()
    assert 1.0 < diff < 40
    assert np.array_equal(noisy.camera_to_world, clean.camera_to_world)


def test_training_clips_have_a_useful_baseline():
    clips = list(itertools.islice(iter_training_scans(seed=1, clip_frames=5, width=96, height=80,
                                                      clips_per_scene=2), 3))
    assert len(clips) == 3
    assert clips[0].metadata.extra["seed"] == clips[1].metadata.extra["seed"] != clips[2].metadata.extra["seed"]
    for clip in clips:
        assert len(clip) == 5 and clip.intrinsics.size == (96, 80)
        assert clip.image(0).shape == (80, 96, 3) and clip.depth(0).shape == (80, 96)
        lo, hi = clip.metadata.depth_range
        assert 0 < lo < hi
        steps = [pose_distance(a, b)[0] for a, b in zip(clip.camera_to_world[:-1], clip.camera_to_world[1:])]
        assert min(steps) >= 0.1 and max(steps) < 0.5


def test_a_keyframe_distance_range_varies_the_baseline_from_room_to_room():
    def mean_steps(distance):
        clips = itertools.islice(iter_training_scans(seed=4, width=48, height=40, clips_per_scene=1,
                                                     keyframe_distance=distance), 6)
        return [float(np.mean([pose_distance(a, b)[0] for a, b in zip(c.camera_to_world[:-1], c.camera_to_world[1:])]))
                for c in clips]

    fixed, ranged = mean_steps(0.2), mean_steps((0.1, 0.5))
    assert max(fixed) - min(fixed) < 0.05 and min(fixed) >= 0.2
    assert max(ranged) - min(ranged) > 0.1 and min(ranged) >= 0.1
    with pytest.raises(ReconError):
        next(iter_training_scans(keyframe_distance=(0.4, 0.2)))


def _near_share(clips) -> float:
    depth = np.concatenate([clip.depth(i).ravel() for clip in clips for i in range(len(clip))])
    return float(np.mean(depth[depth > 0] < 1.0))


def test_close_up_walks_see_more_near_depth():
    rooms = dict(seed=2, width=64, height=48, keyframe_distance=0.2, clips_per_scene=1)
    centred = list(itertools.islice(iter_training_scans(**rooms), 16))
    close = list(itertools.islice(iter_training_scans(**rooms, scene=CLOSE_UP_SCENE, trajectory=CLOSE_UP_WALK), 16))
    assert _near_share(close) > 2 * _near_share(centred) > 0


def test_training_mix_adds_close_ups_as_every_third_clip():
    def sources(close_ups):
        clips = itertools.islice(iter_training_mix(5, (0.25, 10.0), sizes=((48, 40),), close_ups=close_ups), 6)
        return [clip.metadata.extra["training_seed"] for clip in clips]

    assert sources(False) == [5, 55] * 3
    assert sources(True) == [5, 55, 105] * 2


def test_write_scan_with_video_and_transforms(tmp_path):
    config = SynthConfig(seed=2, frames=8, width=96, height=64)
    out = write_synthetic_scan(config, tmp_path / "room", video=True)
    scan = load_scan(out)
    memory, mesh = render_scan(config)
    assert scan.names == memory.names and scan.metadata.metric_scale
    np.testing.assert_allclose(scan.camera_to_world, memory.camera_to_world, atol=1e-12)
    assert np.abs(scan.depth(3) - memory.depth(3)).max() <= 0.0005 + 1e-6  # millimetre PNG
    assert scan.metadata.depth_range == memory.metadata.depth_range
    gt = trimesh.load(out / scan.metadata.gt_mesh, process=False)
    assert len(gt.faces) == len(mesh.faces)
    assert abs(gt.area - mesh.area) < 1e-3 * mesh.area
    video = cv2.VideoCapture(str(out / "video.mp4"))
    sizes = []
    while True:
        ok, frame = video.read()
        if not ok:
            break
        sizes.append(frame.shape)
    assert sizes == [(64, 96, 3)] * 8
    doc = json.loads((out / "transforms.json").read_text())
    assert doc["w"] == 96 and doc["cx"] == pytest.approx(scan.intrinsics.cx + 0.5)
    for frame, entry in zip(scan.frames, doc["frames"]):
        assert (out / entry["file_path"]).is_file()
        gl = np.array(entry["transform_matrix"])
        np.testing.assert_allclose(gl @ np.diag([1.0, -1.0, -1.0, 1.0]), frame.camera_to_world, atol=1e-12)


def test_bad_input_is_one_line_and_exit_code_2(tmp_path, capsys):
    from apps.cli import main

    for bad in (dataclasses.replace(SMALL, frames=0), dataclasses.replace(SMALL, width=0),
                dataclasses.replace(SMALL, height=100000), dataclasses.replace(SMALL, fps=0.0)):
        with pytest.raises(ReconError):
            render_scan(bad)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ReconError, match="not a folder"):
        write_synthetic_scan(dataclasses.replace(SMALL, frames=1), blocker / "scan")
    with pytest.raises(ReconError, match="even"):
        write_synthetic_scan(dataclasses.replace(SMALL, frames=1, width=161), tmp_path / "odd", video=True)
    for args in (["--frames", "0"], ["--size", "0x10"], ["--size", "big"], ["--out", str(blocker / "x")]):
        argv = ["synth", "--out", str(tmp_path / "cli")] + args
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("recon: error: ") and err.count("\n") == 1


def test_cli_writes_a_scan(tmp_path, capsys):
    from apps.cli import main

    assert main(["synth", "--out", str(tmp_path / "s"), "--frames", "3", "--size", "64x48", "--seed", "4",
                 "--preview", str(tmp_path / "sheet.png")]) == 0
    assert "3 frames 64x48" in capsys.readouterr().out
    scan = load_scan(tmp_path / "s")
    assert len(scan) == 3 and scan.has_depth and (tmp_path / "s" / "gt_mesh.ply").is_file()
    assert cv2.imread(str(tmp_path / "sheet.png")).shape[0] > 0


def test_bench_reports_frame_rates(capsys):
    import argparse

    from apps.bench import synth as bench

    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    assert bench.run(parser.parse_args(["--size", "64x48", "--frames", "4", "--clips", "1", "--repeats", "1",
                                        "--json"])) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["width"], result["height"], result["frames"]) == (64, 48, 4)
    assert result["render_fps"] > 0 and result["bare_cast_fps"] > 0 and result["render_vs_bare"] > 0
    assert result["training_clips_per_s"] > 0 and result["training_clip_frames"] == 5
