"""The zero-shot evaluation script (issue 6) end to end on a few 7-Scenes frames, and the shipped weights."""
import importlib.util
import json
import math
from pathlib import Path

import pytest
import torch

from depth.checkpoint import DEFAULT_WEIGHTS
from depth.checkpoint import WEIGHTS_DIR, build_model, load_checkpoint, save_checkpoint
from depth.config import COMPACT, CONFIGS
from depth.model import ESTNet


@pytest.fixture(scope="module")
def random_weights(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("w") / "random.pt"
    return save_checkpoint(path, ESTNet(COMPACT), COMPACT, {"data": {"depth_range": [0.3, 5.0]}})


def test_evaluation_script_on_five_frames(sevenscenes, random_weights, tmp_path):
    script = Path(__file__).resolve().parents[1] / "examples" / "evaluate_7scenes.py"
    spec = importlib.util.spec_from_file_location("evaluate_7scenes", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    main = module.main

    out_json, out_md = tmp_path / "r.json", tmp_path / "r.md"
    rc = main([f"--data={sevenscenes}", f"--weights={random_weights}", "--max-frames", "4", "--threads", "1",
               "--rows", "planesweep,estm_m2", "--out", str(tmp_path / "run"), "--json", str(out_json),
               "--markdown", str(out_md)])
    assert rc == 0
    res = json.loads(out_json.read_text())
    assert res["frames"] == 4 and res["depth_range"] == [0.3, 5.0]  # the checkpoint's training range
    assert res["eval_range"] == [0.001, 10.0]
    for row in ("planesweep", "estm_m2"):
        m = res["rows"][row]
        assert m["frames"] == 4 and 0 < m["abs_rel"] < 5 and 0 <= m["a1"] <= 1 and m["seconds_per_frame"] > 0
        assert math.isfinite(m["flicker"]) and math.isfinite(m["mae_std"])
    assert res["rows"]["estm_m2"]["coverage"] == pytest.approx(1.0)  # the network is dense
    assert res["rows"]["planesweep"]["coverage"] < 0.9  # the plane sweep refuses blank areas
    mesh = res["mesh"]
    assert 0 <= mesh["fscore"] <= 1 and mesh["acc"] > 0 and mesh["gt_points"] > 1000
    assert 0 <= res["mesh_baselines"]["planesweep"]["fscore"] <= 1  # the classical mesh, for comparison
    md = out_md.read_text()
    assert "| planesweep |" in md and "0.1465" in md and "80.36%" in md and "F-score" in md
    assert "| planesweep fusion vs GT-depth fusion |" in md
    assert (tmp_path / "run" / "mesh_gt_fusion.ply").is_file()


def test_shipped_weights_load_and_describe_themselves():
    path = WEIGHTS_DIR / f"{DEFAULT_WEIGHTS}.pt"
    assert path.is_file() and path.stat().st_size <= 25 * 1024 * 1024
    ck = load_checkpoint(DEFAULT_WEIGHTS, expected=CONFIGS[DEFAULT_WEIGHTS])
    assert not ck.training  # weights only, no optimiser state
    meta = ck.metadata
    for key in ("data", "steps", "hardware", "validation"):
        assert meta.get(key), key
    assert meta["steps"] > 0 and len(meta["data"]["depth_range"]) == 2
    # shipped as the default only because, on the recorded held-out figures, ESTM's depth beats the plane sweep's
    # and its meshes beat the plane sweep's on every scan (rule 2) or it beats the incumbent it replaced on every
    # scan, Abs Rel and mesh F each (rule 4; experiments/ship_weights.py)
    heldout = meta["validation"]["heldout_scans"]
    estm = next(v for k, v in heldout.items() if k.endswith(":estm_m2"))
    sweep = heldout["planesweep"]
    assert all(estm[n]["abs_rel"] < sweep[n]["abs_rel"] for n in sweep if n.startswith("synthetic"))
    beats_sweep = all(estm[n]["mesh_fscore"] > sweep[n]["mesh_fscore"] for n in sweep)
    old = (meta["validation"].get("incumbent") or {}).get("heldout_scans", {})
    beats_incumbent = bool(old) and all(estm[n]["abs_rel"] < old[n]["abs_rel"]
                                        and estm[n]["mesh_fscore"] > old[n]["mesh_fscore"] for n in sweep)
    assert beats_sweep or beats_incumbent
    net = build_model(ck)  # every stored tensor fits; the frozen encoder part comes from its package
    assert all(torch.isfinite(p).all() for p in net.parameters())


def test_adapted_rows_adapt_and_the_others_do_not():
    from experiments.results_7scenes import TableOptions, row_options

    opts = TableOptions(depth_range=(0.25, 6.0))
    adapted = {row: row_options(row, opts) for row in ("estm_adapted", "hybrid_adapted")}
    assert {(o.mode, o.adapt.steps) for o in adapted.values()} == {("estm", 60), ("hybrid", 60)}
    assert all(row_options(row, opts).adapt.steps == 0 for row in ("estm_m2", "hybrid", "hybrid_mirror", "independent"))
