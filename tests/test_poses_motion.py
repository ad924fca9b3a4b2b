"""Blocks of video frames posed away from the path (poses/motion.py) and SfM leaving them unposed."""
import dataclasses

import numpy as np
import pycolmap

from poses.motion import displaced_blocks
from poses.sfm import drop_displaced_blocks
from recon.writers import write_colmap_text
from tests.fixtures.box_room import box_room_scan


def _walk(n: int = 120, seed: int = 0) -> np.ndarray:
    """(n, 3) a handheld-like path: a curve with uneven speed, about 3 cm per frame."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(0.03 * (1.0 + 0.5 * np.sin(np.arange(n) / 7.0)) + 0.005 * rng.random(n))
    return np.stack([np.cos(t / 2.0) * 2.0, np.sin(t / 2.0) * 2.0, 0.05 * np.sin(t * 3.0)], axis=1)


def test_a_block_registered_one_texture_repeat_away_is_found():
    centres, index = _walk(), np.arange(120)
    centres[60:80] += [1.5, -0.8, 0.0]  # 20 frames posed 1.7 m away, as one rigid block
    blocks = displaced_blocks(index, centres)
    assert [b.tolist() for b in blocks] == [list(range(60, 80))]


def test_a_smooth_walk_with_fast_stretches_and_missing_frames_keeps_every_frame():
    centres = _walk(seed=1)
    centres[40:50] = centres[40] + 4.0 * (centres[40:50] - centres[40])  # a quick dash: 4 times the speed
    keep = np.setdiff1d(np.arange(120), [10, 11, 12, 13, 90])  # frames that did not register
    assert displaced_blocks(keep, centres[keep]) == []


def test_a_single_jump_or_a_long_block_is_left_alone():
    centres, index = _walk(seed=2), np.arange(120)
    one_jump = centres.copy()
    one_jump[70:] += [2.0, 0.0, 0.0]  # which side is wrong cannot be told
    assert displaced_blocks(index, one_jump) == []
    long_block = centres.copy()
    long_block[20:80] += [2.0, 0.0, 0.0]  # half the video: not taken for the displaced part
    assert displaced_blocks(index, long_block) == []


def test_sfm_leaves_a_displaced_block_unposed(tmp_path):
    scan = box_room_scan(n_frames=30)
    frames = list(scan.frames)
    for i in range(12, 18):  # six frames moved 2 m, far beyond the few centimetres between frames
        pose = frames[i].camera_to_world.copy()
        pose[:3, 3] += [2.0, 0.0, 0.0]
        frames[i] = dataclasses.replace(frames[i], camera_to_world=pose)
    names = [f"{f.name}.jpg" for f in frames]
    write_colmap_text(dataclasses.replace(scan, frames=frames), tmp_path, names)
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert drop_displaced_blocks(rec, names) == names[12:18]
    assert sorted(im.name for im in rec.images.values() if im.has_pose) == sorted(names[:12] + names[18:])
