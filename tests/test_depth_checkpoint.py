"""Checkpoint files: bit-exact round trip, fp16 storage, names, and refusal of bad files."""
import pytest
import torch

from depth.checkpoint import average_checkpoints, build_model, load_checkpoint, resolve_weights, save_checkpoint
from depth.config import TINY
from depth.model import ESTNet
from recon.errors import ReconError


def _trained_like(cfg=TINY):
    torch.manual_seed(1)
    net = ESTNet(cfg)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(torch.randn_like(p) * 0.1)
        for name, b in net.named_buffers():
            if name.endswith("running_var"):
                b.uniform_(0.5, 2.0)
    return net


def test_round_trip_is_bit_exact(tmp_path):
    net = _trained_like()
    path = save_checkpoint(tmp_path / "a.pt", net, TINY, {"data": {"scans": ["x"]}, "steps": 7})
    ckpt = load_checkpoint(path, expected=TINY)
    assert ckpt.config == TINY and ckpt.metadata["steps"] == 7
    original = net.state_dict()
    assert set(ckpt.state_dict) == set(original)
    for k, v in original.items():
        assert ckpt.state_dict[k].dtype == v.dtype and torch.equal(ckpt.state_dict[k], v), k
    restored = build_model(ckpt)
    images = torch.rand(1, 3, 3, TINY.image_height, TINY.image_width)
    K = torch.tensor([[[70.0, 0, 47.5], [0, 70.0, 31.5], [0, 0, 1]]])
    poses = torch.eye(4).repeat(1, 3, 1, 1)
    poses[0, :, 0, 3] = torch.tensor([0.0, 0.1, 0.2])
    rng = torch.tensor([[1.0, 5.0]])
    with torch.no_grad():
        a = net.eval()(images, K, poses, rng)[0].depths[3]
        b = restored(images, K, poses, rng)[0].depths[3]
    assert torch.equal(a, b)


def test_fp16_storage_halves_the_file_and_rounds_weights(tmp_path):
    net = _trained_like()
    full = save_checkpoint(tmp_path / "full.pt", net, TINY)
    half = save_checkpoint(tmp_path / "half.pt", net, TINY, fp16=True)
    assert half.stat().st_size < 0.65 * full.stat().st_size
    ckpt = load_checkpoint(half)
    for k, v in net.state_dict().items():
        got = ckpt.state_dict[k]
        if v.is_floating_point():
            assert got.dtype == torch.float32 and torch.equal(got, v.half().float()), k
        else:
            assert torch.equal(got, v), k


def test_bad_checkpoints_are_refused(tmp_path):
    net = _trained_like()
    path = save_checkpoint(tmp_path / "tiny.pt", net, TINY)
    with pytest.raises(ReconError, match="expected 'other'"):
        load_checkpoint(path, expected=TINY.replace(name="other", num_planes=24))
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ReconError, match="unreadable"):
        load_checkpoint(corrupt)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ReconError, match="not a depth network checkpoint"):
        load_checkpoint(foreign)
    with pytest.raises(ReconError, match="not found"):
        load_checkpoint(tmp_path / "missing.pt")
    with pytest.raises(ReconError, match="planesweep"):
        resolve_weights("nosuchweights")
    # Weights that do not fit the config they claim.
    doc = torch.load(path, weights_only=True)
    doc["config"]["num_planes"] = 24
    torch.save(doc, tmp_path / "mismatch.pt")
    with pytest.raises(ReconError, match="do not fit"):
        build_model(load_checkpoint(tmp_path / "mismatch.pt"))


def test_average_is_the_mean_of_the_weights_and_keeps_counts(tmp_path):
    a, b = _trained_like(), ESTNet(TINY)
    for name, buf in b.named_buffers():
        if name.endswith("num_batches_tracked"):
            buf.fill_(5)
    paths = [save_checkpoint(tmp_path / f"{n}.pt", net, TINY, {"steps": s}) for n, net, s in (("a", a, 10), ("b", b, 20))]
    mean = average_checkpoints(paths)
    assert mean.metadata["steps"] == 20 and mean.metadata["averaged_from"] == [str(p) for p in paths]
    sa, sb = a.state_dict(), b.state_dict()
    for k, v in mean.state_dict.items():
        expect = (sa[k] + sb[k]) / 2 if v.is_floating_point() else sb[k]
        assert torch.allclose(v, expect, atol=1e-6), k
    with pytest.raises(ReconError, match="cannot average"):
        average_checkpoints([save_checkpoint(tmp_path / "c.pt", ESTNet(TINY.replace(num_planes=8)),
                                             TINY.replace(num_planes=8)), paths[0]])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cpu_and_cuda_agree():
    net = _trained_like().eval()
    images = torch.rand(1, 3, 3, TINY.image_height, TINY.image_width)
    K = torch.tensor([[[70.0, 0, 47.5], [0, 70.0, 31.5], [0, 0, 1]]])
    poses = torch.eye(4).repeat(1, 3, 1, 1)
    poses[0, :, 0, 3] = torch.tensor([0.0, 0.1, 0.2])
    rng = torch.tensor([[1.0, 5.0]])
    torch.backends.cudnn.allow_tf32 = False
    torch.backends.cuda.matmul.allow_tf32 = False
    with torch.no_grad():
        cpu = net(images, K, poses, rng)[0].depths[3]
        gpu = net.cuda()(images.cuda(), K.cuda(), poses.cuda(), rng.cuda())[0].depths[3].cpu()
    assert ((cpu - gpu).abs() / cpu).max() < 1e-3


