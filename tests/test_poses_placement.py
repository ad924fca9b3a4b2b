"""Photos posed where their own matched pairs say they are not (poses/placement.py) and SfM leaving them unposed."""
import dataclasses

import numpy as np
import pycolmap

from poses.placement import (agrees, direction_angle_deg, grossly_off, misplaced, pair_relative_pose, pose_residuals,
                             rotation_angle_deg)
from poses.sfm import drop_misplaced_photos, pair_residuals
from recon.geometry import backproject_pixels, invert_pose, project, transform_points
from recon.writers import PIXEL_CENTRE, write_colmap_text
from tests.fixtures.box_room import box_room_scan


def _matches(scan, a: int, b: int, n: int = 600, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions (COLMAP's convention) of wall points that frames a and b both see: exact matches."""
    rng = np.random.default_rng(seed)
    fa, fb, intr = scan.frames[a], scan.frames[b], scan.intrinsics
    u, v = rng.integers(0, intr.width, n), rng.integers(0, intr.height, n)  # pixel centres: exact depth
    z = fa.depth_array[v, u].astype(np.float64)
    world = transform_points(fa.camera_to_world, backproject_pixels(u, v, z, intr.K))
    in_b, depth_b = project(transform_points(invert_pose(fb.camera_to_world), world), intr.K)
    seen = (depth_b > 0.1) & (in_b[:, 0] >= 0) & (in_b[:, 0] <= intr.width - 1) & (in_b[:, 1] >= 0) & (
        in_b[:, 1] <= intr.height - 1)
    return np.stack([u, v], 1)[seen] + PIXEL_CENTRE, in_b[seen] + PIXEL_CENTRE


def _relative(scan, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    b_from_a = invert_pose(scan.frames[b].camera_to_world) @ scan.frames[a].camera_to_world
    return b_from_a[:3, :3], b_from_a[:3, 3]


def test_a_pairs_relative_pose_comes_from_its_matches():
    scan = box_room_scan(n_frames=10, width=160, height=120)
    pixels_a, pixels_b = _matches(scan, 0, 1)
    k_inv = np.linalg.inv(scan.intrinsics.K)
    to_camera = lambda px: (np.c_[px - PIXEL_CENTRE, np.ones(len(px))] @ k_inv.T)[:, :2]  # noqa: E731
    r, t = pair_relative_pose(to_camera(pixels_a), to_camera(pixels_b), 1.0 / scan.intrinsics.fx)
    r_true, t_true = _relative(scan, 0, 1)
    assert rotation_angle_deg(r.T @ r_true) < 0.5 and direction_angle_deg(t, t_true) < 2.0
    assert agrees(*pose_residuals((r_true, t_true), (r, t)))
    backwards = pose_residuals((r_true, -t_true), (r, t))  # the opposite direction of travel
    assert not agrees(*backwards) and grossly_off(*backwards)
    turned = np.array([[np.cos(0.2), 0, np.sin(0.2)], [0, 1, 0], [-np.sin(0.2), 0, np.cos(0.2)]])
    residuals = pose_residuals((turned @ r_true, t_true), (r, t))  # 11 degrees of rotation: off, but not grossly
    assert not agrees(*residuals) and not grossly_off(*residuals)


def test_a_photo_none_of_whose_pairs_agree_is_misplaced():
    pairs = [("a", "b", 100, True), ("b", "c", 50, True), ("a", "c", 80, False),
             ("d", "a", 200, False), ("d", "b", 40, False), ("d", "c", 30, False)]
    assert misplaced(pairs) == ["d"]  # a, b and c agree through some pairs; d through none
    assert misplaced(pairs + [("d", "e", 10, True)]) == ["d"]  # 10 of 280 inliers agree: under 5 %
    assert misplaced(pairs + [("d", "e", 30, True)]) == []  # 30 of 300


N_PHOTOS = 16


def test_sfm_leaves_a_misplaced_photo_unposed(tmp_path):
    scan = box_room_scan(n_frames=N_PHOTOS, width=160, height=120)
    names = [f"IMG_{i:04d}.jpg" for i in range(N_PHOTOS)]
    pairs = []
    for a in range(N_PHOTOS):
        for b in range(a + 1, N_PHOTOS):
            pixels_a, pixels_b = _matches(scan, a, b, seed=a * 100 + b)
            if len(pixels_a) >= 15:
                pairs.append((names[a], names[b], pixels_a, pixels_b))
    frames = list(scan.frames)
    pose = frames[4].camera_to_world.copy()
    pose[:3, 3] += [1.5, 0.0, 0.5]  # the model puts photo 4 elsewhere; its matches say where it was taken
    frames[4] = dataclasses.replace(frames[4], camera_to_world=pose)
    write_colmap_text(dataclasses.replace(scan, frames=frames), tmp_path, names)
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert sum(names[4] in (a, b) for a, b, _, _ in pairs) >= 3  # photo 4 has pairs to disagree with
    assert drop_misplaced_photos(rec, pair_residuals(rec, pairs)) == [names[4]]
    assert sorted(im.name for im in rec.images.values() if im.has_pose) == names[:4] + names[5:]


def test_sfm_keeps_every_photo_of_a_consistent_model(tmp_path):
    scan = box_room_scan(n_frames=N_PHOTOS, width=160, height=120)
    names = [f"IMG_{i:04d}.jpg" for i in range(N_PHOTOS)]
    pairs = [(names[a], names[b], *_matches(scan, a, b, seed=a * 100 + b))
             for a in range(N_PHOTOS) for b in range(a + 1, N_PHOTOS)]
    write_colmap_text(scan, tmp_path, names)
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert drop_misplaced_photos(rec, pair_residuals(rec, [p for p in pairs if len(p[2]) >= 15])) == []
    assert len([im for im in rec.images.values() if im.has_pose]) == N_PHOTOS
