"""Mesh cleanup and export."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from recon.errors import ReconError
from recon.io import atomic_path

MESH_SUFFIXES = (".ply", ".obj", ".glb", ".stl", ".off")


@dataclass
class MeshCleanup:
    """Connected pieces smaller than this area are fusion noise (floaters) and are dropped."""

    min_component_area: float = 0.05  # square metres (scan units squared)


def clean_mesh(mesh: trimesh.Trimesh, cleanup: MeshCleanup) -> trimesh.Trimesh:
    """Drop small disconnected pieces and unreferenced vertices; never returns an empty mesh."""
    if len(mesh.faces) == 0:
        return mesh
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
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types on malformed files
        raise ReconError(f"{path}: unreadable mesh ({exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ReconError(f"{path}: contains no triangles")
    return mesh
