"""`recon batch`: one folder per scan, a summary, resume, a broken scan recorded and not fatal; Ray for real."""
import json
import shutil
from pathlib import Path

import pytest

from apps.batch import run_batch
from apps.pipeline import InputConfig, RunConfig
from depth.options import DepthOptions
from recon.keyframes import KeyframeConfig


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
    return out, run_batch(dataset, out, template(), engine="local", workers=2, on_result=seen.append), seen


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
    summary = run_batch(dataset, tmp_path, template(), engine="ray", cpus_per_scan=1)
    assert summary["counts"]["done"] == 2 and summary["counts"]["failed"] == 1
    local_dir = local_run[0]
    for room in ("room11", "room12"):  # the same deterministic work, run as Ray tasks
        ray_report = json.loads((tmp_path / room / "report.json").read_text())
        local_report = json.loads((local_dir / room / "report.json").read_text())
        assert ray_report["mesh"] == pytest.approx(local_report["mesh"])
        assert ray_report["depth"] == local_report["depth"]


def test_list_file_and_bad_dataset(dataset, tmp_path):
    from recon.errors import ReconError

    listing = tmp_path / "scans.txt"
    listing.write_text(f"# two rooms\n{dataset / 'room11'}\n")
    summary = run_batch(listing, tmp_path / "out", template())
    assert summary["counts"]["done"] == 1
    with pytest.raises(ReconError, match="no scan found"):
        run_batch(tmp_path / "out" / "room11" / "depth", tmp_path / "x", template())
