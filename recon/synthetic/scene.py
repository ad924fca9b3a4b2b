"""Procedural rooms: floor plan, walls, furniture, clutter, pictures and lights, from a seed.

The floor plan is a union of axis-aligned rectangles, each with a ceiling height:
one room, an L-shaped room (two rectangles), or two rooms joined by a doorway (a
short passage rectangle whose ceiling is the door lintel). Walls are generated on
every edge where the ceiling height changes, facing the higher side, so the shell
is closed and every surface faces the space a camera can be in.

Furniture is placed on a 2.5 cm occupancy grid of the floor: an object is kept only
if its footprint (plus a gap) lies inside the room on free floor, so nothing
interpenetrates. The same grid, after placement, gives the camera its free space.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np
from scipy import ndimage

from .mesh import Material, MeshBuilder, Pose2D, Solid
from .textures import DECAL_NAMES, TextureLibrary, srgb_to_linear

GRID_M = 0.025  # floor occupancy grid resolution
GAP_M = 0.04  # minimum free gap between two floor objects
WALL_GAP_M = 0.01  # wall-backed furniture stands this far from the wall


@dataclass(frozen=True)
class SceneConfig:
    """Ranges the room generator draws from (metres unless named otherwise)."""

    room_width_m: tuple[float, float] = (3.0, 8.0)
    ceiling_height_m: tuple[float, float] = (2.4, 3.2)
    l_shape_probability: float = 0.25
    second_room_probability: float = 0.3
    furniture_per_m2: tuple[float, float] = (0.3, 0.55)
    max_floor_objects: int = 14
    camera_clearance_m: float = 0.45  # the camera keeps this far from walls and furniture
    min_free_area_m2: float = 2.0  # furniture is thinned until the camera has this much room


@dataclass
class FreeSpace:
    """Where the camera may be: distance to the nearest wall or object on the floor grid."""

    origin_xy: np.ndarray  # world (x, y) of grid cell (0, 0)'s centre
    resolution_m: float
    distance_m: np.ndarray  # (rows=y, cols=x) metres to the nearest obstacle, 0 on obstacles
    walkable: np.ndarray  # bool (rows, cols): the connected region the camera moves in

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ij = np.round((np.asarray(xy) - self.origin_xy) / self.resolution_m).astype(np.int64)
        col = np.clip(ij[..., 0], 0, self.distance_m.shape[1] - 1)
        row = np.clip(ij[..., 1], 0, self.distance_m.shape[0] - 1)
        return row, col

    def distance_at(self, xy: np.ndarray) -> np.ndarray:
        """Clearance (m) at world points (..., 2); 0 outside the grid or off the walkable region."""
        row, col = self.cell_of(xy)
        inside_grid = np.all((np.asarray(xy) >= self.origin_xy - self.resolution_m)
                             & (np.asarray(xy) <= self.origin_xy + self.resolution_m
                                * np.array(self.distance_m.shape[::-1])), axis=-1)
        return np.where(inside_grid & self.walkable[row, col], self.distance_m[row, col], 0.0)

    def cell_centres(self, mask: np.ndarray) -> np.ndarray:
        rows, cols = np.nonzero(mask)
        return self.origin_xy + np.stack([cols, rows], axis=1) * self.resolution_m


@dataclass
class Scene:
    """A room as one triangle mesh with per-face materials, plus its lights and free space."""

    vertices: np.ndarray  # (F, 3, 3) world metres, z up
    uvs: np.ndarray  # (F, 3, 2) texture repeats
    face_material: np.ndarray  # (F,) index into materials
    materials: list[Material]
    light_positions: np.ndarray  # (K, 3)
    light_colors: np.ndarray  # (K, 3) linear RGB intensity
    shadow_light: int  # the light that casts shadows (the brightest ceiling light of the main room)
    ambient: np.ndarray  # (3,) linear RGB
    free_space: FreeSpace
    ceiling_height_m: float
    solids: list[Solid] = field(default_factory=list)  # every box and cylinder part, for overlap checks
    summary: dict = field(default_factory=dict)

    @property
    def num_faces(self) -> int:
        return len(self.face_material)

    @property
    def face_normals(self) -> np.ndarray:
        """(F, 3) unit normals from the winding (they point to the visible side)."""
        n = np.cross(self.vertices[:, 1] - self.vertices[:, 0], self.vertices[:, 2] - self.vertices[:, 0])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


# -- palettes ------------------------------------------------------------------------------------

def _lin(rgb) -> tuple[float, float, float]:
    return tuple(float(v) for v in srgb_to_linear(np.asarray(rgb, dtype=np.float64)))


WALL_PAINTS = [(0.94, 0.94, 0.92), (0.96, 0.95, 0.9), (0.85, 0.86, 0.86), (0.92, 0.87, 0.77),
               (0.8, 0.87, 0.92), (0.78, 0.85, 0.76), (0.95, 0.91, 0.74), (0.93, 0.83, 0.82),
               (0.98, 0.98, 0.98)]
FURNITURE_COLOURS = [(0.95, 0.95, 0.94), (0.15, 0.15, 0.16), (0.55, 0.56, 0.58), (0.16, 0.24, 0.42),
                     (0.62, 0.18, 0.16), (0.15, 0.45, 0.45), (0.8, 0.62, 0.2), (0.42, 0.3, 0.22)]
FABRIC_COLOURS = [(0.35, 0.38, 0.45), (0.55, 0.5, 0.42), (0.25, 0.3, 0.25), (0.6, 0.25, 0.22),
                  (0.7, 0.7, 0.68), (0.2, 0.22, 0.3)]


class Palette:
    """Draws material instances (texture + tint + scale) for one scene."""

    def __init__(self, library: TextureLibrary, rng: np.random.Generator):
        self.lib, self.rng = library, rng

    def make(self, texture: str, tint=(1.0, 1.0, 1.0), scale_jitter: float = 0.15,
             rotate: bool = False) -> Material:
        spec = self.lib.spec(texture)
        tile = spec.tile_m * float(self.rng.uniform(1 - scale_jitter, 1 + scale_jitter)) if spec.tile_m else 0.0
        return Material(self.lib[texture], _lin(tint), tile,
                        tuple(float(v) for v in self.rng.random(2)) if tile else (0.0, 0.0), rotate)

    def pick(self, options):
        return options[int(self.rng.integers(len(options)))]

    def vary(self, rgb, amount: float = 0.06):
        return tuple(float(np.clip(c * (1 + self.rng.uniform(-amount, amount)), 0, 1)) for c in rgb)

    def wall(self) -> Material:
        r = self.rng.random()
        paint = self.vary(self.pick(WALL_PAINTS), 0.03)
        if r < 0.55:
            return self.make("paint", paint)
        if r < 0.72:
            return self.make("plain", paint)
        if r < 0.84:
            return self.make("plaster", paint)
        return self.make(self.pick(["stripes", "dots"]), self.vary((1.0, 1.0, 1.0), 0.08))

    def accent_wall(self) -> Material:
        if self.rng.random() < 0.6:
            return self.make("brick", self.vary((0.95, 0.62, 0.5), 0.1), 0.1)
        return self.make("paint", self.pick(FURNITURE_COLOURS[3:7]))

    def floor(self) -> Material:
        r = self.rng.random()
        if r < 0.4:
            return self.make("wood_planks", self.vary((1.0, 1.0, 1.0), 0.25), rotate=bool(self.rng.random() < 0.5))
        if r < 0.6:
            return self.make("tiles", self.vary(self.pick([(0.9, 0.9, 0.88), (0.75, 0.72, 0.68),
                                                           (0.55, 0.6, 0.62)]), 0.05))
        if r < 0.72:
            return self.make("gravel", (0.85, 0.85, 0.82))
        if r < 0.87:
            return self.make("fabric", self.pick(FABRIC_COLOURS))
        return self.make("plain", self.pick([(0.6, 0.6, 0.6), (0.72, 0.66, 0.58), (0.35, 0.35, 0.38)]))

    def ceiling(self) -> Material:
        return self.make("plain" if self.rng.random() < 0.6 else "paint", self.vary((0.97, 0.97, 0.96), 0.02))

    def wood(self) -> Material:
        return self.make("wood", self.vary((1.0, 1.0, 1.0), 0.3), rotate=bool(self.rng.random() < 0.3))

    def solid(self) -> Material:
        return self.make("plain", self.vary(self.pick(FURNITURE_COLOURS), 0.08))

    def furniture_surface(self) -> Material:
        return self.wood() if self.rng.random() < 0.55 else self.solid()

    def fabric(self) -> Material:
        return self.make("fabric", self.vary(self.pick(FABRIC_COLOURS), 0.1))

    def picture(self) -> tuple[Material, float]:
        name = self.pick(DECAL_NAMES)
        return self.make(name), self.lib.spec(name).aspect

    def clutter(self) -> Material:
        r = self.rng.random()
        if r < 0.55:
            return self.make("plain", self.vary(self.pick(FURNITURE_COLOURS + FABRIC_COLOURS), 0.15))
        if r < 0.75:
            return self.make(self.pick(["stripes", "dots", "fabric"]), self.vary(self.pick(WALL_PAINTS), 0.1))
        return self.wood()


# -- furniture -----------------------------------------------------------------------------------

@dataclass
class Surface:
    """A horizontal support (table top, shelf board) where small objects may stand."""

    pose: Pose2D  # world placement of the surface centre, z = surface height
    half_x: float
    half_y: float
    clearance: float  # free height above it
    row_of_books: bool = False


@dataclass
class Furniture:
    """A floor object in its own frame: footprint centred on the origin, front towards +y."""

    half_x: float
    half_y: float
    height: float
    draw: Callable[[MeshBuilder, Pose2D], None]
    surfaces: list[tuple[Pose2D, float, float, float, bool]] = field(default_factory=list)  # local
    light_local: tuple[float, float, float] | None = None
    against_wall: bool = False


def _table(p: Palette, rng) -> Furniture:
    hx, hy = rng.uniform(0.4, 0.9), rng.uniform(0.3, 0.5)
    height, thick = rng.uniform(0.72, 0.78), rng.uniform(0.025, 0.05)
    top, legs = p.furniture_surface(), (p.solid() if rng.random() < 0.5 else p.wood())
    round_legs, leg = rng.random() < 0.5, rng.uniform(0.018, 0.03)

    def draw(b: MeshBuilder, pose: Pose2D):
        b.add_box((-hx, -hy, height - thick), (hx, hy, height), top, pose)
        for sx in (-1, 1):
            for sy in (-1, 1):
                cx, cy = sx * (hx - 2.5 * leg), sy * (hy - 2.5 * leg)
                if round_legs:
                    b.add_cylinder(leg, 0.0, height - thick - 0.001, legs, pose.compose(Pose2D(cx, cy)),
                                   segments=8, top=False)
                else:
                    b.add_box((cx - leg, cy - leg, 0.0), (cx + leg, cy + leg, height - thick - 0.001), legs,
                              pose, skip=("-z", "+z"))
    return Furniture(hx, hy, height, draw, [(Pose2D(0, 0, height), hx - 0.03, hy - 0.03, 0.45, False)])


def _chair(p: Palette, rng) -> Furniture:
    h = rng.uniform(0.2, 0.24)
    seat_z, back_h = rng.uniform(0.43, 0.48), rng.uniform(0.35, 0.5)
    seat, legs = p.furniture_surface(), p.solid()
    leg = 0.015

    def draw(b: MeshBuilder, pose: Pose2D):
        b.add_box((-h, -h, seat_z - 0.03), (h, h, seat_z), seat, pose)
        b.add_box((-h, -h, seat_z + 0.001), (h, -h + 0.03, seat_z + back_h), seat, pose, skip=("-z",))
        for sx in (-1, 1):
            for sy in (-1, 1):
                cx, cy = sx * (h - 2 * leg), sy * (h - 2 * leg)
                b.add_box((cx - leg, cy - leg, 0.0), (cx + leg, cy + leg, seat_z - 0.031), legs, pose,
                          skip=("-z", "+z"))
    return Furniture(h, h, seat_z + back_h, draw)


def _shelf(p: Palette, rng) -> Furniture:
    hx, hy = rng.uniform(0.3, 0.7), rng.uniform(0.14, 0.2)
    height, t = rng.uniform(1.2, 2.0), rng.uniform(0.018, 0.025)
    boards = int(np.clip(round(height / rng.uniform(0.3, 0.4)), 3, 6))
    mat = p.furniture_surface()
    spacing = (height - 2 * t - 0.06) / boards
    levels = [0.06] + [0.06 + t + k * spacing for k in range(1, boards)]  # plinth top, then board tops

    def draw(b: MeshBuilder, pose: Pose2D):
        for sx in (-1, 1):  # side panels
            b.add_box((sx * hx - t if sx > 0 else -hx, -hy, 0.0), (hx if sx > 0 else -hx + t, hy, height),
                      mat, pose, skip=("-z",))
        b.add_box((-hx + t + 0.001, -hy, height - t), (hx - t - 0.001, hy, height), mat, pose)  # top
        b.add_box((-hx + t + 0.001, -hy, 0.0), (hx - t - 0.001, -hy + 0.008, height - t - 0.001), mat, pose,
                  skip=("-z",))  # back
        b.add_box((-hx + t + 0.001, -hy + 0.009, 0.0), (hx - t - 0.001, hy, 0.06), mat, pose, skip=("-z",))
        for z in levels[1:]:
            b.add_box((-hx + t + 0.001, -hy + 0.009, z - t), (hx - t - 0.001, hy, z), mat, pose)
    surfaces = [(Pose2D(0, 0.005, z), hx - t - 0.01, hy - 0.015, spacing - t - 0.02, True) for z in levels]
    return Furniture(hx, hy, height, draw, surfaces, against_wall=True)


def _cabinet(p: Palette, rng) -> Furniture:
    hx, hy, height = rng.uniform(0.25, 0.8), rng.uniform(0.2, 0.3), rng.uniform(0.5, 1.1)
    body, handle = p.furniture_surface(), p.solid()
    drawers = int(rng.integers(1, 4))

    def draw(b: MeshBuilder, pose: Pose2D):
        b.add_box((-hx, -hy, 0.0), (hx, hy, height), body, pose, skip=("-z",))
        for k in range(drawers):
            z = height * (k + 0.7) / drawers
            b.add_box((-0.06, hy + 0.001, z - 0.01), (0.06, hy + 0.02, z + 0.01), handle, pose, skip=("-y",))
    return Furniture(hx, hy + 0.02, height, draw, [(Pose2D(0, 0, height), hx - 0.02, hy - 0.02, 0.5, False)],
                     against_wall=True)


def _sofa(p: Palette, rng) -> Furniture:
    hx, hy = rng.uniform(0.75, 1.1), rng.uniform(0.4, 0.48)
    seat_z, back_z, arm = rng.uniform(0.38, 0.45), rng.uniform(0.75, 0.9), rng.uniform(0.08, 0.15)
    cloth = p.fabric()

    def draw(b: MeshBuilder, pose: Pose2D):
        b.add_box((-hx + arm + 0.001, -hy + 0.2, 0.0), (hx - arm - 0.001, hy, seat_z), cloth, pose, skip=("-z",))
        b.add_box((-hx + arm + 0.001, -hy, 0.0), (hx - arm - 0.001, -hy + 0.199, back_z), cloth, pose,
                  skip=("-z",))
        for sx in (-1, 1):
            x0, x1 = (hx - arm, hx) if sx > 0 else (-hx, -hx + arm)
            b.add_box((x0, -hy, 0.0), (x1, hy, seat_z + 0.2), cloth, pose, skip=("-z",))
    return Furniture(hx, hy, back_z, draw, against_wall=True)


def _box_pile(p: Palette, rng) -> Furniture:
    sizes = []
    hx, hy = rng.uniform(0.15, 0.35), rng.uniform(0.15, 0.3)
    for _ in range(int(rng.integers(1, 4))):
        sizes.append((hx, hy, rng.uniform(0.15, 0.4)))
        hx, hy = hx * rng.uniform(0.6, 0.9), hy * rng.uniform(0.6, 0.9)
    cardboard = p.make("plain", p.vary((0.66, 0.5, 0.34), 0.1))
    mats = [cardboard if rng.random() < 0.6 else p.clutter() for _ in sizes]
    prints = [p.picture()[0] if rng.random() < 0.35 else None for _ in sizes]
    shifts = [(rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03)) for _ in sizes]
    total = sum(s[2] for s in sizes) + 0.001 * len(sizes)

    def draw(b: MeshBuilder, pose: Pose2D):
        z = 0.0
        for (bx, by, bz), mat, pic, (dx, dy) in zip(sizes, mats, prints, shifts):
            b.add_box((dx - bx, dy - by, z), (dx + bx, dy + by, z + bz), mat, pose, skip=("-z",),
                      decal_faces={"+y": pic} if pic else None)
            z += bz + 0.001
    return Furniture(sizes[0][0] + 0.03, sizes[0][1] + 0.03, total, draw)


def _cylinder_object(p: Palette, rng) -> Furniture:
    """A bin, stool or plant pot; sometimes a column of two."""
    r, h = rng.uniform(0.12, 0.3), rng.uniform(0.3, 0.9)
    mat = p.clutter()
    top = p.make("grass", (0.6, 1.0, 0.55)) if rng.random() < 0.3 else mat

    def draw(b: MeshBuilder, pose: Pose2D):
        b.add_cylinder(r, 0.0, h, mat, pose, segments=24, cap_material=top)
    return Furniture(r, r, h, draw)


def _floor_lamp(p: Palette, rng) -> Furniture:
    pole_h, shade_r = rng.uniform(1.3, 1.7), rng.uniform(0.15, 0.22)
    metal, shade = p.solid(), p.make("fabric", p.vary((0.95, 0.9, 0.78), 0.05))

    def draw(b: MeshBuilder, pose: Pose2D):
        b.add_cylinder(0.14, 0.0, 0.025, metal, pose, segments=16)
        b.add_cylinder(0.012, 0.026, pole_h, metal, pose, segments=6, top=False)
        b.add_cylinder(shade_r, pole_h + 0.001, pole_h + 0.25, shade, pose, segments=20, bottom=True)
    return Furniture(shade_r, shade_r, pole_h + 0.25, draw, light_local=(0.0, 0.0, pole_h + 0.1))


def _rug(p: Palette, rng) -> Furniture:
    hx, hy = rng.uniform(0.6, 1.3), rng.uniform(0.4, 0.9)
    mat = p.make(p.pick(["fabric", "stripes", "grass", "dots"]), p.vary(p.pick(FABRIC_COLOURS + WALL_PAINTS), 0.1))

    def draw(b: MeshBuilder, pose: Pose2D):
        corners = np.array([[-hx, -hy, 0.006], [hx, -hy, 0.006], [hx, hy, 0.006], [-hx, hy, 0.006]])
        b.add_polygon(corners, np.array([0.0, 0.0, 1.0]), mat, pose)
    return Furniture(hx, hy, 0.006, draw)  # placed first and never raised: the camera walks over it


FLOOR_OBJECTS = [(_table, 3), (_chair, 2), (_shelf, 3), (_cabinet, 3), (_sofa, 1.5), (_box_pile, 3),
                 (_cylinder_object, 2), (_floor_lamp, 1)]


def _small_item(p: Palette, rng, max_h: float, max_half: float):
    """Size and drawing of one object that stands on a surface: (half_x, half_y, height, draw)."""
    kind = rng.random()
    if kind < 0.4:  # a box, sometimes with a printed front
        hx, hy, h = rng.uniform(0.03, max_half), rng.uniform(0.03, max_half), rng.uniform(0.03, min(max_h, 0.3))
        mat, pic = p.clutter(), (p.picture()[0] if rng.random() < 0.3 else None)

        def draw(b: MeshBuilder, pose: Pose2D):
            b.add_box((-hx, -hy, 0.0), (hx, hy, h), mat, pose, skip=("-z",), decal_faces={"+y": pic} if pic else None)
        return hx, hy, h, draw
    if kind < 0.75:  # mug, can, vase or bottle
        r, h = rng.uniform(0.025, min(0.08, max_half)), rng.uniform(0.06, min(max_h, 0.35))
        label = p.picture()[0] if rng.random() < 0.25 else p.clutter()
        cap = p.solid()

        def draw(b: MeshBuilder, pose: Pose2D):
            b.add_cylinder(r, 0.0, h, label, pose, segments=12, cap_material=cap)
        return r, r, h, draw
    # a thin object lying flat: a closed laptop, a tray, a book
    hx, hy, h = rng.uniform(0.05, max_half), rng.uniform(0.04, max_half), rng.uniform(0.01, 0.03)
    mat = p.clutter()

    def draw(b: MeshBuilder, pose: Pose2D):
        b.add_box((-hx, -hy, 0.0), (hx, hy, h), mat, pose, skip=("-z",))
    return hx, hy, h, draw


def _fill_surface(b: MeshBuilder, p: Palette, rng, s: Surface) -> float:
    """Put objects on a surface without overlaps; returns the tallest object's height."""
    tallest = 0.0
    if s.row_of_books:
        x = -s.half_x
        while x < s.half_x - 0.03:
            if rng.random() < 0.15:  # a gap
                x += rng.uniform(0.05, 0.2)
                continue
            w = rng.uniform(0.015, 0.05)
            if x + w > s.half_x:
                break
            h = rng.uniform(0.6, 0.95) * s.clearance
            depth = rng.uniform(0.6, 1.0) * s.half_y
            b.add_box((x, -s.half_y, 0.0), (x + w, -s.half_y + 2 * depth, h), p.clutter(), s.pose, skip=("-z",))
            tallest = max(tallest, h)
            x += w + 0.002
        return tallest
    placed: list[tuple[float, float, float, float]] = []
    max_half = min(0.15, s.half_x, s.half_y)
    if max_half < 0.05:
        return 0.0
    for _ in range(int(rng.integers(0, 5))):
        hx, hy, h, draw = _small_item(p, rng, s.clearance - 0.02, max_half)
        for _attempt in range(8):
            cx, cy = rng.uniform(-s.half_x + hx, s.half_x - hx), rng.uniform(-s.half_y + hy, s.half_y - hy)
            if all(abs(cx - px) >= hx + phx + 0.01 or abs(cy - py) >= hy + phy + 0.01 for px, py, phx, phy in placed):
                draw(b, s.pose.compose(Pose2D(cx, cy)))
                placed.append((cx, cy, hx, hy))
                tallest = max(tallest, h)
                break
    return tallest


