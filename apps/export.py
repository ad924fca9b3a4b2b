"""A finished run in the formats other tools open (`recon export RUN --to FORMAT`).

    glb, obj     the fused mesh with its vertex colours (trimesh writes both)
    nerfstudio   transforms.json + images/ (every frame of the run's scan, OpenGL axes, +0.5 centres)
    colmap       sparse/0/*.txt (PINHOLE camera, world-to-camera poses, the mesh's vertices as points) + images/
    rerun        one .rrd: the camera path with frustums and images, predicted depth, the mesh

The conversions are `recon.writers`' (the inverse of the readers), so a nerfstudio or COLMAP
export reads back through `recon formats` as the same cameras. Each output is built under a
temporary name beside its place and moved there when complete.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from recon.errors import ReconError
from recon.io import atomic_dir, atomic_path, load_depth_map
from recon.scan import Scan, load_scan
from recon.writers import PIXEL_CENTRE, nerfstudio_transforms, write_colmap_text

FORMATS = ("glb", "obj", "nerfstudio", "colmap", "rerun")
DEFAULT_NAMES = {"glb": "mesh.glb", "obj": "mesh.obj", "nerfstudio": "nerfstudio", "colmap": "colmap",
                 "rerun": "recording.rrd"}
COLMAP_MAX_POINTS = 200_000  # mesh vertices written as the COLMAP model's points (subsampled beyond)


def export_run(run_dir: str | os.PathLike, to: str, out: str | os.PathLike | None = None) -> Path:
    """Write run `run_dir` as `to` (one of FORMATS) at `out` (default RUN/export/<name>); returns the path."""
    run = Path(run_dir)
    if to not in FORMATS:
        raise ReconError(f"unknown export format {to!r} (expected one of {', '.join(FORMATS)})")
    if not (run / "scan" / "scan.json").is_file():
        raise ReconError(f"{run}: not a finished run folder (no scan/scan.json; run `recon run` first)")
    target = Path(out) if out is not None else run / "export" / DEFAULT_NAMES[to]
    if target.is_symlink():
        raise ReconError(f"{target}: is a link; give another output path")
    if to in ("glb", "obj"):
        mesh = _run_mesh(run)
        with atomic_path(target) as tmp:
            mesh.export(tmp, file_type=to)
    elif to == "rerun":
        with atomic_path(target) as tmp:
            write_rerun(run, tmp)
    else:
        with atomic_dir(target) as tmp:
            (export_nerfstudio if to == "nerfstudio" else export_colmap)(run, tmp)
    return target


def _run_mesh(run: Path):
    from fusion.mesh import load_mesh

    path = run / "mesh.ply"
    if not path.is_file():
        raise ReconError(f"{run}: the run has no mesh.ply yet (its fusion stage has not finished)")
    return load_mesh(path)


def _copy_images(scan: Scan, folder: Path) -> list[str]:
    """The scan's image files (undistorted, at its size: a run's canonical scan) under folder/images/,
    named by frame; returns their names."""
    (folder / "images").mkdir(parents=True, exist_ok=True)
    names = []
    for i, f in enumerate(scan.frames):
        source = scan.image_file(i)
        names.append(f"{f.name}{source.suffix or '.jpg'}")
        shutil.copyfile(source, folder / "images" / names[-1])
    return names


def export_nerfstudio(run: Path, folder: Path) -> None:
    """transforms.json + images/: what `ns-train` (nerfacto, splatfacto) reads as a custom dataset."""
    scan = load_scan(run / "scan")
    names = _copy_images(scan, folder)
    doc = nerfstudio_transforms(scan, [f"images/{n}" for n in names])
    (folder / "transforms.json").write_text(json.dumps(doc, indent=1) + "\n")


def export_colmap(run: Path, folder: Path) -> None:
    """A COLMAP text model in sparse/0/ beside images/ (the layout COLMAP, gsplat and nerfstudio expect)."""
    scan = load_scan(run / "scan")
    names = _copy_images(scan, folder)
    points = colors = None
    if (run / "mesh.ply").is_file():
        mesh = _run_mesh(run)
        keep = np.random.default_rng(0).permutation(len(mesh.vertices))[:COLMAP_MAX_POINTS]
        keep.sort()
        points = np.asarray(mesh.vertices)[keep]
        colors = np.asarray(mesh.visual.vertex_colors)[keep, :3]
    write_colmap_text(scan, folder / "sparse" / "0", names, points, colors)


def write_rerun(run: Path, path: Path) -> None:
    """A Rerun recording: per frame (timeline `frame`) the camera pose with its frustum and image, and the
    predicted depth of keyframes; the mesh and the camera path as static data."""
    try:
        import rerun as rr
    except ImportError:
        raise ReconError("--to rerun needs the Rerun SDK: pip install 'recon-est[rerun]'") from None
    scan = load_scan(run / "scan")
    depth_dir = run / "depth"

    def pinhole(intr):
        return rr.Pinhole(focal_length=[intr.fx, intr.fy], principal_point=[intr.cx + PIXEL_CENTRE,
                          intr.cy + PIXEL_CENTRE], width=intr.width, height=intr.height,
                          camera_xyz=rr.ViewCoordinates.RDF)

    rec = rr.RecordingStream("recon", recording_id=str(run.resolve()))
    rec.save(str(path))
    rec.log("world/camera_path", rr.LineStrips3D([scan.camera_to_world[:, :3, 3]]), static=True)
    rec.log("world/camera/image", pinhole(scan.intrinsics), static=True)
    if (run / "mesh.ply").is_file():
        mesh = _run_mesh(run)
        rec.log("world/mesh", rr.Mesh3D(vertex_positions=np.asarray(mesh.vertices, np.float32),
                                        triangle_indices=np.asarray(mesh.faces, np.uint32),
                                        vertex_colors=np.asarray(mesh.visual.vertex_colors)[:, :3]), static=True)
    depth_grid = None
    for i, f in enumerate(scan.frames):
        rec.set_time("frame", sequence=i)
        rec.log("world/camera", rr.Transform3D(translation=f.camera_to_world[:3, 3], mat3x3=f.camera_to_world[:3, :3]))
        rec.log("world/camera/image", rr.EncodedImage(path=scan.image_file(i)))
        if not any((depth_dir / f"{f.name}{ext}").is_file() for ext in (".npy", ".png")):
            continue
        depth = load_depth_map(depth_dir, f.name)
        if depth_grid != depth.shape:  # predicted depth has its own grid (the network's), with its own pinhole
            depth_grid = depth.shape
            rec.log("world/camera/depth", pinhole(scan.intrinsics.resized(depth.shape[1], depth.shape[0])))
        rec.log("world/camera/depth", rr.DepthImage(depth, meter=1.0))
    rec.flush()
    rec.disconnect()  # closes the file, so the rename that follows moves a complete recording
