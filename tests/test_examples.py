"""The scripts in examples/ run as a user would run them (examples/evaluate_7scenes.py: tests/test_results_7scenes.py)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def example(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}  # a checkout, as a reader of examples/ would have it
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=900, env=env)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    from recon.synthetic import SynthConfig, write_synthetic_scan

    root = tmp_path_factory.mktemp("rooms")
    for seed in (21, 22):
        write_synthetic_scan(SynthConfig(seed=seed, frames=20, width=96, height=72), root / f"room{seed}")
    return root


def test_reconstruct_example_runs_and_exports(dataset, tmp_path):
    out = tmp_path / "run"
    proc = example("examples/reconstruct.py", str(dataset / "room21"), str(out), "--mode", "planesweep",
                   "--export", "glb", "nerfstudio")
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed = json.loads(proc.stdout[:proc.stdout.index("\nmesh: ")])
    assert 0 < printed["depth"]["abs_rel"] < 1 and 0 <= printed["mesh"]["fscore"] <= 1
    assert (out / "report.html").is_file() and (out / "export" / "mesh.glb").is_file()
    assert (out / "export" / "nerfstudio" / "transforms.json").is_file()


@pytest.mark.slow
def test_batch_example_runs_every_scan(dataset, tmp_path):
    proc = example("examples/batch_dataset.py", str(dataset), str(tmp_path / "batch"), "--mode", "planesweep")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "{'done': 2, 'skipped': 0, 'failed': 0}" in proc.stdout
    summary = json.loads((tmp_path / "batch" / "summary.json").read_text())
    assert sorted(r["name"] for r in summary["scans"]) == ["room21", "room22"]
