"""Training: clips, the whole chain learning (overfitting a clip), exact resume."""
import math

import pytest
import torch

from depth.checkpoint import load_checkpoint
from depth.config import TINY
from depth.data import ClipDataset, ClipOptions, ShapeBatches, StreamingClips
from depth.model import ESTNet
from recon.plane_scene import plane_scan
from depth.train import TrainOptions, train
from recon.errors import ReconError

pytestmark = pytest.mark.usefixtures("single_torch_thread")


CLIP = ClipOptions(width=TINY.image_width, height=TINY.image_height, augment=False)


def _quiet(**kw):
    return TrainOptions(device="cpu", val_every=0, checkpoint_every=0, lr_halve_every=10**6, epochs=10**6, **kw)


def test_clips_shapes_augmentation_and_streaming():
    scan = plane_scan(7, 120, 90, step=0.08)
    ds = ClipDataset([scan], ClipOptions(width=96, height=64, augment=True))
    assert len(ds) == 3
    clip = ds[1]
    assert clip["images"].shape == (5, 3, 64, 96) and clip["depth"].shape == (5, 64, 96)
    assert clip["camera_to_world"].shape == (5, 4, 4) and clip["K"].shape == (3, 3)
    assert torch.allclose(clip["K"], torch.from_numpy(scan.resized(96, 64).intrinsics.K).float())
    assert clip["depth_range"].tolist() == [1.0, 5.0]
    plain = ClipDataset([scan], ClipOptions(width=96, height=64, augment=False))[1]
    assert torch.equal(clip["depth"], plain["depth"])  # augmentation is photometric only
    assert (clip["images"] - plain["images"]).abs().mean() > 0.005
    assert torch.equal(ds[1]["images"], clip["images"])  # deterministic per (seed, epoch, item)
    streamed = list(StreamingClips(iter([scan, plane_scan(6, 120, 90, seed=3)]), ClipOptions(width=96, height=64)))
    assert len(streamed) == 3 + 2
    with pytest.raises(ReconError, match="no training clips"):
        ClipDataset([scan.subset(range(4))], CLIP)


def test_scale_jitter_scales_depth_and_baselines_together():
    scan = plane_scan(7, 120, 90, step=0.08)
    opts = ClipOptions(width=96, height=64, augment=True)
    photometric, scaled = (ClipDataset([scan], o)[1] for o in (opts, ClipOptions(**{**opts.__dict__, "scale_jitter": 0.3})))
    assert torch.equal(scaled["images"], photometric["images"])  # the images do not change
    both = (scaled["depth"] > 0) & (photometric["depth"] > 0)
    ratio = scaled["depth"][both] / photometric["depth"][both]
    factor = float(ratio.mean())
    assert abs(factor - 1) > 1e-3 and 0.74 <= factor <= 1.35 and torch.allclose(ratio, torch.full_like(ratio, factor))
    a, b = photometric["camera_to_world"], scaled["camera_to_world"]
    assert torch.equal(a[:, :3, :3], b[:, :3, :3])
    assert torch.allclose(b[:, :3, 3], a[:, :3, 3] * factor, atol=1e-6)
    # outside the clip's range the scaled GT is invalid, as any GT there is
    assert ((scaled["depth"] == 0) | ((scaled["depth"] >= 1.0) & (scaled["depth"] <= 5.0))).all()


def test_reversed_clips_play_the_same_frames_backwards():
    scan = plane_scan(9, 120, 90, step=0.08)
    plain = ClipOptions(width=96, height=64, augment=False)
    forward = ClipDataset([scan], plain)
    always = ClipDataset([scan], ClipOptions(**{**plain.__dict__, "augment": True, "brightness": 0.0, "contrast": 0.0,
                                                  "saturation": 0.0, "gamma": 0.0, "reverse_share": 1.0}))
    for i in range(len(forward)):
        a, b = forward[i], always[i]
        assert torch.equal(b["camera_to_world"], a["camera_to_world"].flip(0))
        assert torch.equal(b["depth"], a["depth"].flip(0))
        assert torch.allclose(b["images"], a["images"].flip(0), atol=1e-6)
    half = ClipDataset([plane_scan(40, 96, 64, step=0.08)], ClipOptions(width=96, height=64, reverse_share=0.5))
    backwards = sum(bool(half[i]["camera_to_world"][0, 0, 3] > half[i]["camera_to_world"][-1, 0, 3])
                    for i in range(len(half)))
    assert 0.25 * len(half) < backwards < 0.75 * len(half)  # about half of the clips, not all nor none


