"""Camera paths that move like a handheld phone video of a room.

The path is a centripetal Catmull-Rom spline through waypoints drawn in the room's
free space (every straight leg between waypoints keeps the camera's clearance, and
the spline is checked densely too), walked at a speed that drifts between the
configured limits. The view follows the walking direction, sweeps left and right,
sometimes turns fast to glance at something and back, and carries a small
hand shake in pitch, roll and height.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.ndimage import gaussian_filter1d

from recon.errors import ReconError

from .scene import FreeSpace

UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class TrajectoryConfig:
    """How the person holding the camera walks and looks (metres, seconds, degrees)."""

    height_m: tuple[float, float] = (1.2, 1.7)
    speed_mps: tuple[float, float] = (0.2, 0.6)
    sweep_deg: tuple[float, float] = (10.0, 35.0)  # amplitude of the left-right look-around
    sweep_period_s: tuple[float, float] = (4.0, 10.0)
    fast_turns_per_s: float = 0.08
    fast_turn_deg: tuple[float, float] = (45.0, 100.0)
    pitch_deg: tuple[float, float] = (-25.0, -3.0)  # negative looks down
    shake_deg: float = 0.8  # hand shake amplitude in pitch, roll and yaw
    heading_smoothing_s: float = 1.0
    look_at_room: float = 0.7  # how strongly the view turns from the walking direction to the room's middle


def smooth_noise(t: np.ndarray, rng: np.random.Generator, freq_hz: tuple[float, float], terms: int = 4) -> np.ndarray:
    """A smooth random signal of t with roughly unit amplitude (a few sinusoids, random phases)."""
    freqs = rng.uniform(*freq_hz, size=terms)
    phases = rng.uniform(0, 2 * np.pi, size=terms)
    weights = rng.uniform(0.5, 1.0, size=terms)
    signal = (weights[:, None] * np.sin(2 * np.pi * freqs[:, None] * t[None] + phases[:, None])).sum(0)
    return signal / weights.sum() * 2.0


def _segment_clear(free: FreeSpace, a: np.ndarray, b: np.ndarray, clearance: float) -> bool:
    n = max(2, int(np.linalg.norm(b - a) / (free.resolution_m * 2)) + 1)
    pts = a + np.linspace(0, 1, n)[:, None] * (b - a)
    return bool(np.all(free.distance_at(pts) >= clearance))


def _waypoints(free: FreeSpace, rng: np.random.Generator, length_m: float, clearance: float) -> np.ndarray:
    """Points in free space joined by clear straight legs, totalling at least `length_m`."""
    cells = free.cell_centres(free.walkable & (free.distance_m >= clearance))
    if len(cells) == 0:
        raise ReconError("synthetic room has no free space for the camera")
    roomy = free.cell_centres(free.walkable & (free.distance_m >= clearance + 0.2))
    start_pool = roomy if len(roomy) else cells
    points = [start_pool[int(rng.integers(len(start_pool)))]]
    total = 0.0
    while total < length_m or len(points) < 4:
        here = points[-1]
        heading = points[-1] - points[-2] if len(points) > 1 else None
        candidates = cells[rng.integers(len(cells), size=40)]
        chosen = None
        for c in candidates:
            dist = np.linalg.norm(c - here)
            if not 0.8 <= dist <= 3.0:
                continue
            if heading is not None and np.dot(c - here, heading) < -0.5 * dist * np.linalg.norm(heading):
                continue  # people rarely turn right around
            if _segment_clear(free, here, c, clearance):
                chosen = c
                break
        if chosen is None:  # cornered: walk back the way we came
            chosen = points[-2] if len(points) > 1 else cells[int(rng.integers(len(cells)))]
        total += float(np.linalg.norm(chosen - here))
        points.append(chosen)
    return np.array(points)


def catmull_rom(points: np.ndarray, samples_per_segment: int = 24) -> np.ndarray:
    """Centripetal Catmull-Rom spline through all points (no overshoot loops), densely sampled."""
    padded = np.concatenate([2 * points[:1] - points[1:2], points, 2 * points[-1:] - points[-2:-1]])
    out = []
    for k in range(1, len(padded) - 2):
        p0, p1, p2, p3 = padded[k - 1:k + 3]
        t0 = 0.0
        t1 = t0 + max(np.linalg.norm(p1 - p0), 1e-6) ** 0.5
        t2 = t1 + max(np.linalg.norm(p2 - p1), 1e-6) ** 0.5
        t3 = t2 + max(np.linalg.norm(p3 - p2), 1e-6) ** 0.5
        t = np.linspace(t1, t2, samples_per_segment, endpoint=False)[:, None]
        a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
        a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
        a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
        b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
        b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
        out.append((t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2)
    out.append(points[-1:])
    return np.concatenate(out)


def _clear_path(free: FreeSpace, rng: np.random.Generator, length_m: float, clearance: float) -> np.ndarray:
    """A dense, smooth, collision-free path at least `length_m` long."""
    waypoints = _waypoints(free, rng, length_m, clearance)
    for _ in range(6):
        path = catmull_rom(waypoints)
        if np.all(free.distance_at(path) >= 0.9 * clearance):
            return path
        # The curve cut a corner: more waypoints along the (clear) legs pull it onto them.
        mids = (waypoints[:-1] + waypoints[1:]) / 2
        merged = np.empty((len(waypoints) + len(mids), 2))
        merged[0::2], merged[1::2] = waypoints, mids
        waypoints = merged
    return path


def look_rotation(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(N, 3, 3) camera-to-world rotations (OpenCV axes) from yaw about world z, pitch up, roll."""
    forward = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], axis=1)
    right = np.cross(forward, UP)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    down = np.cross(forward, right)
    c, s = np.cos(roll)[:, None], np.sin(roll)[:, None]
    right, down = c * right + s * down, -s * right + c * down
    return np.stack([right, down, forward], axis=2)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0, 1)
    return x * x * (3 - 2 * x)


