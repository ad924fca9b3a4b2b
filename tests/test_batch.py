"""`recon batch`: one folder per scan, a summary, resume, a broken scan recorded and not fatal; Ray for real."""
import json
import re
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from apps.batch import run_batch
from apps.pipeline import EvalConfig, InputConfig, RunConfig
from depth.options import DepthOptions
from fusion.evaluate import mesh_metrics
from recon.keyframes import KeyframeConfig
from recon.readers import open_scan

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    from recon.synthetic import SynthConfig, write_synthetic_scan

    root = tmp_path_factory.mktemp("dataset")
    for seed in (11, 12):
        write_synthetic_scan(SynthConfig(seed=seed, frames=24, width=96, height=72), root / f"room{seed}")
    broken = root / "broken"
    shutil.copytree(root / "room11", broken)
    (broken / "images" / sorted(p.name for p in (broken / "images").iterdir())[3]).write_bytes(b"not an image")
    (root / "notes").mkdir()  # not a scan: ignored
    return root


def template():
    return RunConfig(InputConfig(), "", keyframes=KeyframeConfig(0.05), depth=DepthOptions(mode="planesweep"))


@pytest.fixture(scope="module")
def local_run(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    seen = []
    # One thread per scan, as each Ray task below gets: the same work with the same floating-point sums.
    return out, run_batch(dataset, out, template(), engine="local", workers=2, cpus_per_scan=1,
                          on_result=seen.append), seen


def test_local_batch_summary_resume_and_failure(dataset, local_run):
    tmp_path, summary, seen = local_run
    assert len(seen) == 3
    assert summary["counts"] == {"done": 2, "skipped": 0, "failed": 1}
    failed = next(r for r in summary["scans"] if r["status"] == "failed")
    assert failed["name"] == "broken" and "unreadable image" in failed["error"]
    done = [r for r in summary["scans"] if r["status"] == "done"]
    assert all(r["mesh.fscore"] is not None for r in done)
    assert summary["mean"]["mesh.fscore"] == pytest.approx(sum(r["mesh.fscore"] for r in done) / 2)
    for name in ("summary.csv", "summary.json", "index.html", "room11/report.html", "room12/mesh.ply"):
        assert (tmp_path / name).is_file(), name
    assert "broken" in (tmp_path / "summary.csv").read_text()
    again = run_batch(dataset, tmp_path, template(), engine="local", workers=1)
    assert again["counts"] == {"done": 0, "skipped": 2, "failed": 1}


def test_ray_batch_matches_local(dataset, local_run, tmp_path):
    pytest.importorskip("ray")
    # `recon batch` as a user runs it (the same settings as template()), its terminal output read as they see it.
    proc = subprocess.run([sys.executable, "-m", "apps.cli", "batch", str(dataset), "--out", str(tmp_path),
                           "--engine", "ray", "--cpus-per-scan", "1", "--mode", "planesweep",
                           "--keyframe-distance", "0.05"], cwd=ROOT, capture_output=True, text=True, timeout=900)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert proc.returncode == 1 and summary["counts"]["done"] == 2 and summary["counts"]["failed"] == 1, proc.stderr
    # Workers' stage lines reach the driver prefixed by their scan; Ray's notice about token authentication does not.
    err = proc.stderr
    for room in ("room11", "room12"):  # each scan's own lines, none merged into another's
        assert any(f"({room} pid=" in line and "fusion: done in" in line for line in err.splitlines()), err[-3000:]
    assert "repeated" not in err, err[-3000:]
    assert "Token authentication" not in err
    local_dir = local_run[0]
    for room in ("room11", "room12"):  # the same deterministic work, run as Ray tasks
        ray_report = json.loads((tmp_path / room / "report.json").read_text())
        local_report = json.loads((local_dir / room / "report.json").read_text())
        assert ray_report["depth"] == local_report["depth"]
        assert ray_report["mesh"] == pytest.approx(local_report["mesh"])


def test_list_file_and_bad_dataset(dataset, tmp_path):
    from recon.errors import ReconError

    listing = tmp_path / "scans.txt"
    listing.write_text(f"# two rooms\n{dataset / 'room11'}\n")
    summary = run_batch(listing, tmp_path / "out", template())
    assert summary["counts"]["done"] == 1
    with pytest.raises(ReconError, match="no scan found"):
        run_batch(tmp_path / "out" / "room11" / "depth", tmp_path / "x", template())
    with pytest.raises(ReconError, match="--cpus-per-scan must be > 0"):
        run_batch(listing, tmp_path / "y", template(), cpus_per_scan=0)
    assert not (tmp_path / "y").exists()


def test_skip_check_covers_every_stage(dataset, local_run, tmp_path):
    """Another --gt-mesh re-scores each scan (the reference stage is in the skip check); depth and mesh stay."""
    out = tmp_path / "copy"
    shutil.copytree(local_run[0], out)
    counts = local_run[1]["counts"]
    assert counts["done"] >= 1 and (out / "room11" / "report.json").is_file()
    before = json.loads((out / "room11" / "report.json").read_text())["mesh"]
    mesh_time = (out / "room11" / "mesh.ply").stat().st_mtime_ns
    assert run_batch(dataset, out, template())["counts"]["skipped"] == counts["done"]  # the copy is current
    other = replace(template(), evaluation=EvalConfig(gt_mesh=str(dataset / "room12" / "gt_mesh.ply")))
    summary = run_batch(dataset, out, other)
    assert summary["counts"] == {**counts, "skipped": 0}
    report = json.loads((out / "room11" / "report.json").read_text())
    assert report["stages"]["reference"]["source"].endswith("room12/gt_mesh.ply")
    # scored against the other room's mesh now: exactly what scoring this mesh against that mesh gives
    expected = mesh_metrics(out / "room11" / "mesh.ply", dataset / "room12" / "gt_mesh.ply",
                            scan=open_scan(out / "room11" / "scan"))
    assert report["mesh"]["comp"] == pytest.approx(expected["comp"], rel=1e-6)
    assert report["mesh"]["fscore"] == pytest.approx(expected["fscore"], rel=1e-6)
    assert report["mesh"]["comp"] != pytest.approx(before["comp"], rel=1e-3)
    assert (out / "room11" / "mesh.ply").stat().st_mtime_ns == mesh_time


def test_corrupt_gt_mesh_is_refused_before_any_scan(dataset, tmp_path):
    from recon.errors import ReconError

    (tmp_path / "broken.ply").write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    with pytest.raises(ReconError, match="broken.ply"):
        run_batch(dataset, tmp_path / "out",
                  replace(template(), evaluation=EvalConfig(gt_mesh=str(tmp_path / "broken.ply"))))
    assert not (tmp_path / "out").exists()


def test_index_links_stay_paths_for_hostile_names(tmp_path):
    """A scan folder named like a URL or markup links to its own report.html, never runs as script."""
    from urllib.parse import unquote, urljoin, urlparse

    from apps.batch import write_summary

    names = ["javascript:alert(document.domain)", "x' onmouseover='alert(1)", "<script>alert(1)</script>", "data:,x"]
    write_summary([{"name": n, "status": "done", "seconds": 1.0, "report": {}} for n in names], tmp_path)
    page = (tmp_path / "index.html").read_text()
    hrefs = re.findall(r'href="([^"]*)"', page)
    assert len(hrefs) == len(names) and "<script>" not in page
    index = (tmp_path / "index.html").resolve().as_uri()
    targets = {unquote(urlparse(urljoin(index, h)).path) for h in hrefs}
    assert all(h.startswith("./") for h in hrefs)
    assert targets == {str(tmp_path.resolve() / n / "report.html") for n in names}
