"""The edge-sharpener experiment (experiments/train_sharpener.py): shifted sampling, identity at initialisation,
learning to turn a ramp into a step."""
import pytest
import torch

from depth.loss import log_gradient_error
from experiments.train_sharpener import EdgeSharpener, shift_sample

pytestmark = pytest.mark.usefixtures("single_torch_thread")


def test_shift_sample_moves_by_whole_pixels():
    depth = torch.rand(2, 1, 12, 16) + 1
    assert torch.allclose(shift_sample(depth, torch.zeros(2, 2, 12, 16)), depth, atol=1e-6)
    shift = torch.zeros(2, 2, 12, 16)
    shift[:, 0] = 2.0  # read from two pixels to the right
    shift[:, 1] = -1.0  # and one row up
    out = shift_sample(depth, shift)
    assert torch.allclose(out[..., 1:, :-2], depth[..., :-1, 2:], atol=1e-6)
    assert torch.allclose(out[..., 0, :-2], depth[..., 0, 2:], atol=1e-6)  # above the top row: the top row
    assert torch.allclose(out[..., 1:, -1], depth[..., :-1, -1], atol=1e-6)


def test_untrained_sharpener_is_the_identity():
    torch.manual_seed(0)
    depth = torch.rand(1, 1, 32, 48) * 4 + 1
    out = EdgeSharpener((4, 4, 4, 4))(depth, torch.randn(1, 3, 32, 48), torch.rand(1, 1, 8, 12))
    assert torch.allclose(out, depth, atol=1e-5)


def _ramp_scene(batch: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A vertical occluding edge at a random column: the image is dark left, bright right; GT depth jumps
    from 1 m to 3 m there; the 'network' depth is the same step blurred into a 9 px ramp."""
    g = torch.Generator().manual_seed(seed)
    h, w = 32, 48
    cols = torch.randint(12, 36, (batch,), generator=g)
    x = torch.arange(w).float()
    gt = torch.where(x[None] < cols[:, None], 1.0, 3.0)[:, None, None, :].expand(batch, 1, h, w)
    ramp = ((x[None] - cols[:, None] + 4.5) / 9).clamp(0, 1)
    blurred = (1 + 2 * ramp)[:, None, None, :].expand(batch, 1, h, w)
    image = (gt - 2).expand(batch, 3, h, w).contiguous()
    return blurred.contiguous(), image, gt.contiguous()


def test_sharpener_learns_to_snap_a_ramp_to_the_image_edge():
    torch.manual_seed(0)
    model = EdgeSharpener((8, 8, 8, 8), max_shift=8.0)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    conf = torch.ones(4, 1, 8, 12)
    depth, image, gt = _ramp_scene(4, 100)

    def error(pred, truth):
        return float((pred - truth).abs().mean())

    before = error(depth, gt)
    for step in range(150):
        d, im, t = _ramp_scene(4, step)
        pred = model(d, im, conf)
        loss = (pred - t).abs().mean() + log_gradient_error(pred, t, torch.ones_like(t, dtype=torch.bool))
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        after = error(model(depth, image, conf), gt)
    assert after < 0.5 * before, (before, after)