def _two_plane_scans(shard):
    """Loader worker `shard`'s stream: rooms of its own."""
    return (plane_scan(5, 96, 64, step=0.08, seed=10 * shard + k) for k in range(2))


def test_loader_workers_stream_clips_of_their_own():
    clips = list(torch.utils.data.DataLoader(StreamingClips(_two_plane_scans, CLIP), batch_size=None, num_workers=2))
    alone = list(StreamingClips(_two_plane_scans, CLIP))  # no workers: shard 0's stream
    assert len(clips) == 4 and len(alone) == 2
    assert torch.equal(clips[0]["images"], alone[0]["images"])  # workers interleave: shard 0, 1, 0, 1
    assert not torch.equal(clips[0]["images"], clips[1]["images"])
    assert not torch.equal(clips[1]["images"], clips[3]["images"])
    shared = StreamingClips(iter([plane_scan(5, 96, 64, step=0.08)]), CLIP)
    with pytest.raises(ReconError, match="a stream per worker"):
        list(torch.utils.data.DataLoader(shared, batch_size=None, num_workers=2))


def test_shape_batches_keep_portrait_and_landscape_apart():
    scans = [plane_scan(5, 96, 64, step=0.08, seed=1), plane_scan(5, 64, 96, step=0.08, seed=2),
             plane_scan(5, 96, 64, step=0.08, seed=3), plane_scan(5, 64, 96, step=0.08, seed=4),
             plane_scan(5, 96, 64, step=0.08, seed=5)]
    batches = list(ShapeBatches(StreamingClips(iter(scans), CLIP), 2))
    assert [tuple(b["images"].shape[-2:]) for b in batches] == [(64, 96), (96, 64)]  # the fifth clip waits
    assert all(b["images"].shape[0] == 2 and b["K"].shape == (2, 3, 3) for b in batches)


def _overfit(out_dir, steps):
    torch.manual_seed(0)
    data = ClipDataset([plane_scan(6, 96, 64, step=0.08)], CLIP)  # two clips, one batch
    return train(data, out_dir, _quiet(max_steps=steps, lr=2e-3, batch_size=2), model_config=TINY).losses


def _drop(losses, head=3, tail=5):
    return (sum(losses[:head]) / head) / (sum(losses[-tail:]) / tail)


def test_tiny_model_starts_learning(tmp_path):
    losses = _overfit(tmp_path, 60)
    assert _drop(losses) > 5.0


@pytest.mark.slow
def test_tiny_model_overfits_a_clip(tmp_path):
    losses = _overfit(tmp_path, 300)
    assert _drop(losses) >= 10.0


def test_gradient_weight_enters_the_training_loss(tmp_path):
    data = ClipDataset([plane_scan(5, 96, 64, step=0.08)], CLIP)
    first = {}
    for w in (0.0, 5.0):
        torch.manual_seed(0)
        first[w] = train(data, tmp_path / str(w), _quiet(max_steps=1, grad_weight=w), model_config=TINY).losses[0]
    assert first[5.0] > first[0.0] + 1e-4  # same weights, same clip: only the added term differs
    with pytest.raises(ReconError, match="gradient weight"):
        train(data, tmp_path / "x", _quiet(max_steps=1, grad_weight=-1.0), model_config=TINY)


def test_resume_continues_exactly(tmp_path):
    data = ClipDataset([plane_scan(5, 96, 64, step=0.08)], CLIP)
    torch.manual_seed(0)
    straight = train(data, tmp_path / "a", _quiet(max_steps=4, lr=1e-3), model_config=TINY)
    torch.manual_seed(0)
    first = train(data, tmp_path / "b", _quiet(max_steps=2, lr=1e-3), model_config=TINY)
    resumed = train(data, tmp_path / "b", _quiet(max_steps=4, lr=1e-3), model_config=TINY,
                    resume=first.checkpoint)
    assert resumed.steps == 4 and resumed.losses == straight.losses[2:]
    a, b = load_checkpoint(straight.model_path), load_checkpoint(resumed.model_path)
    assert a.metadata["steps"] == 4 and a.metadata["data"]["clips"] == 1
    for k, v in a.state_dict.items():
        assert torch.equal(v, b.state_dict[k]), k
    with pytest.raises(ReconError, match="no training state"):
        train(data, tmp_path / "c", _quiet(max_steps=1), model_config=TINY, resume=straight.model_path)