def handheld_trajectory(free: FreeSpace, frames: int, fps: float, rng: np.random.Generator,
                        config: TrajectoryConfig = TrajectoryConfig(), clearance: float = 0.45) -> np.ndarray:
    """(frames, 4, 4) camera-to-world poses sampled at `fps` along a walk through `free`."""
    t = np.arange(frames) / fps
    lo, hi = config.speed_mps
    mean_speed = rng.uniform(lo + 0.05 * (hi - lo), hi - 0.3 * (hi - lo))
    speed = np.clip(mean_speed + 0.35 * (hi - lo) * smooth_noise(t, rng, (0.05, 0.25)), lo, hi)
    walked = np.concatenate([[0.0], np.cumsum(speed[:-1] / fps)])
    path = _clear_path(free, rng, walked[-1] + 1.0, clearance)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    xy = np.stack([np.interp(walked, along, path[:, k]) for k in (0, 1)], axis=1)
    ahead = np.stack([np.interp(walked + 0.3, along, path[:, k]) for k in (0, 1)], axis=1)
    # Look where you walk, but drawn towards the middle of the room: people film the room, not the wall.
    walking = ahead - xy
    walking /= np.maximum(np.linalg.norm(walking, axis=1, keepdims=True), 1e-9)
    open_cells = free.walkable * free.distance_m
    centre = (free.cell_centres(open_cells > 0) * open_cells[open_cells > 0][:, None]).sum(0) / open_cells.sum()
    to_centre = centre - xy
    dist = np.linalg.norm(to_centre, axis=1, keepdims=True)
    look = walking + config.look_at_room * np.clip(dist / 1.5, 0, 1) * to_centre / np.maximum(dist, 1e-9)
    heading = np.unwrap(np.arctan2(look[:, 1], look[:, 0]))
    heading = gaussian_filter1d(heading, config.heading_smoothing_s * fps, mode="nearest")

    sweep = math.radians(rng.uniform(*config.sweep_deg)) * np.sin(
        2 * np.pi * t / rng.uniform(*config.sweep_period_s) + rng.uniform(0, 2 * np.pi))
    glances = np.zeros(frames)
    duration = frames / fps
    for _ in range(rng.poisson(config.fast_turns_per_s * duration)):
        start, turn = rng.uniform(0, duration), math.radians(rng.uniform(*config.fast_turn_deg)) * rng.choice([-1, 1])
        up, hold, back = rng.uniform(0.4, 0.8), rng.uniform(0.5, 2.0), rng.uniform(1.5, 3.0)
        glances += turn * (_smoothstep((t - start) / up) - _smoothstep((t - start - up - hold) / back))
    shake = math.radians(config.shake_deg)
    yaw = heading + sweep + glances + shake * smooth_noise(t, rng, (0.5, 3.0))
    pitch = (math.radians(rng.uniform(*config.pitch_deg)) + math.radians(6) * smooth_noise(t, rng, (0.03, 0.15))
             + shake * smooth_noise(t, rng, (0.5, 3.0)))
    roll = shake * 1.5 * smooth_noise(t, rng, (0.3, 2.0))
    h_lo, h_hi = config.height_m
    base_height = rng.uniform(h_lo + 0.1, h_hi - 0.1)
    height = np.clip(base_height + 0.06 * smooth_noise(t, rng, (0.05, 0.2))
                     + 0.008 * np.sin(2 * np.pi * 1.8 * t + rng.uniform(0, 2 * np.pi)), h_lo, h_hi)

    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = look_rotation(yaw, pitch, roll)
    poses[:, :2, 3] = xy
    poses[:, 2, 3] = height
    return poses