# -- the room ------------------------------------------------------------------------------------

@dataclass
class _Rect:
    x0: float
    y0: float
    x1: float
    y1: float
    height: float
    room: int  # 0 main room, 1 second room, 2 door passage


def _floor_plan(cfg: SceneConfig, rng) -> tuple[list[_Rect], str, tuple | None]:
    """Rectangles of the plan, its kind, and the door passage (x0, y0, x1, y1, height) if any."""
    lo, hi = cfg.room_width_m
    w, d = rng.uniform(lo, hi), rng.uniform(lo, hi)
    h = rng.uniform(*cfg.ceiling_height_m)
    r = rng.random()
    if r < cfg.l_shape_probability and min(w, d) >= 4.0:
        cut_x, cut_y = rng.uniform(0.3, 0.5) * w, rng.uniform(0.3, 0.5) * d
        return [_Rect(0, 0, w, d - cut_y, h, 0), _Rect(0, d - cut_y, w - cut_x, d, h, 0)], "L-shaped", None
    if r < cfg.l_shape_probability + cfg.second_room_probability:
        t = 0.12
        w2, d2 = rng.uniform(2.5, 4.5), rng.uniform(2.5, 5.0)
        y2 = rng.uniform(1.3 - d2, d - 1.3)  # the rooms share at least 1.3 m of wall
        overlap = (max(0.0, y2), min(d, y2 + d2))
        door_w = min(rng.uniform(0.8, 1.0), overlap[1] - overlap[0] - 0.4)
        if door_w >= 0.7:
            low = overlap[0] + 0.2  # a door as wide as the overlap allows leaves no slack (nor rounding)
            dy = rng.uniform(low, max(low, overlap[1] - 0.2 - door_w))
            door_h = rng.uniform(2.0, 2.1)
            passage = (w, dy, w + t, dy + door_w, door_h)
            return ([_Rect(0, 0, w, d, h, 0), _Rect(w + t, y2, w + t + w2, y2 + d2, h, 1),
                     _Rect(w, dy, w + t, dy + door_w, door_h, 2)], "two rooms with a doorway", passage)
    return [_Rect(0, 0, w, d, h, 0)], "rectangular", None