def test_held_statistics_stay_while_the_weights_train(tmp_path):
    """--hold-statistics: BatchNorm normalises with its running statistics in training, so they never move."""
    data = ClipDataset([plane_scan(5, 96, 64, step=0.08)], CLIP)
    trained = {}
    for held in (False, True):
        torch.manual_seed(0)
        result = train(data, tmp_path / str(held), _quiet(max_steps=3, lr=1e-3, hold_statistics=held),
                       model_config=TINY)
        trained[held] = load_checkpoint(result.model_path).state_dict
    means = [k for k in trained[True] if k.endswith("running_mean")]
    assert means and all(not trained[True][k].any() for k in means)  # still the fresh zeros
    assert any(trained[False][k].abs().max() > 1e-3 for k in means)  # a plain run moves them
    torch.manual_seed(0)
    fresh = ESTNet(TINY).state_dict()
    moved = [k for k, v in trained[True].items() if v.is_floating_point() and "running" not in k
             and not torch.equal(v, fresh[k])]
    assert len(moved) > len(means)  # convolutions and BatchNorm's affine parameters still learn


def test_recalibrated_batchnorm_holds_the_plain_mean_over_its_batches():
    """experiments/precise_bn.py"""
    from depth.model import ESTNet
    from experiments.precise_bn import recalibrate_batchnorm

    torch.manual_seed(0)
    net = ESTNet(TINY)
    batches = list(torch.utils.data.DataLoader(ClipDataset([plane_scan(7, 96, 64, step=0.08, seed=s) for s in (1, 2)],
                                                           CLIP), 1))
    weights = {k: v.clone() for k, v in net.state_dict().items() if "running" not in k and "num_batches" not in k}
    bn = next(m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d))

    def stats(which):
        recalibrate_batchnorm(net, which)
        return bn.running_mean.clone(), bn.running_var.clone()

    per_batch = [stats([b]) for b in batches]
    both = stats(batches)
    # every batch calls each BatchNorm equally often, so the mean over all is the mean of the per-batch means
    assert torch.allclose(both[0], torch.stack([m for m, _ in per_batch]).mean(0), atol=1e-5)
    assert torch.allclose(both[1], torch.stack([v for _, v in per_batch]).mean(0), atol=1e-5)
    assert not torch.allclose(per_batch[0][0], per_batch[-1][0], atol=1e-3)  # the batches do differ
    assert torch.allclose(stats(batches[::-1])[0], both[0], atol=1e-5)  # order does not matter
    both = stats(batches)
    assert not net.training and bn.momentum == 0.1
    assert all(torch.equal(v, net.state_dict()[k]) for k, v in weights.items())  # weights untouched
    with pytest.raises(ReconError, match="no batches"):
        recalibrate_batchnorm(net, [])
    assert torch.equal(bn.running_mean, both[0])  # and nothing was reset


def test_bf16_autocast_gives_the_fp32_loss_and_trains(tmp_path):
    """Under bf16 autocast a batch's loss and per-stage errors agree with fp32's, and a bf16 training step runs.
    (A CPU without bf16 kernels runs it 8x slower than fp32: its learning curve is the slow test below.)"""
    from depth.model import ESTNet
    from depth.train import clip_loss

    data = ClipDataset([plane_scan(6, 96, 64, step=0.08)], CLIP)
    batch = next(iter(torch.utils.data.DataLoader(data, 1)))
    torch.manual_seed(0)
    net = ESTNet(TINY).eval()  # running BatchNorm statistics, so both passes see the same network
    with torch.no_grad():
        loss32, stages32, _ = clip_loss(net, batch)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            loss16, stages16, _ = clip_loss(net, batch)
    assert float(loss16) == pytest.approx(float(loss32), rel=0.005)
    assert stages16 == pytest.approx(stages32, rel=0.005)
    stepped = train(data, tmp_path / "bf16", _quiet(max_steps=1, lr=1e-3, amp="bf16"), model_config=TINY)
    assert stepped.steps == 1 and math.isfinite(stepped.losses[0])
    assert load_checkpoint(stepped.checkpoint).training["step"] == 1


