"""The EST network: sizes against the paper, output shapes, gradients, fusion variants, backbone loading."""
import math

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from depth.config import COMPACT, PAPER, TINY, ESTConfig, get_config
from depth.loss import log_gradient_error, multi_stage_loss, stage_weights
from depth.model import ESTNet
from depth.model.context import ContextNet
from depth.model.layers import Conv3d
from depth.model.volumes import soft_argmax_depth
from recon.errors import ReconError


pytestmark = pytest.mark.usefixtures("single_torch_thread")


def _window(cfg, batch=1, views=3):
    torch.manual_seed(0)
    images = torch.rand(batch, views, 3, cfg.image_height, cfg.image_width)
    K = torch.tensor([[0.8 * cfg.image_width, 0, cfg.image_width / 2 - 0.5],
                      [0, 0.8 * cfg.image_width, cfg.image_height / 2 - 0.5], [0, 0, 1]]).expand(batch, 3, 3)
    poses = torch.eye(4).repeat(batch, views, 1, 1)
    poses[:, :, 0, 3] = torch.arange(views) * 0.1
    return images, K.contiguous(), poses, torch.tensor([[1.0, 5.0]]).expand(batch, 2).contiguous()


def test_paper_config_matches_paper_size():
    """36.2 M parameters and 176.9 G MACs at 320x256 for one ESTM step (3-frame window, memory 2)."""
    with torch.device("meta"):
        net = ESTNet(PAPER).eval()
        images, K, poses, rng = _window(PAPER)
        with torch.no_grad():
            out = net(images, K, poses, rng, targets=[(1, (0, 2))])
            counter = FlopCounterMode(display=False)
            with counter:
                net(images, K, poses, rng, targets=[(1, (0, 2))], memory=[out[0].memory] * 2)
    params = sum(p.numel() for p in net.parameters()) / 1e6
    gmacs = counter.get_total_flops() / 2e9
    assert abs(params - 36.2) / 36.2 < 0.03
    assert abs(gmacs - 176.9) / 176.9 < 0.03
    assert sum(p.numel() for p in ESTNet(COMPACT).parameters()) < 0.05 * params * 1e6


