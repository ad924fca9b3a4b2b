"""Test-time adaptation (`depth.adapt`): a loss that prefers the true depth, steps that lower it, a copy that
leaves the loaded network alone, and the depth stage's option."""
import json

import numpy as np
import pytest
import torch

from depth.adapt import _clip, adapted_copy, photometric_error, reprojection_loss, self_supervised_loss, ssim_distance
from depth.config import TINY
from depth.estimator import DepthEstimator
from depth.inference import estimate_depth
from depth.model import ESTNet
from depth.options import AdaptOptions, DepthOptions
from recon.errors import ReconError
from recon.plane_scene import plane_scan

pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def scan():
    return plane_scan(6, 160, 128, step=0.08)


def test_ssim_distance_is_zero_for_equal_images_and_grows_with_noise():
    x = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    noise = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(1)) - 0.5
    assert ssim_distance(x, x).abs().max() < 1e-6
    small, large = (photometric_error(x, (x + a * noise).clamp(0, 1)).mean() for a in (0.1, 0.5))
    assert 0 < small < large


def test_reprojection_loss_prefers_the_true_depth(scan):
    images, K, poses = _clip(scan, 0, 5, torch.device("cpu"))
    true = torch.from_numpy(scan.depth(2))[None, None]
    losses = {name: float(reprojection_loss(depth, 2, images, K, poses))
              for name, depth in (("true", true), ("25 % far", true * 1.25), ("20 % near", true * 0.8),
                                  ("flat", torch.full_like(true, float(true.mean()))))}
    assert losses["true"] < 0.5 * min(v for k, v in losses.items() if k != "true"), losses


def test_adapted_copy_lowers_the_loss_and_leaves_the_model_alone(scan):
    torch.manual_seed(0)
    model = ESTNet(TINY).eval()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    images, K, poses = _clip(scan, 0, 5, torch.device("cpu"))
    rng = torch.tensor([[1.0, 5.0]])

    def loss_of(m):
        with torch.no_grad():
            return float(self_supervised_loss(images, K, poses, m(images, K, poses, rng)))

    # lr 2e-3: at 1e-3 eight steps took just over 10 % off on earlier sessions' Intel CPUs and 9.8 % on an AMD EPYC
    # (2026-12-07), too close to the bar to say anything; at 2e-3 they take 15 % there
    adapted, summary = adapted_copy(model, scan.select(0, 1, 5), (1.0, 5.0), AdaptOptions(steps=8, lr=2e-3))
    assert all(torch.equal(v, model.state_dict()[k]) for k, v in before.items())
    assert any(not torch.equal(v, adapted.state_dict()[k]) for k, v in before.items() if v.is_floating_point())
    assert not adapted.training and summary["steps"] == 8 and summary["seconds"] > 0
    assert loss_of(adapted) < 0.9 * loss_of(model)


def test_depth_stage_adapts_when_asked_and_records_it(scan, tmp_path):
    torch.manual_seed(0)
    estimator = DepthEstimator(ESTNet(TINY), "cpu")
    before = {k: v.clone() for k, v in estimator.model.state_dict().items()}
    opts = DepthOptions(mode="estm", precision="fp32", adapt=AdaptOptions(steps=2, lr=1e-3))
    plain = estimate_depth(scan, tmp_path / "plain", DepthOptions(mode="estm", precision="fp32"), estimator=estimator)
    summary = estimate_depth(scan, tmp_path / "adapted", opts, estimator=estimator)
    assert all(torch.equal(v, estimator.model.state_dict()[k]) for k, v in before.items())
    stored = json.loads((tmp_path / "adapted" / "depth.json").read_text())
    assert stored["adaptation"]["steps"] == 2 and stored["settings"]["adapt"]["lr"] == 1e-3
    assert "adaptation" not in plain and "adapt" not in plain["settings"]
    from recon.io import load_depth_map

    name = scan.names[3]
    assert np.abs(load_depth_map(tmp_path / "plain", name) - load_depth_map(tmp_path / "adapted", name)).max() > 1e-4
    assert summary["frames"] == stored["frames"]


def test_adaptation_refuses_bad_settings_before_writing(scan, tmp_path):
    estimator = DepthEstimator(ESTNet(TINY), "cpu")
    with pytest.raises(ReconError, match="at least 5 frames"):
        estimate_depth(scan.select(0, 1, 4), tmp_path / "short", DepthOptions(adapt=AdaptOptions(steps=1)),
                       estimator=estimator)
    assert not (tmp_path / "short").exists()
    for bad, message in ((AdaptOptions(steps=-1), "--adapt-steps"), (AdaptOptions(steps=1, lr=0), "--adapt-lr")):
        with pytest.raises(ReconError, match=message):
            DepthOptions(adapt=bad).validate()
    with pytest.raises(ReconError, match="adapts a network"):
        DepthOptions(mode="planesweep", adapt=AdaptOptions(steps=3)).validate()


def test_anchor_measures_how_far_the_depth_moved():
    from depth.adapt import anchor_loss
    from depth.model import TargetOutput

    def out(depth):
        return TargetOutput(depths=[depth], confidence=None, memory=None)

    d = torch.full((1, 1, 4, 4), 2.0)
    assert float(anchor_loss([out(d)], [out(d)])) == 0
    assert abs(float(anchor_loss([out(d * 1.1)], [out(d)])) - np.log(1.1)) < 1e-5


def test_anchor_holds_the_adapted_depth_near_the_unadapted(scan):
    from depth.adapt import anchor_loss

    torch.manual_seed(0)
    model = ESTNet(TINY).eval()
    images, K, poses = _clip(scan, 0, 5, torch.device("cpu"))
    rng = torch.tensor([[1.0, 5.0]])
    with torch.no_grad():
        reference = model(images, K, poses, rng)
        moved = {anchor: float(anchor_loss(adapted_copy(model, scan.select(0, 1, 5), (1.0, 5.0),
                                                        AdaptOptions(steps=6, lr=1e-3, anchor=anchor))[0](
            images, K, poses, rng), reference)) for anchor in (0.0, 10.0)}
    assert 0 < moved[10.0] < 0.7 * moved[0.0], moved