def _build_shell(b: MeshBuilder, rects: list[_Rect], p: Palette, rng) -> list[tuple]:
    """Floor, ceilings and walls of the plan; returns full-height wall pieces (start, end, normal, room)."""
    xs = sorted({v for r in rects for v in (r.x0, r.x1)})
    ys = sorted({v for r in rects for v in (r.y0, r.y1)})
    nx, ny = len(xs) - 1, len(ys) - 1
    height = np.zeros((nx, ny))
    room = np.full((nx, ny), -1)
    for i in range(nx):
        for j in range(ny):
            cx, cy = (xs[i] + xs[i + 1]) / 2, (ys[j] + ys[j + 1]) / 2
            for r in rects:
                if r.x0 <= cx <= r.x1 and r.y0 <= cy <= r.y1 and r.height > height[i, j]:
                    height[i, j], room[i, j] = r.height, r.room
    rooms = sorted({r.room for r in rects})
    walls = {k: p.wall() for k in rooms}
    walls[2] = p.make("plain", (0.95, 0.95, 0.94))  # door jambs
    floors = {k: p.floor() for k in rooms}
    floors[2] = p.wood()
    ceilings = {k: p.ceiling() for k in rooms}
    main = next(r for r in rects if r.room == 0)
    accent = None
    if rng.random() < 0.35:
        side = int(rng.integers(4))
        accent = (("x", main.x0), ("x", main.x1), ("y", main.y0), ("y", main.y1))[side]
        accent_material = p.accent_wall()
    up = np.array([0.0, 0.0, 1.0])
    pieces = []
    for i in range(nx):
        for j in range(ny):
            if room[i, j] < 0:
                continue
            x0, x1, y0, y1, h = xs[i], xs[i + 1], ys[j], ys[j + 1], height[i, j]
            quad = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], dtype=np.float64)
            b.add_polygon(quad, up, floors[room[i, j]], Pose2D())
            b.add_polygon(quad + [0, 0, h], -up, ceilings[room[i, j]], Pose2D())
            # Each side of the cell: a wall from the neighbour's ceiling (0 outside) up to this one's.
            for di, dj, a, bb, normal in ((-1, 0, (x0, y0), (x0, y1), (1, 0)), (1, 0, (x1, y0), (x1, y1), (-1, 0)),
                                          (0, -1, (x0, y0), (x1, y0), (0, 1)), (0, 1, (x0, y1), (x1, y1), (0, -1))):
                ni, nj = i + di, j + dj
                h_other = height[ni, nj] if 0 <= ni < nx and 0 <= nj < ny else 0.0
                if h_other >= h:
                    continue
                corners = np.array([[a[0], a[1], h_other], [bb[0], bb[1], h_other], [bb[0], bb[1], h],
                                    [a[0], a[1], h]])
                material = walls[room[i, j]]
                if accent and room[i, j] == 0:
                    axis, value = accent
                    coord = a[0] if axis == "x" else a[1]
                    along = a[0] == bb[0] if axis == "x" else a[1] == bb[1]
                    if along and abs(coord - value) < 1e-9:
                        material = accent_material
                b.add_polygon(corners, np.array([normal[0], normal[1], 0.0]), material, Pose2D())
                if h_other == 0.0 and room[i, j] != 2:
                    pieces.append((np.array(a, float), np.array(bb, float), np.array(normal, float), room[i, j]))
    return pieces