def test_with_config_changes_the_forward_pass_not_the_weights(tmp_path):
    """experiments/with_config.py: the same weights under `refine_keeps_scale`, metadata kept and the change noted."""
    from experiments.with_config import main

    net = _trained_like()
    free = TINY.replace(refine_keeps_scale=False)
    src = save_checkpoint(tmp_path / "a.pt", net, free, {"steps": 7}, fp16=True)
    assert main([str(src), "--set", "refine_keeps_scale=true", "--out", str(tmp_path / "b.pt")]) == 0
    before, after = load_checkpoint(src), load_checkpoint(tmp_path / "b.pt", expected=TINY.replace(refine_keeps_scale=True))
    assert after.metadata["steps"] == 7 and after.metadata["config_changed"] == {"refine_keeps_scale": True}
    assert all(torch.equal(before.state_dict[k], v) for k, v in after.state_dict.items())
    with pytest.raises(ReconError, match="differs in refine_keeps_scale"):
        load_checkpoint(tmp_path / "b.pt", expected=free)


def test_fewer_planes_keeps_what_the_plane_layers_compute(tmp_path):
    """experiments/fewer_planes.py: layers that read plane channels sum a linear-in-depth signal as before,
    layers that write them give the old channels at the new planes' positions, and the file loads as 8 planes."""
    from experiments.fewer_planes import interpolation, main

    net = _trained_like()
    src = save_checkpoint(tmp_path / "a.pt", net, TINY, {"steps": 7})
    assert main([str(src), "--planes", "8", "--out", str(tmp_path / "b.pt")]) == 0
    old, new = load_checkpoint(src), load_checkpoint(tmp_path / "b.pt", expected=TINY.replace(num_planes=8))
    assert new.metadata["steps"] == 7 and new.metadata["planes_changed"]["to"] == 8
    position = torch.linspace(0, 15, 8)
    signal_old, signal_new = 0.3 + 0.2 * torch.arange(16.0), 0.3 + 0.2 * position
    key = "refine.stage1_in.0.weight"  # reads [context, logits], 16 + 16 channels, now 8 + 8
    before = torch.einsum("oikl,i->o", old.state_dict[key], torch.cat([signal_old, 2 * signal_old]))
    after = torch.einsum("oikl,i->o", new.state_dict[key], torch.cat([signal_new, 2 * signal_new]))
    assert torch.allclose(before, after, atol=1e-4) and not torch.allclose(before, 0 * before)
    last = max(int(k.split(".")[2]) for k in old.state_dict if k.startswith("context.up_convs."))
    key = f"context.up_convs.{last}.0.weight"  # writes one channel per plane
    expected = torch.einsum("no,oikl->nikl", interpolation(16, 8).float(), old.state_dict[key])
    assert torch.allclose(new.state_dict[key], expected, atol=1e-6)
    assert torch.equal(new.state_dict[key][0], old.state_dict[key][0])
    assert torch.equal(new.state_dict[key][-1], old.state_dict[key][-1])
    model = build_model(new)
    images, K = torch.rand(1, 3, 3, TINY.image_height, TINY.image_width), torch.eye(3)[None]
    K[0, 0, 0], K[0, 1, 1], K[0, 0, 2], K[0, 1, 2] = 80.0, 80.0, TINY.image_width / 2, TINY.image_height / 2
    poses = torch.eye(4).repeat(1, 3, 1, 1)
    poses[0, :, 0, 3] = torch.tensor([-0.1, 0.0, 0.1])
    with torch.no_grad():
        depth = model(images, K, poses, torch.tensor([[0.5, 5.0]]))[0].depths[3]
    assert torch.isfinite(depth).all() and depth.min() >= 0.5 and depth.max() <= 5.0
