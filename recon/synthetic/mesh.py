"""Triangle soup with per-face material and texture coordinates, built from boxes, quads and cylinders.

Faces are oriented: the winding gives the normal that points to the side a camera
can see (into the room for walls, outwards for objects). Texture coordinates are
in texture repeats (1.0 = one repeat of the material's texture), computed from the
object's own coordinates in metres, so a texture keeps its physical size and moves
with the object. Decal materials (pictures) span their face exactly once.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UP = np.array([0.0, 0.0, 1.0])
DECAL_INSET = 0.002  # keeps decal lookups off the picture's wrap-around border


@dataclass(frozen=True)
class Material:
    """One use of a library texture: tint (linear RGB multiplier), repeat size and offset."""

    texture: int
    tint: tuple[float, float, float]
    tile_m: float  # metres per repeat; 0 = decal
    uv_offset: tuple[float, float] = (0.0, 0.0)
    uv_rotate: bool = False  # swap the texture axes (wood grain across instead of along)


@dataclass(frozen=True)
class Pose2D:
    """Placement of an object on the floor plan: rotation about the vertical axis, then translation."""

    x: float = 0.0  # metres, room frame (z up)
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0  # radians about +z

    @property
    def rotation(self) -> np.ndarray:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def apply(self, points: np.ndarray) -> np.ndarray:
        return points @ self.rotation.T + np.array([self.x, self.y, self.z])

    def compose(self, local: "Pose2D") -> "Pose2D":
        """This placement applied after `local` (local is expressed in this object's frame)."""
        x, y, z = self.apply(np.array([local.x, local.y, local.z]))
        return Pose2D(float(x), float(y), float(z), self.yaw + local.yaw)


@dataclass(frozen=True)
class Solid:
    """A closed part (a box, or a vertical cylinder when `radius` > 0) where it was placed.

    Kept beside the triangles so tests can check that no two parts of a scene overlap.
    """

    pose: Pose2D
    lo: tuple[float, float, float]  # local bounds (a cylinder: its bounding box)
    hi: tuple[float, float, float]
    radius: float = 0.0

    def probe_points(self) -> np.ndarray:
        """World points on the part's surface: corners, edge midpoints and face centres (rims for cylinders)."""
        lo, hi = np.array(self.lo), np.array(self.hi)
        if self.radius > 0:
            angles = np.linspace(0, 2 * np.pi, 16, endpoint=False)
            ring = np.stack([np.cos(angles), np.sin(angles)], axis=1) * self.radius
            local = np.concatenate([np.column_stack([ring, np.full(16, z)]) for z in (lo[2], (lo[2] + hi[2]) / 2, hi[2])]
                                   + [[[0, 0, lo[2]], [0, 0, hi[2]]]])
        else:
            grid = np.stack(np.meshgrid(*[[lo[k], (lo[k] + hi[k]) / 2, hi[k]] for k in range(3)], indexing="ij"), -1)
            local = grid.reshape(-1, 3)
        return self.pose.apply(local)

    def contains(self, world_points: np.ndarray, margin: float) -> np.ndarray:
        """Which points lie inside the part by more than `margin` (touching does not count)."""
        local = (world_points - np.array([self.pose.x, self.pose.y, self.pose.z])) @ self.pose.rotation
        lo, hi = np.array(self.lo) + margin, np.array(self.hi) - margin
        inside_z = (local[:, 2] > lo[2]) & (local[:, 2] < hi[2])
        if self.radius > 0:
            return inside_z & (np.hypot(local[:, 0], local[:, 1]) < self.radius - margin)
        return inside_z & np.all((local[:, :2] > lo[:2]) & (local[:, :2] < hi[:2]), axis=1)


def _face_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right and down directions of a face as seen from its front (pictures read upright)."""
    if abs(normal[2]) > 0.9:
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, -np.sign(normal[2]), 0.0])
    right = np.cross(-normal, UP)
    return right / np.linalg.norm(right), -UP


class MeshBuilder:
    """Collects oriented, textured triangles; `arrays()` hands them to the renderer and the GT mesh."""

    def __init__(self):
        self._triangles: list[np.ndarray] = []
        self._uvs: list[np.ndarray] = []
        self._materials: list[int] = []
        self.materials: list[Material] = []
        self._material_ids: dict[Material, int] = {}
        self.solids: list[Solid] = []

    def material_id(self, material: Material) -> int:
        if material not in self._material_ids:
            self._material_ids[material] = len(self.materials)
            self.materials.append(material)
        return self._material_ids[material]

    def _uv(self, local_points: np.ndarray, right: np.ndarray, down: np.ndarray, material: Material,
            decal_extent: tuple[np.ndarray, float, float] | None) -> np.ndarray:
        if material.tile_m <= 0 and decal_extent is not None:
            origin, width, height = decal_extent
            u = (local_points - origin) @ right / width
            v = (local_points - origin) @ down / height
            uv = np.stack([u, v], axis=1)
            return DECAL_INSET + (1 - 2 * DECAL_INSET) * np.clip(uv, 0, 1)
        uv = np.stack([local_points @ right, local_points @ down], axis=1) / max(material.tile_m, 1e-6)
        if material.uv_rotate:
            uv = uv[:, ::-1]
        return uv + np.array(material.uv_offset)

    def add_polygon(self, local_corners: np.ndarray, normal: np.ndarray, material: Material, pose: Pose2D,
                    decal: bool = False) -> None:
        """A planar convex polygon (corners in order, local frame) facing `normal` (local frame)."""
        local_corners = np.asarray(local_corners, dtype=np.float64)
        normal = np.asarray(normal, dtype=np.float64)
        right, down = _face_axes(normal)
        extent = None
        if decal:
            proj_r, proj_d = local_corners @ right, local_corners @ down
            origin = right * proj_r.min() + down * proj_d.min()
            extent = (origin, max(np.ptp(proj_r), 1e-9), max(np.ptp(proj_d), 1e-9))
        uv = self._uv(local_corners, right, down, material, extent)
        world = pose.apply(local_corners)
        mid = self.material_id(material)
        for k in range(1, len(local_corners) - 1):
            idx = [0, k, k + 1]
            tri_local = local_corners[idx]
            if np.cross(tri_local[1] - tri_local[0], tri_local[2] - tri_local[0]) @ normal < 0:
                idx = [0, k + 1, k]
            self._triangles.append(world[idx])
            self._uvs.append(uv[idx])
            self._materials.append(mid)

    def add_box(self, lo, hi, material: Material, pose: Pose2D = Pose2D(), skip: tuple[str, ...] = (),
                decal_faces: dict[str, Material] | None = None) -> None:
        """Axis-aligned box [lo, hi] in the local frame, faces outwards.

        Faces are named "+x", "-x", "+y", "-y", "+z", "-z"; `skip` leaves some out (a base resting
        on the floor), `decal_faces` puts a picture material on some (a print on a box's front).
        """
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        self.solids.append(Solid(pose, tuple(map(float, lo)), tuple(map(float, hi))))
        for axis in range(3):
            for sign, name in ((1, f"+{'xyz'[axis]}"), (-1, f"-{'xyz'[axis]}")):
                if name in skip:
                    continue
                normal = np.zeros(3)
                normal[axis] = sign
                a, b = [k for k in range(3) if k != axis]
                corners = np.zeros((4, 3))
                corners[:, axis] = hi[axis] if sign > 0 else lo[axis]
                corners[:, a] = [lo[a], hi[a], hi[a], lo[a]]
                corners[:, b] = [lo[b], lo[b], hi[b], hi[b]]
                face_material = (decal_faces or {}).get(name, material)
                self.add_polygon(corners, normal, face_material, pose, decal=face_material.tile_m <= 0)

    def add_cylinder(self, radius: float, z0: float, z1: float, material: Material, pose: Pose2D = Pose2D(),
                     segments: int = 20, top: bool = True, bottom: bool = False,
                     cap_material: Material | None = None) -> None:
        """Vertical cylinder around the local z axis; sides are flat facets with outward normals."""
        self.solids.append(Solid(pose, (-radius, -radius, z0), (radius, radius, z1), radius))
        angles = np.linspace(0, 2 * np.pi, segments + 1)
        ring = np.stack([np.cos(angles), np.sin(angles)], axis=1) * radius
        mid = self.material_id(material)
        circumference = 2 * np.pi * radius
        for k in range(segments):
            (xa, ya), (xb, yb) = ring[k], ring[k + 1]
            quad = np.array([[xa, ya, z0], [xb, yb, z0], [xb, yb, z1], [xa, ya, z1]])
            if material.tile_m > 0:
                u = np.array([k, k + 1, k + 1, k]) * circumference / segments / material.tile_m
                v = -quad[:, 2] / material.tile_m
            else:  # a label wrapped once around
                u = DECAL_INSET + (1 - 2 * DECAL_INSET) * np.array([k, k + 1, k + 1, k]) / segments
                v = DECAL_INSET + (1 - 2 * DECAL_INSET) * (z1 - quad[:, 2]) / (z1 - z0)
            uv = np.stack([u, v], axis=1) + (np.array(material.uv_offset) if material.tile_m > 0 else 0)
            world = pose.apply(quad)
            for idx in ([0, 1, 2], [0, 2, 3]):  # counter-clockwise seen from outside
                self._triangles.append(world[idx])
                self._uvs.append(uv[idx])
                self._materials.append(mid)
        cap = cap_material or material
        if cap.tile_m <= 0:
            cap = material
        for z, normal, wanted in ((z1, UP, top), (z0, -UP, bottom)):
            if wanted:
                corners = np.concatenate([ring[:-1], np.full((segments, 1), z)], axis=1)
                self.add_polygon(corners, normal, cap, pose)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(F, 3, 3) world vertices, (F, 3, 2) texture coordinates, (F,) material ids."""
        return (np.array(self._triangles, dtype=np.float64).reshape(-1, 3, 3),
                np.array(self._uvs, dtype=np.float64).reshape(-1, 3, 2),
                np.array(self._materials, dtype=np.int32))