class _FloorGrid:
    """The occupancy grid used to place furniture without overlaps."""

    def __init__(self, rects: list[_Rect]):
        self.x0 = min(r.x0 for r in rects) - 0.1
        self.y0 = min(r.y0 for r in rects) - 0.1
        w = max(r.x1 for r in rects) + 0.1 - self.x0
        h = max(r.y1 for r in rects) + 0.1 - self.y0
        self.shape = (int(math.ceil(h / GRID_M)), int(math.ceil(w / GRID_M)))
        self.inside = np.zeros(self.shape, bool)
        for r in rects:
            if r.room != 2:
                self.inside |= self.rect_mask(r.x0, r.y0, r.x1, r.y1, shrink=True)
        self.height = np.zeros(self.shape)  # top of whatever stands on each cell
        self.blocked = np.zeros(self.shape, bool)  # cells no new object may use (objects, rugs, door)
        self.wall_used = np.zeros(self.shape, bool)  # wall strips taken by doors, windows and pictures

    def rect_mask(self, x0, y0, x1, y1, shrink=False) -> np.ndarray:
        """Cells whose centres lie in the rectangle (all cells touching it unless `shrink`)."""
        ys = self.y0 + (np.arange(self.shape[0]) + 0.5) * GRID_M
        xs = self.x0 + (np.arange(self.shape[1]) + 0.5) * GRID_M
        pad = 0.0 if shrink else GRID_M / 2
        return ((ys[:, None] >= y0 - pad) & (ys[:, None] <= y1 + pad)
                & (xs[None, :] >= x0 - pad) & (xs[None, :] <= x1 + pad))

    def footprint(self, pose: Pose2D, half_x: float, half_y: float, grow: float,
                  grow_back: float | None = None) -> np.ndarray:
        """Cells under the object's rectangle grown by `grow` (`grow_back` behind it, towards -y)."""
        back = grow if grow_back is None else grow_back
        corners = np.array([[-half_x - grow, -half_y - back, 0], [half_x + grow, -half_y - back, 0],
                            [half_x + grow, half_y + grow, 0], [-half_x - grow, half_y + grow, 0]])
        xy = pose.apply(corners)[:, :2]
        pts = ((xy - [self.x0, self.y0]) / GRID_M - 0.5) * 16
        mask = np.zeros(self.shape, np.uint8)
        cv2.fillPoly(mask, [np.round(pts).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
        return mask.astype(bool)

    def fits(self, mask: np.ndarray) -> bool:
        return bool(mask.any()) and bool(np.all(self.inside[mask])) and not bool(self.blocked[mask].any())


def _place_floor_objects(b: MeshBuilder, p: Palette, rng, grid: _FloorGrid, wall_pieces, rects, count: int):
    """Place up to `count` objects; returns their surfaces (with footprint cells), lamp lights and names."""
    kinds, weights = zip(*FLOOR_OBJECTS)
    weights = np.array(weights) / np.sum(weights)
    surfaces, lights, placed = [], [], []
    lengths = np.array([np.linalg.norm(bb - a) for a, bb, _, _ in wall_pieces])
    # A rug first (it lies under nothing), then the rest.
    if rng.random() < 0.5:
        rug = _rug(p, rng)
        main = rects[0]
        pose = Pose2D(rng.uniform(main.x0 + 1, max(main.x0 + 1, main.x1 - 1)),
                      rng.uniform(main.y0 + 1, max(main.y0 + 1, main.y1 - 1)), 0.0, float(rng.uniform(0, np.pi)))
        mask = grid.footprint(pose, rug.half_x, rug.half_y, GAP_M)
        if grid.fits(mask):
            rug.draw(b, pose)
            grid.blocked |= mask
            placed.append("rug")
    for _attempt in range(count * 12):
        if len([n for n in placed if n != "rug"]) >= count:
            break
        maker = kinds[int(rng.choice(len(kinds), p=weights))]
        obj = maker(p, rng)
        if obj.against_wall:
            k = int(rng.choice(len(wall_pieces), p=lengths / lengths.sum()))
            a, bb, normal, _room = wall_pieces[k]
            t = rng.uniform(0, 1)
            at = a + t * (bb - a) + normal * (obj.half_y + WALL_GAP_M)
            pose = Pose2D(float(at[0]), float(at[1]), 0.0, float(math.atan2(-normal[0], normal[1])))
        else:
            r = rects[int(rng.integers(len(rects)))]
            if r.room == 2:
                continue
            yaw = float(rng.uniform(0, 2 * np.pi)) if rng.random() < 0.6 else float(rng.integers(4)) * np.pi / 2
            pose = Pose2D(float(rng.uniform(r.x0, r.x1)), float(rng.uniform(r.y0, r.y1)), 0.0, yaw)
        grown = grid.footprint(pose, obj.half_x, obj.half_y, GAP_M, 0.0 if obj.against_wall else GAP_M)
        if not grid.fits(grown):
            continue
        obj.draw(b, pose)
        exact = grid.footprint(pose, obj.half_x, obj.half_y, 0.0)
        grid.blocked |= exact
        grid.height[exact] = np.maximum(grid.height[exact], obj.height)
        placed.append(maker.__name__.strip("_"))
        for local, hx, hy, clearance, books in obj.surfaces:
            surfaces.append((Surface(pose.compose(local), hx, hy, clearance, books), exact))
        if obj.light_local is not None:
            lights.append(pose.apply(np.array([obj.light_local]))[0])
    return surfaces, lights, placed


def _place_pictures(b: MeshBuilder, p: Palette, rng, grid: _FloorGrid, wall_pieces, ceiling: float) -> int:
    count, wanted = 0, int(rng.integers(2, 7))
    for _ in range(4 * wanted):
        if count == wanted:
            break
        a, bb, normal, _room = wall_pieces[int(rng.integers(len(wall_pieces)))]
        material, aspect = p.picture()
        width = rng.uniform(0.3, 1.0)
        height = width / aspect
        if height > 0.9:
            height, width = 0.9, 0.9 * aspect
        length = np.linalg.norm(bb - a)
        if length < width + 0.3:
            continue
        t = rng.uniform((width / 2 + 0.15) / length, 1 - (width / 2 + 0.15) / length)
        z = rng.uniform(1.2, 1.7)
        z0, z1 = z - height / 2, z + height / 2
        if z1 > ceiling - 0.15:
            continue
        depth = rng.uniform(0.015, 0.04)
        at = a + t * (bb - a)
        pose = Pose2D(float(at[0]), float(at[1]), 0.0, float(math.atan2(-normal[0], normal[1])))
        strip = grid.footprint(Pose2D(*(at + normal * 0.07), 0.0, pose.yaw), width / 2 + 0.05, 0.05, 0.0)
        if grid.wall_used[strip].any() or np.any(grid.height[strip] > z0 - 0.05) or not np.all(grid.inside[strip]):
            continue
        frame = p.solid() if rng.random() < 0.6 else p.wood()
        b.add_box((-width / 2, 0.001, z0), (width / 2, depth, z1), frame, pose, skip=("-y",),
                  decal_faces={"+y": material})
        grid.wall_used |= strip
        count += 1
    return count


def _place_doors(b: MeshBuilder, p: Palette, rng, grid: _FloorGrid, wall_pieces) -> int:
    """Closed doors on the walls; the floor in front of each stays clear of furniture."""
    count = 0
    for _ in range(int(rng.integers(0, 3))):
        a, bb, normal, _room = wall_pieces[int(rng.integers(len(wall_pieces)))]
        width, height = rng.uniform(0.78, 0.92), rng.uniform(2.0, 2.1)
        length = np.linalg.norm(bb - a)
        if length < width + 0.4:
            continue
        at = a + rng.uniform((width / 2 + 0.2) / length, 1 - (width / 2 + 0.2) / length) * (bb - a)
        yaw = float(math.atan2(-normal[0], normal[1]))
        front = grid.footprint(Pose2D(*(at + normal * 0.45), 0.0, yaw), width / 2 + 0.1, 0.43, 0.0)
        strip = grid.footprint(Pose2D(*(at + normal * 0.07), 0.0, yaw), width / 2 + 0.05, 0.05, 0.0)
        if grid.blocked[front].any() or grid.wall_used[strip].any() or not np.all(grid.inside[front]):
            continue
        pose = Pose2D(float(at[0]), float(at[1]), 0.0, yaw)
        leaf, handle = (p.wood() if rng.random() < 0.5 else p.solid()), p.solid()
        b.add_box((-width / 2, 0.001, 0.0), (width / 2, 0.035, height), leaf, pose, skip=("-y", "-z"))
        b.add_box((width / 2 - 0.12, 0.036, 1.0), (width / 2 - 0.06, 0.06, 1.03), handle, pose, skip=("-y",))
        grid.blocked |= front
        grid.wall_used |= strip
        count += 1
    return count


def _place_windows(b: MeshBuilder, p: Palette, rng, grid: _FloorGrid, wall_pieces, ceiling: float) -> int:
    """Bright glazed panes with frames and a mullion, above whatever stands below them."""
    count = 0
    for _ in range(int(rng.integers(0, 3))):
        a, bb, normal, _room = wall_pieces[int(rng.integers(len(wall_pieces)))]
        width, height, z0 = rng.uniform(0.7, 1.6), rng.uniform(0.9, 1.4), rng.uniform(0.8, 1.0)
        length = np.linalg.norm(bb - a)
        if length < width + 0.4 or z0 + height > ceiling - 0.2:
            continue
        at = a + rng.uniform((width / 2 + 0.2) / length, 1 - (width / 2 + 0.2) / length) * (bb - a)
        yaw = float(math.atan2(-normal[0], normal[1]))
        strip = grid.footprint(Pose2D(*(at + normal * 0.07), 0.0, yaw), width / 2 + 0.05, 0.05, 0.0)
        if (grid.wall_used[strip].any() or np.any(grid.height[strip] > z0 - 0.05)
                or not np.all(grid.inside[strip])):
            continue
        pose = Pose2D(float(at[0]), float(at[1]), 0.0, yaw)
        sky = p.make("plain", tuple(float(v) for v in rng.uniform(0.9, 1.1) * np.array([1.6, 1.7, 1.8])))  # daylight
        frame = p.make("plain", p.vary((0.95, 0.95, 0.95), 0.03))
        z1, f = z0 + height, 0.05
        b.add_box((-width / 2, 0.001, z0), (width / 2, 0.02, z1), sky, pose, skip=("-y",))
        for lo, hi in (((-width / 2, z0), (width / 2, z0 + f)), ((-width / 2, z1 - f), (width / 2, z1)),
                       ((-width / 2, z0 + f + 0.001), (-width / 2 + f, z1 - f - 0.001)),
                       ((width / 2 - f, z0 + f + 0.001), (width / 2, z1 - f - 0.001)),
                       ((-f / 2, z0 + f + 0.001), (f / 2, z1 - f - 0.001))):
            b.add_box((lo[0], 0.021, lo[1]), (hi[0], 0.05, hi[1]), frame, pose, skip=("-y",))
        grid.wall_used |= strip
        count += 1
    return count


def _free_space(grid: _FloorGrid, cfg: SceneConfig) -> FreeSpace:
    obstacle = ~grid.inside | (grid.height > 0.0)
    distance = ndimage.distance_transform_edt(~obstacle) * GRID_M
    ok = distance >= cfg.camera_clearance_m
    labels, n = ndimage.label(ok)
    if n == 0:
        walkable = ok
    else:
        sizes = ndimage.sum(ok, labels, index=np.arange(1, n + 1))
        walkable = labels == (1 + int(np.argmax(sizes)))
    origin = np.array([grid.x0 + GRID_M / 2, grid.y0 + GRID_M / 2])
    return FreeSpace(origin, GRID_M, distance, walkable)


def generate_scene(seed: int, library: TextureLibrary, config: SceneConfig = SceneConfig()) -> Scene:
    """Build the room for `seed` (the same seed always gives the same scene)."""
    layout_rng = np.random.default_rng([seed, 1])
    rects, kind, passage = _floor_plan(config, layout_rng)
    ceiling = rects[0].height
    floor_area = sum((r.x1 - r.x0) * (r.y1 - r.y0) for r in rects if r.room != 2)
    density = layout_rng.uniform(*config.furniture_per_m2)
    for attempt in range(6):  # fewer objects each time until the camera has room to move
        rng = np.random.default_rng([seed, 2, attempt])
        p = Palette(library, rng)
        b = MeshBuilder()
        wall_pieces = _build_shell(b, rects, p, rng)
        grid = _FloorGrid(rects)
        if passage is not None:  # keep the doorway usable: nothing stands in front of it
            x0, y0, x1, y1, _h = passage
            grid.blocked |= grid.rect_mask(x0 - 0.9, y0 - 0.1, x1 + 0.9, y1 + 0.1)
        doors = _place_doors(b, p, rng, grid, wall_pieces)
        count = int(min(config.max_floor_objects, round(floor_area * density * 0.6 ** attempt)))
        surfaces, lamp_lights, placed = _place_floor_objects(b, p, rng, grid, wall_pieces, rects, count)
        for surface, cells in surfaces:
            tallest = _fill_surface(b, p, rng, surface)
            grid.height[cells] = np.maximum(grid.height[cells], surface.pose.z + tallest)
        windows = _place_windows(b, p, rng, grid, wall_pieces, ceiling)
        pictures = _place_pictures(b, p, rng, grid, wall_pieces, ceiling)
        free = _free_space(grid, config)
        if free.walkable.sum() * GRID_M ** 2 >= config.min_free_area_m2:
            break
    lights, main_room_lights = [], []
    for r in rects:
        if r.room == 2:
            continue
        n_lights = 1 + int((r.x1 - r.x0) * (r.y1 - r.y0) > 16) + int(rng.random() < 0.3)
        for _ in range(n_lights):
            for _try in range(10):  # fixtures (at most 0.5 m wide) keep apart
                x = rng.uniform(r.x0 + 0.6, max(r.x0 + 0.6, r.x1 - 0.6))
                y = rng.uniform(r.y0 + 0.6, max(r.y0 + 0.6, r.y1 - 0.6))
                if all(np.hypot(x - q[0], y - q[1]) > 0.6 for q in lights):
                    break
            else:
                continue
            b.add_cylinder(rng.uniform(0.12, 0.25), ceiling - 0.06, ceiling - 0.001,
                           p.make("plain", (1.0, 1.0, 0.98)), Pose2D(x, y), segments=16, top=False, bottom=True)
            if r.room == 0:
                main_room_lights.append(len(lights))
            lights.append(np.array([x, y, ceiling - 0.3]))
    lights += lamp_lights
    warmth = rng.uniform(-1, 1, size=len(lights))
    colors = np.array([[1.0, 0.93 + 0.04 * w, 0.82 + 0.15 * w] for w in warmth]) * \
        rng.uniform(0.8, 1.3, size=(len(lights), 1))
    colors /= max(1.0, len(lights) / 2.5)  # many lights share the power, so rooms are not overexposed
    ambient = np.array([1.0, 1.0, 1.0]) * rng.uniform(0.15, 0.3)
    shadow_light = main_room_lights[int(np.argmax(colors[main_room_lights].sum(axis=1)))]
    vertices, uvs, face_material = b.arrays()
    xs = [v for r in rects for v in (r.x0, r.x1)]
    ys = [v for r in rects for v in (r.y0, r.y1)]
    summary = {"seed": int(seed), "layout": kind, "extent_m": [round(max(xs) - min(xs), 2), round(max(ys) - min(ys), 2),
                                                              round(ceiling, 2)],
               "floor_area_m2": round(floor_area, 2), "objects": placed, "pictures": pictures,
               "doors": doors, "windows": windows,
               "lights": len(lights), "triangles": int(len(face_material))}
    return Scene(vertices, uvs, face_material, list(b.materials), np.array(lights, float), colors, shadow_light,
                 ambient, free, float(ceiling), list(b.solids), summary)
