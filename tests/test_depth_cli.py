"""`recon depth` / `recon train` / `recon bench depth` through the CLI entry point."""
import itertools
import json

import numpy as np
import pytest

from apps.cli import main
from recon.plane_scene import plane_scan
from recon.io import load_depth_map
from recon.scan import save_scan


@pytest.fixture(scope="module")
def scan_dir(tmp_path_factory):
    return save_scan(plane_scan(5, 128, 96, step=0.08), tmp_path_factory.mktemp("scan") / "scan")


def test_recon_depth_planesweep_writes_maps(scan_dir, tmp_path, capsys):
    out = tmp_path / "depth"
    assert main(["-q", "depth", str(scan_dir), "--out", str(out), "--mode", "planesweep", "--max-frames", "4",
                 "--keyframe-distance", "0"]) == 0
    summary = json.loads((out / "depth.json").read_text())
    assert [f["name"] for f in summary["frames"]] == ["000000", "000001", "000002", "000003"]
    depth = load_depth_map(out, "000001")
    gt = plane_scan(5, 128, 96, step=0.08).depth(1)
    valid = depth > 0
    assert valid.mean() > 0.4 and np.mean(np.abs(depth[valid] - gt[valid]) / gt[valid]) < 0.1
    assert "wrote 4 depth maps" in capsys.readouterr().out


def test_recon_depth_keyframes_only(scan_dir, tmp_path):
    out = tmp_path / "depth"
    # The scan moves 0.08 m per frame: a 0.15 keyframe distance keeps every other frame.
    assert main(["-q", "depth", str(scan_dir), "--out", str(out), "--mode", "planesweep",
                 "--keyframe-distance", "0.15", "--depth-range", "1", "5"]) == 0
    names = [f["name"] for f in json.loads((out / "depth.json").read_text())["frames"]]
    assert names == ["000000", "000002", "000004"]


def test_recon_depth_with_missing_weights_points_to_planesweep(scan_dir, tmp_path, capsys):
    # the shipped `compact` weights are the default now; a name that ships nothing must still explain itself
    assert main(["depth", str(scan_dir), "--out", str(tmp_path / "d"), "--mode", "estm", "--weights", "nosuch"]) == 2
    err = capsys.readouterr().err
    assert "recon: error:" in err and "planesweep" in err and "--weights" in err


def test_recon_depth_and_train_refuse_bad_arguments(scan_dir, tmp_path, capsys):
    assert main(["depth", str(scan_dir), "--out", str(tmp_path / "d"), "--mode", "planesweep",
                 "--depth-range", "4", "2"]) == 2
    assert "invalid depth range" in capsys.readouterr().err
    assert main(["depth", str(scan_dir), "--out", str(tmp_path / "d"), "--adapt-steps", "-3"]) == 2
    assert "--adapt-steps must be >= 0" in capsys.readouterr().err
    assert main(["depth", str(scan_dir), "--out", str(tmp_path / "d"), "--mode", "planesweep", "--adapt-steps", "3"]) == 2
    assert "adapts a network" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()
    assert main(["train", str(scan_dir), "--out", str(tmp_path / "t"), "--config", "huge"]) == 2
    assert "unknown depth network config" in capsys.readouterr().err
    assert main(["train", "--out", str(tmp_path / "t")]) == 2
    assert "scans or --synthetic" in capsys.readouterr().err
    assert main(["train", "--synthetic", "--out", str(tmp_path / "t")]) == 2
    assert "--max-steps" in capsys.readouterr().err


def test_recon_depth_adapts_the_shipped_network_to_the_scan(scan_dir, tmp_path, single_torch_thread):
    out = tmp_path / "depth"
    assert main(["-q", "depth", str(scan_dir), "--out", str(out), "--keyframe-distance", "0", "--adapt-steps", "2",
                 "--precision", "fp32"]) == 0
    summary = json.loads((out / "depth.json").read_text())
    assert summary["weights"] == "compact" and summary["adaptation"]["steps"] == 2 and len(summary["frames"]) == 5
    assert summary["adaptation"]["seconds"] > 0 and np.isfinite(summary["adaptation"]["loss_end"])


