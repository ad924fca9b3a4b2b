"""Mesh cleanup and export."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from recon.errors import ReconError
from recon.io import atomic_path

if TYPE_CHECKING:  # trimesh (scipy) takes seconds to import: loaded where a mesh is made, so `--help` stays fast
    import trimesh

MESH_SUFFIXES = (".ply", ".obj", ".glb", ".stl", ".off")


@dataclass
class MeshCleanup:
    """Connected pieces smaller than this area are fusion noise (floaters) and are dropped. Off by default: on
    the held-out rooms it cost the plane sweep's sparse meshes a fifth to three quarters of their recall and
    moved the network's F by 0.01 at most (docs/evaluation.md); the depth filter removes floaters before fusion."""

    min_component_area: float = 0.0  # square metres (scan units squared); 0 keeps every piece

    def validate(self) -> "MeshCleanup":
        if not self.min_component_area >= 0:
            raise ReconError(f"--min-component-area must be >= 0, got {self.min_component_area}")
        return self


def clean_mesh(mesh: trimesh.Trimesh, cleanup: MeshCleanup) -> trimesh.Trimesh:
    """Drop small disconnected pieces and unreferenced vertices; never returns an empty mesh."""
    if len(mesh.faces) == 0 or cleanup.min_component_area <= 0:
        return mesh
    import trimesh

    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    area = np.bincount(labels, weights=mesh.area_faces)
    keep_component = area >= cleanup.min_component_area
    if not keep_component.any():
        keep_component[np.argmax(area)] = True
    out = mesh.copy()
    out.update_faces(keep_component[labels])
    out.remove_unreferenced_vertices()
    return out


def check_mesh_path(path: str | os.PathLike) -> Path:
    """Fail early (before any work) on an output name whose format we cannot write."""
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ReconError(f"{path}: unsupported mesh format (use one of {', '.join(MESH_SUFFIXES)})")
    return path


def save_mesh(mesh: trimesh.Trimesh, path: str | os.PathLike) -> Path:
    """Export by suffix (.ply .obj .glb .stl .off), atomically."""
    path = check_mesh_path(path)
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type=path.suffix.lower().lstrip("."))
    return path


def load_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """Read a triangle mesh; a point cloud or an empty file is an error."""
    path = Path(path)
    if not path.is_file():
        raise ReconError(f"{path}: mesh file not found")
    try:
        import trimesh

        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types on malformed files
        raise ReconError(f"{path}: unreadable mesh ({exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ReconError(f"{path}: contains no triangles")
    return mesh
