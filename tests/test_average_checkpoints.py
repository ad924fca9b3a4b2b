"""experiments/average_checkpoints.py: run folders stand for their last step files."""
import importlib.util
from pathlib import Path

import pytest
import torch

from depth.checkpoint import load_checkpoint, save_checkpoint
from depth.config import TINY
from depth.model import ESTNet

SCRIPT = Path(__file__).resolve().parents[1] / "experiments" / "average_checkpoints.py"


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("average_checkpoints", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(folder: Path, steps: list[int]) -> list[Path]:
    """A run folder holding step files (and a last.pt, which is not a step file)."""
    folder.mkdir()
    torch.manual_seed(len(steps))
    paths = [save_checkpoint(folder / f"step_{s:06d}.pt", ESTNet(TINY), TINY, {"steps": s}) for s in steps]
    save_checkpoint(folder / "last.pt", ESTNet(TINY), TINY, {"steps": steps[-1]})
    return paths


def test_run_folders_give_their_last_step_files_in_step_order(script, tmp_path):
    a = _run(tmp_path / "a", [900, 1000, 1100, 10_000])
    b = _run(tmp_path / "b", [1200, 1250])
    single = tmp_path / "single.pt"
    save_checkpoint(single, ESTNet(TINY), TINY, {"steps": 5})
    files = script.expand_runs([str(tmp_path / "a"), str(single), str(tmp_path / "b")], last=3)
    assert files == [str(p) for p in a[1:]] + [str(single)] + [str(p) for p in b]

    out = tmp_path / "mean.pt"
    assert script.main([str(tmp_path / "a"), str(tmp_path / "b"), "--last", "2", "--out", str(out)]) == 0
    mean = load_checkpoint(out)
    assert mean.metadata["averaged_from"] == [str(p) for p in a[2:] + b]


def test_a_run_folder_without_step_files_stops_with_its_name(script, tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="no step_\\*.pt in .*empty"):
        script.expand_runs([str(tmp_path / "empty")], last=4)
