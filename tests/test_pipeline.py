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
    assert 3 <= len(keys) < 40 and len(list((finished_run / "depth").glob("*.conf.png"))) == len(keys)


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
    while time.time() < deadline and len(list((killed / "depth").glob("*.conf.png"))) < 5:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = {p.name: p.stat().st_mtime_ns for p in (killed / "depth").glob("*.png")}
    assert 5 <= len([n for n in done_before if n.endswith(".conf.png")]) < 12, "kill did not land in the depth stage"
    assert len(list((killed / "depth" / ".estm-memory").glob("*.pt"))) >= 2  # the memory it resumes with
    assert not (killed / "mesh.ply").exists()
    assert recon(*args, "--out", str(killed)).returncode == 0
    for name, mtime in done_before.items():  # finished frames were not redone
        assert (killed / "depth" / name).stat().st_mtime_ns == mtime
    assert same_surface(whole / "mesh.ply", killed / "mesh.ply")


def test_bad_input_keeps_finished_stages(finished_run, room, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(finished_run, out)
    (tmp_path / "broken.ply").write_bytes(b"not a mesh")  # exists, so only the reference stage finds it broken
    proc = recon("run", str(room), "--out", str(out), "--mode", "planesweep", "--voxel-size", "0.05",
                 "--gt-mesh", str(tmp_path / "broken.ply"))
    assert proc.returncode == 2 and "broken.ply" in proc.stderr.strip().splitlines()[-1]
    assert (out / "mesh.ply").is_file() and (out / "depth/depth.json").is_file()
    state = json.loads((out / "run.json").read_text())["stages"]
    assert state["fusion"]["done"] and "reference" not in state
    # A missing file named by an option is refused before the first stage: the run folder is left as it was.
    before = (out / "run.json").read_bytes()
    proc = recon("run", str(room), "--out", str(out), "--mode", "planesweep", "--gt-mesh", str(tmp_path / "missing.ply"))
    assert proc.returncode == 2 and "missing.ply" in proc.stderr.strip().splitlines()[-1]
    assert (out / "run.json").read_bytes() == before
    assert recon("run", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")).returncode == 2


def same_surface(a: Path, b: Path) -> bool:
    """Two meshes with the same vertices (Open3D's hash map may order them differently)."""
    va, vb = (np.asarray(trimesh.load(m).vertices) for m in (a, b))
    va, vb = (v[np.lexsort(v.T)] for v in (va, vb))
    return va.shape == vb.shape and np.allclose(va, vb, atol=1e-5)


def kill_when(args: list[str], out: Path, landed) -> None:
    """Start `recon run`, SIGKILL it as soon as `landed()` says it is inside the stage under test."""
    proc = subprocess.Popen([sys.executable, "-m", "apps.cli", *args, "--out", str(out)], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and not landed():
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()


def _stages(out: Path) -> dict:
    try:
        return json.loads((out / "run.json").read_text())["stages"]
    except (OSError, ValueError, KeyError):
        return {}


@pytest.mark.slow
def test_killed_during_scan_resumes_to_the_same_mesh(finished_run, room, tmp_path):
    """SIGKILL while the scan stage writes its images; the re-run clears the half-written folder and ends with
    the uninterrupted run's mesh."""
    out = tmp_path / "killed"
    kill_when(["run", str(room), "--mode", "planesweep", "--quiet"], out,
              lambda: any(any(t.glob("images/*.jpg")) for t in out.glob(".scan.tmp-*")))
    assert not (out / "scan" / "scan.json").exists(), "kill did not land in the scan stage"
    assert list(out.glob(".scan.tmp-*")), "the killed stage left no temporary folder"
    assert recon("run", str(room), "--mode", "planesweep", "--quiet", "--out", str(out)).returncode == 0
    assert not list(out.glob(".scan.tmp-*")) and not list(out.glob(".scan.old-*"))  # what the kill left is gone
    assert same_surface(finished_run / "mesh.ply", out / "mesh.ply")


@pytest.mark.slow
def test_killed_during_fusion_resumes_to_the_same_mesh(finished_run, room, tmp_path):
    """SIGKILL inside the fusion stage; the re-run keeps the finished depth maps and fuses the same mesh."""
    out = tmp_path / "killed"
    kill_when(["run", str(room), "--mode", "planesweep", "--quiet"], out,
              lambda: _stages(out).get("depth", {}).get("done") and "fusion" not in _stages(out))
    assert _stages(out)["depth"]["done"] and not (out / "mesh.ply").exists(), "kill did not land in fusion"
    depth_times = {p.name: p.stat().st_mtime_ns for p in (out / "depth").glob("*.png")}
    assert len(depth_times) > 3
    assert recon("run", str(room), "--mode", "planesweep", "--quiet", "--out", str(out)).returncode == 0
    assert {p.name: p.stat().st_mtime_ns for p in (out / "depth").glob("*.png")} == depth_times
    assert same_surface(finished_run / "mesh.ply", out / "mesh.ply")


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def open_in_chromium(browser: str, page: Path, profile: Path) -> tuple[str, list[str]]:
    """Load `page` in headless Chromium with software WebGL (SwiftShader); returns the DOM once it settled and
    the URLs the page itself asked the network for (from Chromium's net log: the browser's own background
    requests carry no page origin and are left out)."""
    netlog = profile.with_suffix(".netlog.json")
    proc = subprocess.run([browser, "--headless", "--no-sandbox", "--use-angle=swiftshader",
                           "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
                           "--disable-background-networking", "--disable-component-update", "--disable-sync",
                           f"--user-data-dir={profile}", f"--log-net-log={netlog}", "--virtual-time-budget=30000",
                           "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=180)
    assert "</body>" in proc.stdout, proc.stderr[-2000:]
    log = json.loads(netlog.read_text())
    start = log["constants"]["logEventTypes"]["URL_REQUEST_START_JOB"]
    asked = [e.get("params", {}) for e in log["events"] if e["type"] == start]
    urls = [p["url"] for p in asked if "url" in p and p.get("initiator") != "not an origin"]  # (end events: no url)
    return proc.stdout, [u for u in urls if not u.startswith(("data:", "blob:", "file:"))]


def _body(dom: str) -> dict:
    """The data-* attributes the report's own checks leave on <body>."""
    import re

    tag = re.search(r"<body([^>]*)>", dom).group(1)
    return dict(re.findall(r'data-([a-z0-9-]+)="([^"]*)"', tag))


def test_report_loads_in_a_real_browser(finished_run, tmp_path):
    """report.html opened from the file, offline: every picture decodes, the 3D view draws through WebGL
    (the mesh alone covers part of its image), no script error, and the page asks the network for nothing."""
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium installed (make setup installs it when it can)")
    # The detector sees a page's requests: a page that does fetch is caught.
    leaky = tmp_path / "leaky.html"
    leaky.write_text('<!doctype html><body><img src="http://plotly.invalid/logo.png"></body>')
    assert set(open_in_chromium(browser, leaky, tmp_path / "p0")[1]) == {"http://plotly.invalid/logo.png"}

    dom, requests = open_in_chromium(browser, finished_run / "report.html", tmp_path / "p1")
    body = _body(dom)
    assert "<h1>Reconstruction report</h1>" in dom and requests == []
    assert "errors" not in body and "blocked" not in body, body
    assert int(body["images"]) >= 6 and body["images-loaded"] == body["images"]  # depth tiles, scales, renders
    assert body["view3d"] == "drawn", body
    assert float(body["view3d-coverage"]) > 0.02 and float(body["view3d-mesh-coverage"]) > 0.005, body
    report = json.loads((finished_run / "report.json").read_text())
    for label in ("3D view", "Per-frame error and flicker", "Stage timings", "depth accuracy", "mesh accuracy"):
        assert label in dom, label
    assert f"{report['depth']['abs_rel']:.4f}" in dom and f"{report['mesh']['fscore']:.4f}" in dom
