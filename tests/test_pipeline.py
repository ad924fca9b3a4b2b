"""`recon run` end to end on a small synthetic room: outputs, caching, resume after SIGKILL, lock, report."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from recon.errors import ReconError
from apps.pipeline import InputConfig, Pipeline, RunConfig, RunLock
from depth.options import DepthOptions
from fusion.tsdf import TSDFConfig

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    from recon.synthetic import SynthConfig, write_synthetic_scan

    return write_synthetic_scan(SynthConfig(seed=3, frames=40, width=128, height=96),
                                tmp_path_factory.mktemp("room") / "scan")


@pytest.fixture(scope="module")
def random_weights(tmp_path_factory) -> Path:
    """An untrained compact network: the ESTM path end to end without shipped weights."""
    from depth.checkpoint import save_checkpoint
    from depth.config import get_config
    from depth.model import ESTNet

    torch.manual_seed(0)
    config = get_config("compact")
    return save_checkpoint(tmp_path_factory.mktemp("w") / "random.pt", ESTNet(config), config,
                           metadata={"note": "random init, for tests"})


def recon(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "apps.cli", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def finished_run(room, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "out"
    Pipeline(RunConfig(InputConfig(str(room)), str(out), depth=DepthOptions(mode="planesweep"))).run()
    return out


def test_run_writes_every_output(finished_run):
    for name in ("scan/scan.json", "keyframes.json", "depth/depth.json", "mesh.ply", "reference.ply",
                 "metrics.json", "report.json", "report.html", "run.json"):
        assert (finished_run / name).is_file(), name
    report = json.loads((finished_run / "report.json").read_text())
    assert set(report["depth"]) >= {"abs_rel", "abs", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3"}
    assert set(report["temporal"]) == {"mae_mean", "mae_std", "flicker"}
    assert set(report["mesh"]) >= {"acc", "comp", "chamfer", "prec", "recall", "fscore"}
    assert "poses" not in report  # supplied poses: nothing to score them against
    assert set(report["timing"]) == {"scan", "depth", "fusion", "reference", "evaluate"}
    assert report["memory"]["peak_rss_mb"] > 50 and report["metric_scale"] is True
    # The reference is the room's exact mesh. The plane sweep leaves blank walls empty (low coverage and
    # completeness), but what it does reconstruct must be right: depth within 25 % and surfaces within 10 cm.
    depth, mesh = report["depth"], report["mesh"]
    assert 0.02 < depth["coverage"] and depth["a1"] / depth["coverage"] > 0.8
    assert mesh["prec"] > 0.5 and mesh["acc"] < 0.1
    keys = json.loads((finished_run / "keyframes.json").read_text())["keyframes"]
    assert 3 <= len(keys) < 40 and len(list((finished_run / "depth").glob("*.conf.npy"))) == len(keys)


def test_rerun_skips_finished_stages_and_force_redoes(finished_run, room):
    mesh_time = (finished_run / "mesh.ply").stat().st_mtime_ns
    pipeline = Pipeline(RunConfig(InputConfig(str(room)), str(finished_run), depth=DepthOptions(mode="planesweep")))
    pipeline.run()
    assert (finished_run / "mesh.ply").stat().st_mtime_ns == mesh_time
    pipeline.run(force=("fusion",))
    assert (finished_run / "mesh.ply").stat().st_mtime_ns != mesh_time
    depth_time = (finished_run / "depth/depth.json").stat().st_mtime_ns
    assert depth_time == (finished_run / "depth/depth.json").stat().st_mtime_ns
    # Another voxel size changes the fusion's options: fusion and what follows rerun, depth does not.
    Pipeline(RunConfig(InputConfig(str(room)), str(finished_run), depth=DepthOptions(mode="planesweep"),
                       fusion=TSDFConfig(voxel_size=0.05))).run()
    assert (finished_run / "depth/depth.json").stat().st_mtime_ns == depth_time
    state = json.loads((finished_run / "run.json").read_text())
    assert state["config"]["fusion"]["voxel_size"] == 0.05


def test_second_run_in_same_folder_refuses(finished_run, room):
    with RunLock(finished_run):
        with pytest.raises(ReconError, match="another run"):
            Pipeline(RunConfig(InputConfig(str(room)), str(finished_run), depth=DepthOptions(mode="planesweep"))).run()
    proc_lock = RunLock(finished_run)
    with proc_lock:  # released after the first holder left
        pass


def test_killed_run_resumes_to_the_same_mesh(room, random_weights, tmp_path):
    """SIGKILL in the middle of the ESTM depth stage, same command again: same mesh as an uninterrupted run."""
    args = ["run", str(room), "--mode", "estm", "--weights", str(random_weights), "--keyframe-distance", "0",
            "--max-frames", "12", "--depth-range", "0.3", "8", "--quiet"]
    whole = tmp_path / "whole"
    assert recon(*args, "--out", str(whole)).returncode == 0
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "apps.cli", *args, "--out", str(killed)], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and len(list((killed / "depth").glob("*.conf.npy"))) < 5:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = {p.name: p.stat().st_mtime_ns for p in (killed / "depth").glob("*.npy")}
    assert 5 <= len([n for n in done_before if n.endswith(".conf.npy")]) < 12, "kill did not land in the depth stage"
    assert len(list((killed / "depth" / ".estm-memory").glob("*.pt"))) >= 2  # the memory it resumes with
    assert not (killed / "mesh.ply").exists()
    assert recon(*args, "--out", str(killed)).returncode == 0
    for name, mtime in done_before.items():  # finished frames were not redone
        assert (killed / "depth" / name).stat().st_mtime_ns == mtime
    a, b = trimesh.load(whole / "mesh.ply"), trimesh.load(killed / "mesh.ply")
    # Open3D's hash map may order vertices differently; the surfaces must be the same.
    va, vb = (np.asarray(m.vertices)[np.lexsort(np.asarray(m.vertices).T)] for m in (a, b))
    assert va.shape == vb.shape and np.allclose(va, vb, atol=1e-5)


def test_bad_input_keeps_finished_stages(finished_run, room, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(finished_run, out)
    proc = recon("run", str(room), "--out", str(out), "--mode", "planesweep", "--voxel-size", "0.05",
                 "--gt-mesh", str(tmp_path / "missing.ply"))
    assert proc.returncode == 2 and "missing.ply" in proc.stderr.strip().splitlines()[-1]
    assert (out / "mesh.ply").is_file() and (out / "depth/depth.json").is_file()
    state = json.loads((out / "run.json").read_text())["stages"]
    assert state["fusion"]["done"] and "reference" not in state
    assert recon("run", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")).returncode == 2


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def test_report_loads_in_a_real_browser(finished_run, tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium installed (make setup installs it when it can)")
    proc = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                           "--disable-background-networking", "--disable-component-update", "--disable-sync",
                           f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=5000", "--dump-dom",
                           (finished_run / "report.html").as_uri()], capture_output=True, text=True, timeout=120)
    dom = proc.stdout
    assert "<h1>Reconstruction report</h1>" in dom, proc.stderr[-2000:]
    import re

    images = int(re.search(r'data-images="(\d+)"', dom).group(1))
    loaded = int(re.search(r'data-images-loaded="(\d+)"', dom).group(1))
    assert images >= 6 and loaded == images  # depth panels + mesh previews all decoded
    assert "data-errors" not in dom
    assert "<svg" in dom and "Camera path" in dom