def test_auto_precision_is_bf16_where_the_hardware_computes_it(tmp_path):
    """`amp="auto"` (the CLI default) trains in bf16 only on a device with bf16 arithmetic, and the
    checkpoint records what ran; on Linux the CPU's answer agrees with the flags the kernel lists."""
    from pathlib import Path

    from depth.device import computes_bf16

    native = computes_bf16(torch.device("cpu"))
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        flags = set(next(line for line in cpuinfo.read_text().splitlines() if line.startswith("flags")).split())
        assert native == bool(flags & {"amx_bf16", "avx512_bf16"})
    data = ClipDataset([plane_scan(6, 96, 64, step=0.08)], CLIP)
    auto = train(data, tmp_path / "auto", _quiet(max_steps=1, lr=1e-3, amp="auto"), model_config=TINY)
    assert load_checkpoint(auto.checkpoint).metadata["options"]["amp"] == ("bf16" if native else None)


@pytest.mark.slow
def test_bf16_training_learns(tmp_path):
    data = ClipDataset([plane_scan(6, 96, 64, step=0.08)], CLIP)
    torch.manual_seed(0)
    bf16 = train(data, tmp_path / "bf16", _quiet(max_steps=30, lr=2e-3, batch_size=2, amp="bf16"), model_config=TINY)
    assert _drop(bf16.losses) > 2.0


def test_fp16_scaler_state_resumes(tmp_path):
    data = ClipDataset([plane_scan(6, 96, 64, step=0.08)], CLIP)
    torch.manual_seed(0)
    fp16 = train(data, tmp_path / "fp16", _quiet(max_steps=3, lr=1e-3, amp="fp16"), model_config=TINY)
    scaler = load_checkpoint(fp16.checkpoint).training["grad_scaler"]
    assert scaler is not None and scaler["scale"] > 0  # the loss scale travels with the checkpoint
    resumed = train(data, tmp_path / "fp16", _quiet(max_steps=5, lr=1e-3, amp="fp16"), model_config=TINY,
                    resume=fp16.checkpoint)
    assert resumed.steps == 5 and all(torch.isfinite(torch.tensor(resumed.losses)))
    with pytest.raises(ReconError, match="mixed precision"):
        train(data, tmp_path / "x", _quiet(max_steps=1, amp="fp8"), model_config=TINY)


DDP_SCRIPT = """
import os, sys, torch
torch.set_num_threads(1)
from depth.config import TINY
from depth.data import ClipDataset, ClipOptions
from recon.plane_scene import plane_scan
from depth.train import TrainOptions, train
ds = ClipDataset([plane_scan(7, 96, 64, step=0.08)], ClipOptions(width=96, height=64, augment=False))
r = train(ds, sys.argv[1], TrainOptions(device="cpu", max_steps=2, epochs=5, val_every=0, checkpoint_every=0),
          model_config=TINY)
torch.save(r.losses, os.path.join(sys.argv[1], f"losses{os.environ['RANK']}.pt"))
"""


@pytest.mark.slow
def test_distributed_training_under_torchrun(tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "ddp.py"
    script.write_text(DDP_SCRIPT)
    torchrun = Path(sys.executable).with_name("torchrun")
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([str(torchrun), "--nproc_per_node", "2", "--master_port", "29541", str(script),
                           str(tmp_path / "run")], cwd=root, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(root)})
    assert proc.returncode == 0, proc.stderr[-2000:]
    l0, l1 = (torch.load(tmp_path / "run" / f"losses{r}.pt") for r in (0, 1))
    assert len(l0) == len(l1) == 2 and l0 != l1  # each rank trains on its own shard
    assert load_checkpoint(tmp_path / "run" / "model.pt").metadata["steps"] == 2


def test_streamed_scans_with_steps_per_epoch(tmp_path):
    def endless():
        seed = 0
        while True:
            yield plane_scan(5, 96, 64, step=0.08, seed=seed)
            seed += 1

    torch.manual_seed(0)
    stream = StreamingClips(endless(), CLIP)
    opts = TrainOptions(device="cpu", val_every=0, checkpoint_every=0, max_steps=3, steps_per_epoch=1,
                        lr_halve_every=1, lr=1e-3, epochs=100)
    result = train(stream, tmp_path, opts, model_config=TINY)
    assert result.steps == 3 and result.epochs == 3
    state = load_checkpoint(result.checkpoint).training
    assert state["optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-3 / 8)