def test_outputs_shapes_and_ranges():
    net = ESTNet(TINY).eval()
    images, K, poses, rng = _window(TINY, batch=2, views=5)
    with torch.no_grad():
        outs = net(images, K, poses, rng)
    assert len(outs) == 3
    h, w = TINY.image_height, TINY.image_width
    shapes = [tuple(d.shape) for d in outs[0].depths]
    assert shapes == [(2, 1, h // 4, w // 4), (2, 1, h // 4, w // 4), (2, 1, h // 2, w // 2), (2, 1, h, w)]
    for o in outs:
        for d in o.depths:
            assert d.min() >= 1.0 - 1e-4 and d.max() <= 5.0 + 1e-4
        assert o.confidence.min() >= 1.0 / TINY.num_planes - 1e-6 and o.confidence.max() <= 1.0
        assert o.memory.key.shape == (2, TINY.volume_channels // 2, TINY.num_planes, h // 4, w // 4)


@pytest.mark.parametrize("channels", [8, 16, 17])
def test_fast_conv3d_is_the_plain_convolution(channels):
    """Zero-padded narrow inputs and the channels-last layout change the kernel, not the function or its gradients."""
    torch.manual_seed(0)
    fast = Conv3d(channels, 8, 3, 1, 1)
    plain = torch.nn.Conv3d(channels, 8, 3, 1, 1)
    plain.load_state_dict(fast.state_dict())
    x = torch.randn(1, channels, 6, 10, 12, requires_grad=True)
    y_fast, y_plain = fast(x), plain(x)
    assert torch.allclose(y_fast, y_plain, atol=1e-5)
    (g_fast,) = torch.autograd.grad(y_fast.square().sum(), fast.weight)
    (g_plain,) = torch.autograd.grad(y_plain.square().sum(), plain.weight)
    assert torch.allclose(g_fast, g_plain, rtol=1e-4, atol=1e-4)


def test_soft_argmax_recovers_plane_depth():
    planes = torch.linspace(1.0, 4.0, 7)[None]
    logits = torch.full((1, 7, 2, 2), -30.0)
    logits[0, 3] = 30.0
    logits[0, 3, 1, 1] = -30.0
    logits[0, 5, 1, 1], logits[0, 6, 1, 1] = 30.0, 30.0  # two equal peaks: halfway between planes 5 and 6
    depth, conf = soft_argmax_depth(logits, planes)
    assert torch.allclose(depth[0, 0], torch.tensor([[2.5, 2.5], [2.5, 3.75]]))
    assert torch.allclose(conf[0, 0], torch.tensor([[1.0, 1.0], [1.0, 0.5]]))


@pytest.mark.parametrize("fusion,keeps_scale", [("adaptive", False), ("concat", False), ("adaptive", True)])
def test_every_parameter_receives_a_gradient(fusion, keeps_scale):
    cfg = TINY.replace(fusion=fusion, refine_keeps_scale=keeps_scale)
    net = ESTNet(cfg).train()
    images, K, poses, rng = _window(cfg, batch=1, views=5)
    gt = torch.rand(1, 3, cfg.image_height, cfg.image_width) * 3 + 1.5
    outs = net(images, K, poses, rng)
    loss, per_stage = multi_stage_loss([o.depths for o in outs], gt)
    loss.backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None or not torch.any(p.grad != 0)]
    assert not missing, f"no gradient for {missing}"
    assert len(per_stage) == 4 and all(x > 0 for x in per_stage)


def test_refine_keeps_scale_holds_the_est_stage_median():
    """A RefineNet that pushes every pixel far away moves the scale unless `refine_keeps_scale` holds it to D1's
    median; the flag adds no weights, so trained weights load either way."""
    images, K, poses, rng = _window(TINY)
    free = ESTNet(TINY.replace(refine_keeps_scale=False)).eval()
    kept = ESTNet(TINY.replace(refine_keeps_scale=True)).eval()
    kept.load_state_dict(free.state_dict(), strict=True)
    medians = {}
    for name, net in (("free", free), ("kept", kept)):
        with torch.no_grad():
            net.refine.stage2_depth.bias.fill_(2.0)
            d1, d2, d3 = net(images, K, poses, rng, targets=[(1, (0, 2))])[0].depths[1:]
        medians[name] = (d1.median().item(), d2.median().item(), d3.median().item())
    d1, d2, d3 = medians["kept"]
    assert d2 == pytest.approx(d1, rel=1e-5) and d3 == pytest.approx(d1, rel=1e-5)
    assert medians["free"][0] == pytest.approx(d1)  # same weights, same EST stage
    assert medians["free"][2] > 1.2 * d1  # without the flag the pushed stage moves the scale


def test_memory_changes_the_fused_output():
    net = ESTNet(TINY).eval()
    images, K, poses, rng = _window(TINY)
    with torch.no_grad():
        alone = net(images, K, poses, rng, targets=[(1, (0, 2))])[0]
        other = net(images.flip(1), K, poses, rng, targets=[(1, (0, 2))])[0].memory
        with_memory = net(images, K, poses, rng, targets=[(1, (0, 2))], memory=[other])[0]
    assert torch.equal(alone.depths[0], with_memory.depths[0])  # D0 is computed before the EST
    assert (alone.depths[1] - with_memory.depths[1]).abs().max() > 1e-4


def test_loss_weights_and_invalid_pixels():
    assert stage_weights() == pytest.approx([0.512, 0.64, 0.8, 1.0])
    gt = torch.zeros(1, 1, 4, 4)
    gt[0, 0, :2] = 2.0  # half the pixels valid
    pred_full = torch.full((1, 1, 4, 4), 3.0)
    pred_low = torch.full((1, 1, 2, 2), 2.5)
    loss, per_stage = multi_stage_loss([[pred_low, pred_low, pred_full, pred_full]], gt)
    assert per_stage == pytest.approx([0.5, 0.5, 1.0, 1.0])
    assert float(loss) == pytest.approx(0.512 * 0.5 + 0.64 * 0.5 + 0.8 + 1.0)


def test_gradient_term_rewards_edges_not_scale():
    gt = torch.ones(1, 1, 16, 16)
    gt[..., 8:] = 3.0  # a step edge: a near wall in front of a far one
    valid = torch.ones_like(gt, dtype=torch.bool)
    assert float(log_gradient_error(2.5 * gt, gt, valid)) == pytest.approx(0.0, abs=1e-6)
    ramp = torch.linspace(1.0, 3.0, 16).expand(1, 1, 16, 16)  # the same range, blurred over the image
    blurred = float(log_gradient_error(ramp, gt, valid))
    assert blurred > 0.05
    hidden = valid.clone()
    hidden[..., 4:12] = False  # no valid pair across the edge or the ramp's steep part counts
    assert float(log_gradient_error(ramp, gt, hidden)) < blurred
    loss, _ = multi_stage_loss([[ramp, ramp]], gt)
    with_grad, _ = multi_stage_loss([[ramp, ramp]], gt, grad_weight=2.0)
    assert float(with_grad - loss) == pytest.approx(2.0 * blurred, rel=1e-5)


def test_near_factor_weighs_only_depth_that_is_too_near():
    gt = torch.full((1, 1, 2, 2), 2.0)
    near, far = torch.full((1, 1, 2, 2), 1.5), torch.full((1, 1, 2, 2), 2.5)  # both 0.5 m off
    for kind in ("l1", "log_l1"):
        plain = [float(multi_stage_loss([[p]], gt, kind)[0]) for p in (near, far)]
        weighted = [float(multi_stage_loss([[p]], gt, kind, near_factor=3.0)[0]) for p in (near, far)]
        assert weighted[0] == pytest.approx(3.0 * plain[0]) and weighted[1] == pytest.approx(plain[1])


def test_near_margin_spares_small_near_errors_and_weighs_the_rest():
    gt = torch.full((1, 1, 1, 2), 2.0)
    pred = torch.tensor([[[[1.9, 1.0]]]])  # 5 % and 50 % too near
    for kind, excess in (("l1", 1.0 - 0.2), ("log_l1", math.log(2.0) - math.log(1 / 0.9))):
        plain = float(multi_stage_loss([[pred]], gt, kind)[0])
        margin = float(multi_stage_loss([[pred]], gt, kind, near_factor=3.0, near_margin=0.1)[0])
        # only the 50 % pixel's error beyond 10 % of the truth weighs 2 more; mean over the two pixels
        assert margin - plain == pytest.approx(2.0 * excess / 2, rel=1e-5)
    far = torch.full((1, 1, 1, 2), 4.0)
    assert float(multi_stage_loss([[far]], gt, "l1", near_factor=3.0, near_margin=0.1)[0]) == pytest.approx(2.0)


def test_config_round_trip_and_errors():
    assert ESTConfig.from_dict(COMPACT.to_dict()) == COMPACT
    assert get_config("paper") is PAPER
    with pytest.raises(ReconError):
        get_config("huge")
    with pytest.raises(ReconError):
        TINY.replace(fusion="sum")
    with pytest.raises(ReconError):
        TINY.replace(image_width=100)


def test_external_backbone_weights_load(tmp_path):
    donor = ContextNet(TINY)
    for p in donor.encoder.parameters():
        torch.nn.init.normal_(p)
    state = {f"module.{k}": v for k, v in donor.encoder.state_dict().items()}
    state["fc.weight"] = torch.zeros(10, 24)  # a classifier head is ignored
    torch.save(state, tmp_path / "backbone.pt")
    net = ContextNet(TINY)
    assert net.load_backbone(tmp_path / "backbone.pt") == []
    for (k, a), b in zip(net.encoder.state_dict().items(), donor.encoder.state_dict().values()):
        assert torch.equal(a, b), k
    torch.save(ContextNet(COMPACT).encoder.state_dict(), tmp_path / "other.pt")
    with pytest.raises(ReconError, match="does not match"):
        net.load_backbone(tmp_path / "other.pt")