def test_recon_bench_depth_json(capsys):
    assert main(["bench", "depth", "--config", "compact", "--frames", "1", "--threads", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    for key in ("config", "device", "params_m", "gmacs", "peak_mem_mb", "s_per_frame", "planesweep_s_per_frame"):
        assert key in result
    assert result["config"] == "compact" and result["params_m"] == pytest.approx(0.692, abs=0.001)
    assert 15 < result["gmacs"] < 20 and result["s_per_frame"] > 0 and result["frames"] == 1


def test_recon_bench_depth_times_the_config_of_weights(tmp_path, capsys):
    """--config also takes weights, whose own config (here 8 planes, which no named config has) is timed."""
    from depth.checkpoint import save_checkpoint
    from depth.config import TINY
    from depth.model import ESTNet

    cfg = TINY.replace(num_planes=8)
    weights = save_checkpoint(tmp_path / "eight.pt", ESTNet(cfg), cfg)
    assert main(["bench", "depth", "--config", str(weights), "--frames", "1", "--threads", "1", "--no-baseline",
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["config"] == "tiny" and result["num_planes"] == 8 and result["s_per_frame"] > 0
    assert main(["bench", "depth", "--config", "nonesuch", "--frames", "1"]) == 2
    assert "nonesuch" in capsys.readouterr().err


def test_recon_bench_train_times_the_precision_training_picks(capsys):
    import torch

    from depth.device import computes_bf16

    assert main(["bench", "train", "--steps", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    native = computes_bf16(torch.device("cpu"))
    assert result["config"] == "compact" and result["computes_bf16"] == native
    assert result["amp_auto_picks"] == ("bf16" if native else "fp32") and 0 < result["rows"]["fp32"]["s_per_step"] < 120
    bf16 = result["rows"]["bf16"]
    assert (bf16["s_per_step"] > 0) if native else ("emulated" in bf16["note"])
    assert main(["bench", "train", "--steps", "0"]) == 2
    assert "--steps" in capsys.readouterr().err


def test_recon_train_takes_the_config_of_the_weights_it_starts_from(scan_dir, tmp_path, capsys):
    # weights trained under a changed config (here `tiny` with the scale-keeping RefineNet, no named config)
    # train on without restating it; a --config that contradicts them is refused
    import torch

    from depth.checkpoint import load_checkpoint, save_checkpoint
    from depth.config import TINY
    from depth.model import ESTNet

    cfg = TINY.replace(refine_keeps_scale=True)
    torch.manual_seed(0)
    start = save_checkpoint(tmp_path / "start.pt", ESTNet(cfg), cfg, {"steps": 3})
    out = tmp_path / "t"
    assert main(["-q", "train", str(scan_dir), "--init", str(start), "--out", str(out), "--max-steps", "4",
                 "--threads", "1", "--no-augment"]) == 0
    trained = load_checkpoint(out / "model.pt")
    assert trained.config == cfg and trained.metadata["steps"] == 4
    assert main(["train", str(scan_dir), "--init", str(start), "--out", str(tmp_path / "u"), "--max-steps", "4",
                 "--config", "compact"]) == 2
    assert "differs in" in capsys.readouterr().err


def test_recon_train_sweeps_the_range_the_starting_weights_were_trained_on(tmp_path):
    # a plane index means a depth only within the trained range: continuing `compact` (0.25-6 m) must not
    # silently retrain it on the 0.25-10 m default
    import argparse

    from apps.commands.train import synthetic_depth_range
    from depth.checkpoint import save_checkpoint
    from depth.config import TINY
    from depth.model import ESTNet

    start = save_checkpoint(tmp_path / "s.pt", ESTNet(TINY), TINY, {"steps": 1, "data": {"depth_range": [0.25, 6.0]}})
    bare = save_checkpoint(tmp_path / "b.pt", ESTNet(TINY), TINY, {"steps": 1})

    def rng(**kw):
        return synthetic_depth_range(argparse.Namespace(**{"depth_range": None, "init": None, "resume": None, **kw}))

    assert rng(init=str(start)) == (0.25, 6.0) and rng(resume=str(start)) == (0.25, 6.0)
    assert rng(init=str(start), depth_range=[0.5, 8.0]) == (0.5, 8.0)
    assert rng(init=str(bare)) == (0.25, 10.0) and rng() == (0.25, 10.0)


def test_training_stream_passes_close_ups_on():
    from apps.commands.train import training_stream

    def sources(close_ups):
        clips = itertools.islice(training_stream(7, (0.25, 10.0), close_ups, 0), 3)
        return [clip.metadata.extra["training_seed"] for clip in clips]

    assert sources(True) == [7, 57, 107] and sources(False) == [7, 57, 7]
