"""The shipping rules of experiments/ship_weights.py: what gets written, and when nothing is."""
import importlib.util
import json
from pathlib import Path

import pytest
import torch

import depth.checkpoint
from depth.checkpoint import load_checkpoint, save_checkpoint
from depth.config import COMPACT
from depth.model import ESTNet

SCRIPT = Path(__file__).resolve().parents[1] / "experiments" / "ship_weights.py"
PLANESWEEP = {"synthetic_1": {"abs_rel": 0.30, "a1": 0.50, "mesh_fscore": 0.20},
              "demo": {"abs_rel": 0.20, "a1": 0.60, "mesh_fscore": 0.50}}
COMPACT_ROW = {"synthetic_1": {"abs_rel": 0.18, "a1": 0.70, "mesh_fscore": 0.30},
               "demo": {"abs_rel": 0.22, "a1": 0.60, "mesh_fscore": 0.25}}


def _row(abs_rel: float, demo_f: float) -> dict:
    return {"synthetic_1": {"abs_rel": abs_rel, "a1": 0.75, "mesh_fscore": 0.35},
            "demo": {"abs_rel": abs_rel, "a1": 0.70, "mesh_fscore": demo_f}}


@pytest.fixture()
def ship(tmp_path, monkeypatch):
    """main() of the script, writing into a temporary weights folder; returns (run it, that folder)."""
    spec = importlib.util.spec_from_file_location("ship_weights", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    weights = tmp_path / "weights"
    weights.mkdir()
    monkeypatch.setattr(depth.checkpoint, "WEIGHTS_DIR", weights)
    run = tmp_path / "run"
    run.mkdir()
    (run / "log.jsonl").write_text(json.dumps({"kind": "val", "step": 7, "abs_rel": 0.2}) + "\n")
    torch.manual_seed(0)

    def main(step: int, rows: dict) -> int:
        ckpt = save_checkpoint(run / f"step_{step:06d}.pt", ESTNet(COMPACT), COMPACT, {"steps": step})
        sel = tmp_path / "summary.json"
        sel.write_text(json.dumps({"planesweep": PLANESWEEP, "compact:estm_m2": COMPACT_ROW,
                                   **{f"{k}:estm_m2": v for k, v in rows.items()}}))
        return module.main([str(ckpt), "--run", str(run), "--selection", str(sel), "--name", "lite",
                            "--incumbent", "compact"])

    main.shipped_rows = module.shipped_rows
    return main, weights


def test_depth_worse_than_the_plane_sweep_ships_nothing(ship):
    main, weights = ship
    assert main(1, {"step_000001": _row(0.35, 0.6)}) == 1
    assert list(weights.iterdir()) == []


def test_a_lineage_that_beats_the_plane_sweep_depth_ships_a_preview_that_only_a_better_one_replaces(ship):
    main, weights = ship
    assert main(1, {"step_000001": _row(0.25, 0.3)}) == 0  # worse than compact, mesh rule fails
    preview = weights / "lite-preview.pt"
    assert [p.name for p in weights.iterdir()] == ["lite-preview.pt"]
    assert load_checkpoint(preview).metadata["steps"] == 1
    # the preview's own shipped figures (0.25) decide, not a selection row left from an older preview file
    assert main(3, {"step_000003": _row(0.26, 0.3), "lite-preview": _row(0.30, 0.3)}) == 1
    assert load_checkpoint(preview).metadata["steps"] == 1
    assert main(4, {"step_000004": _row(0.24, 0.3)}) == 0
    assert load_checkpoint(preview).metadata["steps"] == 4
    assert load_checkpoint(preview).metadata["validation"]["rules"]["beats compact"] is False
    save_checkpoint(preview, ESTNet(COMPACT), COMPACT, {"steps": 9})  # a preview that records no figures
    with pytest.raises(SystemExit, match="did not score it"):
        main(5, {"step_000005": _row(0.20, 0.3)})
    assert main(6, {"step_000006": _row(0.20, 0.3), "lite-preview": _row(0.21, 0.3)}) == 0


def test_passing_every_rule_ships_the_named_weights(ship):
    main, weights = ship
    assert main(5, {"step_000005": _row(0.15, 0.6)}) == 0
    assert load_checkpoint(weights / "lite.pt").metadata["validation"]["rules"] == {
        "beats plane sweep depth": True, "beats plane sweep mesh on every scan": True, "beats compact": True,
        "beats compact on every scan": True}


def test_beating_an_incumbent_that_loses_to_the_plane_sweep_on_every_scan_ships_the_default(ship):
    """compact loses the demo mesh to the plane sweep (0.25 vs 0.50); a network that fails that too (0.45)
    but beats compact on every scan replaces it, while one that is worse on one scan only ships a preview."""
    main, weights = ship
    better_on_means_only = {"synthetic_1": {"abs_rel": 0.12, "a1": 0.75, "mesh_fscore": 0.40},
                            "demo": {"abs_rel": 0.23, "a1": 0.70, "mesh_fscore": 0.45}}
    assert main(1, {"step_000001": better_on_means_only}) == 0
    assert [p.name for p in weights.iterdir()] == ["lite-preview.pt"]
    assert main(2, {"step_000002": _row(0.17, 0.45)}) == 0
    rules = load_checkpoint(weights / "lite.pt").metadata["validation"]["rules"]
    assert rules["beats plane sweep mesh on every scan"] is False
    assert rules["beats compact on every scan"] is True


def test_a_shipped_file_gives_back_the_rows_that_decided_it(ship):
    """A fresh machine without runs/ rebuilds the selection from the shipped file (select_checkpoint --rows-from):
    the plane sweep's, the incumbent's and the file's own rows, exactly as they were scored."""
    main, weights = ship
    assert main(1, {"step_000001": _row(0.25, 0.3)}) == 0
    assert main.shipped_rows(weights / "lite-preview.pt") == {
        "planesweep": PLANESWEEP, "compact:estm_m2": COMPACT_ROW, "step_000001:estm_m2": _row(0.25, 0.3)}
