"""TSDF fusion of depth maps into a colored mesh with Open3D's tensor VoxelBlockGrid (CPU or CUDA)."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, NamedTuple

import cv2
import numpy as np

from recon.errors import ReconError
from recon.geometry import invert_pose, transform_points
from recon.io import load_confidence_map, load_depth_map
from recon.scan import Intrinsics, Scan

from .mesh import MeshCleanup, clean_mesh

if TYPE_CHECKING:  # trimesh (scipy) takes seconds to import: loaded where a mesh is made, so `--help` stays fast
    import trimesh


@dataclass
class TSDFConfig:
    """Fusion parameters; the defaults follow the field (4 cm voxels, 3-voxel truncation, 4 m range)."""

    voxel_size: float = 0.04  # metres (scan units for non-metric scans)
    trunc_voxels: float = 3.0  # truncation distance in voxels
    depth_min: float = 0.1
    depth_max: float = 4.0
    min_confidence: float | None = None  # drop predicted depth whose confidence is below this
    device: str = "auto"  # auto | cpu | cuda | an Open3D device string such as CUDA:0
    min_weight: float = 0.5  # voxels must weigh more than this to be meshed; Open3D's own default (3) drops
    #                         surfaces that only a few keyframes see, and 1 drops those seen once
    block_resolution: int = 8  # voxels per block side
    initial_blocks: int = 20000  # hash map capacity to start with; it grows as needed

    def validate(self) -> "TSDFConfig":
        for name in ("voxel_size", "trunc_voxels", "depth_min", "depth_max", "min_weight"):
            setattr(self, name, float(getattr(self, name)))  # Open3D's bindings refuse ints here
        if not self.voxel_size > 0 or not self.trunc_voxels > 0:
            raise ReconError(f"--voxel-size and --trunc-voxels must be positive (voxel size and truncation: got "
                             f"{self.voxel_size}, {self.trunc_voxels})")
        if not 0 <= self.depth_min < self.depth_max:
            raise ReconError(f"--depth-min/--depth-max: invalid depth range [{self.depth_min}, {self.depth_max}] for fusion")
        if self.min_confidence is not None and not 0 <= self.min_confidence < 1:
            raise ReconError(f"--min-confidence must be in [0, 1) (confidence is a probability), "
                             f"got {self.min_confidence}")
        return self


def open3d_device(name: str):
    """'auto' | 'cpu' | 'cuda' | 'CUDA:1' -> open3d.core.Device."""
    import open3d.core as o3c

    key = name.lower()
    if key == "auto":
        return o3c.Device("CUDA:0" if o3c.cuda.is_available() else "CPU:0")
    if key == "cpu":
        return o3c.Device("CPU:0")
    if key.startswith("cuda"):
        if not o3c.cuda.is_available():
            raise ReconError("CUDA fusion requested but this Open3D build has no CUDA device (install open3d, not open3d-cpu)")
        return o3c.Device("CUDA:0" if key == "cuda" else name.upper())
    raise ReconError(f"unknown device {name!r} (auto, cpu, cuda, CUDA:N)")


class TSDFIntegrator:
    """Integrates one frame at a time; `extract_mesh` may be called at any point."""

    def __init__(self, config: TSDFConfig | None = None):
        import open3d as o3d
        import open3d.core as o3c

        self.config = (config or TSDFConfig()).validate()
        self.device = open3d_device(self.config.device)
        self._o3c = o3c
        self._o3d = o3d
        self.grid = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=self.config.voxel_size,
            block_resolution=self.config.block_resolution,
            block_count=self.config.initial_blocks,
            device=self.device)
        self.frames_integrated = 0
        self.frames_skipped = 0  # frames with no depth inside the range
        self._color: np.ndarray | None = None

    def _tensor(self, array: np.ndarray):
        """Zero-copy view on the CPU (integration finishes before the buffer is reused), a copy on CUDA."""
        o3c = self._o3c
        return o3c.Tensor.from_numpy(array) if self.device.get_type() == o3c.Device.DeviceType.CPU \
            else o3c.Tensor(array, device=self.device)

    def integrate(self, depth_m: np.ndarray, rgb: np.ndarray, intrinsics: Intrinsics, camera_to_world: np.ndarray,
                  confidence: np.ndarray | None = None, weight: np.ndarray | None = None) -> None:
        """Add one frame. depth_m (H, W) float metres, 0 = invalid; rgb (H', W', 3) uint8, resized to the depth grid;
        confidence (H, W) masks pixels below `min_confidence`; weight (H, W), when given, is each pixel's
        integration weight (Open3D's own integration counts every pixel 1)."""
        cfg, o3c, o3d = self.config, self._o3c, self._o3d
        h, w = depth_m.shape
        if (intrinsics.width, intrinsics.height) != (w, h):
            intrinsics = intrinsics.resized(w, h)
        if rgb.shape[:2] != (h, w):
            rgb = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
        depth = depth_m.astype(np.float32, copy=True)
        depth[~(depth >= cfg.depth_min)] = 0.0  # also zeroes NaN; beyond depth_max Open3D ignores by itself
        if confidence is not None and cfg.min_confidence is not None:
            depth[_on_grid(confidence, w, h) < cfg.min_confidence] = 0.0
        if self._color is None or self._color.shape != rgb.shape:
            self._color = np.empty(rgb.shape, np.float32)  # reused: a fresh 4 MB array per frame costs page faults
        np.multiply(rgb, np.float32(1 / 255), out=self._color, dtype=np.float32)
        depth_img = o3d.t.geometry.Image(self._tensor(depth))
        color_img = o3d.t.geometry.Image(self._tensor(self._color))
        K = o3c.Tensor(intrinsics.K, o3c.float64)
        world_to_camera = o3c.Tensor(invert_pose(camera_to_world), o3c.float64)
        try:
            blocks = self.grid.compute_unique_block_coordinates(depth_img, K, world_to_camera, 1.0, cfg.depth_max,
                                                                cfg.trunc_voxels)
        except RuntimeError as exc:  # Open3D aborts when no pixel lies inside the depth range
            if "No block is touched" not in str(exc):
                raise
            self.frames_skipped += 1
            return
        if weight is None:
            self.grid.integrate(blocks, depth_img, color_img, K, K, world_to_camera, 1.0, cfg.depth_max,
                                cfg.trunc_voxels)
        else:
            depth[depth > cfg.depth_max] = 0.0
            pixel_weight = np.clip(_on_grid(weight, w, h), 0.0, None).astype(np.float32)
            self._integrate_weighted(blocks, depth, pixel_weight, rgb, intrinsics.K, invert_pose(camera_to_world))
        self.frames_integrated += 1

    def _integrate_weighted(self, blocks, depth: np.ndarray, weight: np.ndarray, rgb: np.ndarray, K: np.ndarray,
                            world_to_camera: np.ndarray) -> None:
        """Open3D's TSDF update with each pixel's own weight instead of 1: the same voxels (those within the
        truncation band in front of the pixel they project to, the projection truncated to a pixel), the same
        truncated distance, running weighted means of distance and colour. Numpy on the grid's own memory
        (CPU grids; a CUDA grid would need the same arithmetic in Open3D tensors, which index 50x slower).

        depth, weight: (H, W) float32; rgb (H, W, 3) uint8; K (3, 3); world_to_camera (4, 4).
        """
        if self.device.get_type() != self._o3c.Device.DeviceType.CPU:
            raise ReconError("per-pixel fusion weights (--near-weight-m, --filter-weights) need the CPU grid: "
                             "pass --near-weight-m 0 to fuse on CUDA, or --device cpu")
        cfg = self.config
        h, w = depth.shape
        hashmap = self.grid.hashmap()
        hashmap.activate(blocks)
        buffer_index, _ = hashmap.find(blocks)
        xyz, index = (t.numpy() for t in self.grid.voxel_coordinates_and_flattened_indices(buffer_index))
        cam = transform_points(world_to_camera.astype(np.float32), xyz)
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = cam[:, 0] * np.float32(K[0, 0]) / z + np.float32(K[0, 2])
            v = cam[:, 1] * np.float32(K[1, 1]) / z + np.float32(K[1, 2])
            inside = (z > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        pixel = v[inside].astype(np.int64) * w + u[inside].astype(np.int64)
        z, index = z[inside], index.reshape(-1)[inside]
        observed = depth.reshape(-1)[pixel]
        pixel_weight = weight.reshape(-1)[pixel]
        trunc = np.float32(cfg.trunc_voxels * cfg.voxel_size)
        sdf = observed - z
        seen = (observed > 0) & (sdf >= -trunc) & (pixel_weight > 0)
        pixel, index, sdf, pixel_weight = pixel[seen], index[seen], sdf[seen], pixel_weight[seen]
        tsdf, total, color = (self.grid.attribute(name).numpy().reshape(shape)
                              for name, shape in (("tsdf", -1), ("weight", -1), ("color", (-1, 3))))
        old_weight = total[index]
        new_weight = old_weight + pixel_weight
        tsdf[index] = (tsdf[index] * old_weight + np.minimum(sdf, trunc) / trunc * pixel_weight) / new_weight
        observed_color = rgb.reshape(-1, 3)[pixel].astype(np.float32)
        color[index] = (color[index] * old_weight[:, None] + observed_color * pixel_weight[:, None]) \
            / new_weight[:, None]
        total[index] = new_weight

    def extract_mesh(self, cleanup: MeshCleanup | None = MeshCleanup()) -> trimesh.Trimesh:
        """Marching cubes on the zero level set, as a vertex-colored trimesh (optionally cleaned)."""
        if self.frames_integrated == 0:
            kept = f" with confidence >= {self.config.min_confidence}" if self.config.min_confidence else ""
            raise ReconError(f"fusion produced an empty mesh: no frame had depth inside "
                             f"[{self.config.depth_min}, {self.config.depth_max}] m{kept}")
        mesh = self.grid.extract_triangle_mesh(weight_threshold=self.config.min_weight).to_legacy()
        vertices = np.asarray(mesh.vertices)
        faces = np.asarray(mesh.triangles)
        if len(faces) == 0:
            raise ReconError("fusion produced an empty mesh (check the depth range, voxel size and poses)")
        colors = (np.clip(np.asarray(mesh.vertex_colors), 0, 1) * 255).round().astype(np.uint8)
        import trimesh

        out = trimesh.Trimesh(vertices, faces, vertex_colors=colors, process=False)
        return clean_mesh(out, cleanup) if cleanup is not None else out


def _on_grid(per_pixel: np.ndarray, width: int, height: int) -> np.ndarray:
    """A per-pixel map (confidence, weight) resampled (nearest) onto the depth grid when its size differs."""
    if per_pixel.shape == (height, width):
        return per_pixel
    return cv2.resize(per_pixel, (width, height), interpolation=cv2.INTER_NEAREST)


class DepthMap(NamedTuple):
    """One frame's depth as fusion takes it: metres (0 = invalid), optional confidence and integration weight."""

    depth_m: np.ndarray
    confidence: np.ndarray | None = None
    weight: np.ndarray | None = None


DepthSource = Callable[[int], DepthMap]


def depth_source(scan: Scan, depth: str | os.PathLike) -> DepthSource:
    """'gt' (the scan's own depth) or a folder of predicted maps named by frame -> i -> DepthMap."""
    if str(depth) == "gt":
        if not scan.has_depth:
            missing = next(f.name for f in scan.frames if not f.has_depth)
            raise ReconError(f"{scan.root or 'scan'}: frame {missing} has no ground-truth depth (use --depth DIR)")
        return lambda i: DepthMap(scan.depth(i))
    folder = Path(depth)
    if not folder.is_dir():
        raise ReconError(f"{folder}: depth folder not found")
    return lambda i: DepthMap(load_depth_map(folder, scan.frames[i].name),
                              load_confidence_map(folder, scan.frames[i].name))


def fuse_scan(scan: Scan, depth: "str | os.PathLike | DepthSource" = "gt", config: TSDFConfig | None = None,
              cleanup: MeshCleanup | None = MeshCleanup(), progress: Callable[[int, int], None] | None = None
              ) -> trimesh.Trimesh:
    """Fuse every frame of `scan` with depth from `depth` ('gt', a folder, or a DepthSource such as
    `fusion.filtering.DepthFilter`) into a cleaned colored mesh."""
    source = depth if callable(depth) else depth_source(scan, depth)
    integrator = TSDFIntegrator(config)
    for i in range(len(scan)):
        frame = source(i)
        integrator.integrate(frame.depth_m, scan.image(i), scan.intrinsics, scan.frames[i].camera_to_world,
                             frame.confidence, frame.weight)
        if progress:
            progress(i + 1, len(scan))
    return integrator.extract_mesh(cleanup)
