"""Keyframe selection by combined pose distance, and source choice for baseline."""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon.errors import ReconError
from recon.keyframes import KeyframeConfig, SourceConfig, pose_distance, select_keyframes, select_sources


def line_poses(n: int, step: float) -> np.ndarray:
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    poses[:, 0, 3] = np.arange(n) * step
    return poses


def test_pose_distance_translation_and_rotation():
    a = np.eye(4)
    b = np.eye(4)
    b[:3, 3] = [0.03, 0.04, 0.0]
    assert pose_distance(a, b) == pytest.approx((0.05, 0.0, 0.05))
    c = np.eye(4)
    theta = math.radians(10)
    c[:3, :3] = Rotation.from_euler("y", theta).as_matrix()
    combined, rot, trans = pose_distance(a, c)
    # trace = 1 + 2 cos(theta): r = sqrt(2 (1 - trace / 3)) = sqrt(4/3 (1 - cos theta))
    assert rot == pytest.approx(math.sqrt(4 / 3 * (1 - math.cos(theta))))
    assert (combined, trans) == pytest.approx((rot, 0.0))
    # Relative pose is measured in the first camera's frame: the same motion seen from a rotated
    # and moved start gives the same distance.
    start = np.eye(4)
    start[:3, :3] = Rotation.from_euler("xyz", [0.3, -1.0, 2.0]).as_matrix()
    start[:3, 3] = [5.0, -2.0, 1.0]
    assert pose_distance(start, start @ b)[0] == pytest.approx(0.05)


def test_keyframes_every_tenth_centimetre_step():
    poses = line_poses(51, 0.01)  # 1 cm per frame along x
    keys = select_keyframes(poses, KeyframeConfig(keyframe_distance=0.0999))  # clear of float round-off
    assert keys == [0, 10, 20, 30, 40, 50]


def test_keyframes_from_rotation_only():
    poses = np.repeat(np.eye(4)[None], 40, axis=0)
    for i in range(40):
        poses[i, :3, :3] = Rotation.from_euler("y", math.radians(i)).as_matrix()  # 1 degree per frame
    keys = select_keyframes(poses)
    # r(theta) = 0.1 at theta = acos(1 - 0.0075) = 7.02 degrees -> every 8th frame.
    assert keys == [0, 8, 16, 24, 32]


def test_keyframes_reject_bad_shape():
    with pytest.raises(ReconError):
        select_keyframes(np.zeros((3, 3, 4)))


def test_sources_prefer_the_optimal_baseline():
    poses = line_poses(101, 0.01)
    keys = select_keyframes(poses, KeyframeConfig(keyframe_distance=0.0499))  # every 5 cm
    cfg = SourceConfig(num_sources=2, source_window=4, source_baseline=0.15)
    sources = {keys[i]: [keys[j] for j in s] for i, s in select_sources(poses[keys], cfg).items()}
    # For the keyframe at 50 cm the best baselines are 15 cm either side (35 and 65 cm).
    assert sorted(sources[50]) == [35, 65]
    # At the start only later keyframes exist: 15 cm, then 10 cm or 20 cm (equal penalty; nearer wins).
    assert sources[0] == [15, 10]
    online = select_sources(poses[keys], SourceConfig(num_sources=2, window="online"))
    online = {keys[i]: [keys[j] for j in s] for i, s in online.items()}
    assert all(s < k for k, ss in online.items() for s in ss)
    assert sorted(online[50]) == [35, 40]
    with pytest.raises(ReconError, match="source window"):
        select_sources(poses, SourceConfig(window="sideways"))
    with pytest.raises(ReconError, match="keyframe-distance"):
        KeyframeConfig(keyframe_distance=-1).validate()
