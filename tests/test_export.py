"""`recon export`: every format opened by its own tool's reader, and the cameras read back by ours."""
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from apps.cli import main
from apps.export import export_run
from recon.errors import ReconError
from recon.readers import open_scan
from recon.scan import load_scan


@pytest.fixture
def run_dir(small_run) -> Path:
    return small_run


def _same_cameras(read, scan, atol=1e-6):
    """`read` (a scan from one of our readers) has `scan`'s frames, poses and intrinsics."""
    assert read.names == scan.names
    assert np.allclose(read.camera_to_world, scan.camera_to_world, atol=atol)
    a, b = read.intrinsics, scan.intrinsics
    assert (a.width, a.height) == (b.width, b.height)
    assert np.allclose([a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], atol=1e-6)


@pytest.mark.parametrize("fmt", ["glb", "obj"])
def test_mesh_exports_open_in_trimesh(run_dir, fmt, tmp_path):
    path = export_run(run_dir, fmt, tmp_path / f"room.{fmt}")
    mesh = trimesh.load(path, force="mesh", process=False)
    original = trimesh.load(run_dir / "mesh.ply", process=False)
    assert len(mesh.faces) == len(original.faces) > 0
    assert np.allclose(np.sort(mesh.vertices, axis=0), np.sort(original.vertices, axis=0), atol=1e-5)
    colors = np.asarray(mesh.visual.vertex_colors)[:, :3].astype(float)
    source = np.asarray(original.visual.vertex_colors)[:, :3].astype(float)
    assert colors.std() > 0 and np.allclose(colors.mean(0), source.mean(0), atol=1.0)  # the colours travelled


def test_nerfstudio_export_reads_back_as_the_run(run_dir, tmp_path):
    import json

    folder = export_run(run_dir, "nerfstudio", tmp_path / "ns")
    doc = json.loads((folder / "transforms.json").read_text())
    scan = load_scan(run_dir / "scan")
    # nerfstudio's conventions: OpenGL camera axes (y up, z back) and pixel centres at +0.5.
    gl = np.array(doc["frames"][0]["transform_matrix"])
    assert np.allclose(gl[:3, 1], -scan.camera_to_world[0][:3, 1]) and np.allclose(gl[:3, 2],
                                                                                   -scan.camera_to_world[0][:3, 2])
    assert doc["cx"] == pytest.approx(scan.intrinsics.cx + 0.5)
    assert all((folder / f["file_path"]).is_file() for f in doc["frames"])
    _same_cameras(open_scan(folder), scan)


def test_colmap_export_opens_in_pycolmap_and_reads_back(run_dir, tmp_path):
    import pycolmap

    from recon.geometry import invert_pose

    folder = export_run(run_dir, "colmap", tmp_path / "colmap")
    scan = load_scan(run_dir / "scan")
    rec = pycolmap.Reconstruction(str(folder / "sparse" / "0"))
    assert rec.num_images() == len(scan) and rec.num_cameras() == 1
    mesh = trimesh.load(run_dir / "mesh.ply", process=False)
    assert rec.num_points3D() == min(len(mesh.vertices), 200_000)
    camera = rec.cameras[1]
    assert camera.model_name == "PINHOLE" and camera.params[2] == pytest.approx(scan.intrinsics.cx + 0.5)
    first = next(im for im in rec.images.values() if im.name.startswith(scan.names[0]))
    expected = invert_pose(scan.camera_to_world[0])  # COLMAP keeps world-to-camera
    assert np.allclose(first.cam_from_world().matrix(), expected[:3], atol=1e-6)
    _same_cameras(open_scan(folder), scan)


def test_rerun_export_opens_in_rerun(run_dir, tmp_path):
    pytest.importorskip("rerun", reason="the rerun extra (pip install 'recon-est[rerun]') is not installed")
    from rerun.chunk import RrdReader

    path = export_run(run_dir, "rerun", tmp_path / "room.rrd")
    reader = RrdReader(path)
    assert [r.application_id for r in reader.recordings()] == ["recon"]
    rows = {}  # (entity, archetype) -> logged rows, from chunk lines "/world/camera rows=30 ... cols=['Transform3D:…']"
    for line in reader.store().summary().splitlines():
        entity, rest = line.split(" rows=")
        archetype = rest.split("cols=['")[1].split(":")[0]
        rows[entity, archetype] = rows.get((entity, archetype), 0) + int(rest.split()[0])
    scan = load_scan(run_dir / "scan")
    keyframes = len(list((run_dir / "depth").glob("*.conf.png")))
    assert rows["/world/camera", "Transform3D"] == len(scan) == rows["/world/camera/image", "EncodedImage"]
    assert rows["/world/camera/image", "Pinhole"] == 1 and rows["/world/camera/depth", "DepthImage"] == keyframes > 0
    assert rows["/world/mesh", "Mesh3D"] == 1 and rows["/world/camera_path", "LineStrips3D"] == 1


def test_export_refuses_bad_input_in_one_line(run_dir, tmp_path, capsys):
    with pytest.raises(ReconError, match="not a finished run"):
        export_run(tmp_path, "glb")
    with pytest.raises(ReconError, match="unknown export format"):
        export_run(run_dir, "fbx")
    link = tmp_path / "link.glb"
    link.symlink_to(tmp_path / "elsewhere.glb")
    with pytest.raises(ReconError, match="is a link"):
        export_run(run_dir, "glb", link)
    assert not (tmp_path / "elsewhere.glb").exists()
    assert main(["export", str(tmp_path / "missing"), "--to", "obj"]) == 2
    assert capsys.readouterr().err.startswith("recon: error: ")
    assert main(["export", str(run_dir), "--to", "obj", "--out", str(tmp_path / "cli.obj")]) == 0
    assert (tmp_path / "cli.obj").is_file() and not list(tmp_path.glob(".cli*"))  # no temporary left over
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    assert main(["export", str(copy), "--to", "nerfstudio"]) == 0  # by default into the run folder
    assert (copy / "export" / "nerfstudio" / "transforms.json").is_file()
    assert main(["export", str(copy), "--to", "nerfstudio"]) == 0  # a second export replaces the first
    assert sorted(p.name for p in (copy / "export").iterdir()) == ["nerfstudio"]