def orbit_poses(free: FreeSpace, centre: np.ndarray, views: int, step_deg: float, rng: np.random.Generator,
                config: TrajectoryConfig = TrajectoryConfig(), clearance: float = 0.45,
                radius_m: tuple[float, float] = (1.0, 3.5),
                sees: Callable[[np.ndarray, np.ndarray], bool] | None = None) -> np.ndarray:
    """(views, 4, 4) camera-to-world poses of photos taken walking round `centre` (x, y), each aimed at it.

    A photo collection rather than a video: consecutive views are `step_deg` apart round the
    centre (wide baselines), walked for several laps when views x step exceeds 360 degrees. Each
    lap has its own preferred distance and height, so no two photos repeat; in each direction the
    camera stands at the clear spot (`clearance` from walls and furniture) nearest that distance,
    as a person steps round the furniture, and directions with no clear spot are skipped.
    `sees(eye, target)` (3-vectors) can refuse spots without a line of sight to the centre (a wall
    of an L-shaped room in between).
    """
    centre = np.asarray(centre, dtype=np.float64)
    radii = np.arange(radius_m[0], radius_m[1] + 1e-9, free.resolution_m)
    start, laps, poses = rng.uniform(0, 2 * np.pi), {}, []
    h_lo, h_hi = config.height_m
    for k in range(views * 4):  # skipped directions need extra steps
        if len(poses) == views:
            break
        travelled = np.radians(step_deg) * k
        lap = int(travelled // (2 * np.pi))
        if lap not in laps:
            laps[lap] = (rng.uniform(*radius_m), rng.uniform(h_lo, h_hi))
        preferred, height = laps[lap]
        direction = np.array([np.cos(start + travelled), np.sin(start + travelled)])
        spots = centre + radii[:, None] * direction
        target = np.array([*centre, 0.8])
        xy = next((spots[i] for i in np.argsort(np.abs(radii - preferred))
                   if free.distance_at(spots[i]) >= clearance
                   and (sees is None or sees(np.array([*spots[i], height]), target))), None)
        if xy is None:
            continue
        yaw = np.arctan2(-direction[1], -direction[0]) + np.radians(rng.uniform(-10, 10, 1))
        pose = np.eye(4)
        pose[:3, :3] = look_rotation(yaw, np.radians(rng.uniform(*config.pitch_deg, 1)),
                                     np.radians(rng.uniform(-3, 3, 1)))[0]
        pose[:3, 3] = [xy[0], xy[1], height]
        poses.append(pose)
    if len(poses) < views:
        raise ReconError(f"synthetic room: only {len(poses)} of {views} directions round the orbit's centre "
                         "have a clear spot for the camera")
    return np.array(poses)
