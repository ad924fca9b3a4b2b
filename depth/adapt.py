"""Test-time adaptation: fine-tune the network on the scan itself before it runs (`recon depth --adapt-steps N`).

The network was trained on synthetic rooms; a real scan differs in texture, light and layout. The scan's
own frames and poses hold a training signal that needs no ground truth: a right depth map warps its
neighbours onto the frame. Each step takes a clip of consecutive frames, predicts its middle frames'
depth as training does, and lowers the photometric error of the neighbours warped through that depth
(0.85 SSIM + 0.15 L1, per pixel the best neighbour, only where warping beats not warping: Monodepth2's
minimum reprojection and auto-mask), plus a small edge-aware smoothness. BatchNorm stays frozen
(`model.eval()`): one clip's statistics would drift it. The adapted weights live only for this run.
Measured in docs/depth.md "Test-time adaptation".
"""
from __future__ import annotations

import copy
import logging
import time

import torch
import torch.nn.functional as F

from recon.errors import ReconError
from recon.scan import Scan

from .geometry import plane_sweep_warp
from .model import ESTNet, TargetOutput
from .options import AdaptOptions
from .views import image_tensor

log = logging.getLogger(__name__)


def ssim_distance(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """(1 - SSIM) / 2 over 3x3 windows, averaged over channels. (B, C, H, W) x2 -> (B, 1, H, W) in [0, 1]."""
    def pool(t):
        return F.avg_pool2d(F.pad(t, (1, 1, 1, 1), mode="reflect"), 3, 1)

    mx, my = pool(x), pool(y)
    sx, sy, sxy = pool(x * x) - mx * mx, pool(y * y) - my * my, pool(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    ssim = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sx + sy + c2))
    return ((1 - ssim) / 2).clamp(0, 1).mean(1, keepdim=True)


def photometric_error(ref: torch.Tensor, other: torch.Tensor) -> torch.Tensor:
    """0.85 SSIM distance + 0.15 mean absolute difference. (B, 3, H, W) x2 -> (B, 1, H, W)."""
    return 0.85 * ssim_distance(ref, other) + 0.15 * (ref - other).abs().mean(1, keepdim=True)


def edge_aware_smoothness(depth: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """Gradients of the mean-normalised inverse depth, damped where the image has edges.
    depth (B, 1, H, W), image (B, 3, H, W) -> scalar."""
    disp = 1.0 / depth.clamp_min(1e-3)
    disp = disp / disp.mean((2, 3), keepdim=True)
    dx, dy = (disp[..., :, 1:] - disp[..., :, :-1]).abs(), (disp[..., 1:, :] - disp[..., :-1, :]).abs()
    ix = (image[..., :, 1:] - image[..., :, :-1]).abs().mean(1, keepdim=True)
    iy = (image[..., 1:, :] - image[..., :-1, :]).abs().mean(1, keepdim=True)
    return (dx * (-ix).exp()).mean() + (dy * (-iy).exp()).mean()


def reprojection_loss(depth: torch.Tensor, target: int, images: torch.Tensor, K: torch.Tensor,
                      camera_to_world: torch.Tensor) -> torch.Tensor:
    """Photometric error of frame `target` against every other clip frame warped through `depth`: per pixel
    the best neighbour, averaged over the pixels where warping beats the unwarped neighbour.

    depth (B, 1, H, W) metres of frame `target`; images (B, V, 3, H, W) in [0, 1]; K (B, 3, 3) at H x W;
    camera_to_world (B, V, 4, 4) -> scalar."""
    ref = images[:, target]
    warped_err, identity_err = [], []
    for s in range(images.shape[1]):
        if s == target:
            continue
        warped, valid = plane_sweep_warp(images[:, s], K, K, camera_to_world[:, target], camera_to_world[:, s],
                                         depth, ref_size=depth.shape[-2:])
        err = photometric_error(ref, warped[:, :, 0])
        warped_err.append(torch.where(valid, err, torch.full_like(err, 1e3)))
        identity_err.append(photometric_error(ref, images[:, s]) + 1e-5)  # ties go to "not warping"
    best = torch.stack(warped_err).min(0)[0]
    keep = (best < torch.stack(identity_err).min(0)[0]) & (best < 1e2)
    return (best * keep).sum() / keep.sum().clamp_min(1)


def self_supervised_loss(images: torch.Tensor, K: torch.Tensor, camera_to_world: torch.Tensor,
                         outputs: list[TargetOutput], smoothness: float = 1e-3) -> torch.Tensor:
    """Mean over a clip's targets (frames 1 .. V-2, in order) of `reprojection_loss` of the final depth plus
    `smoothness` x `edge_aware_smoothness`. Shapes as `reprojection_loss`; reads no ground truth."""
    total = images.new_zeros(())
    for t, out in enumerate(outputs, start=1):
        depth = out.depths[-1].float()
        total = total + reprojection_loss(depth, t, images, K, camera_to_world) \
            + smoothness * edge_aware_smoothness(depth, images[:, t])
    return total / len(outputs)


def anchor_loss(outputs: list[TargetOutput], reference: list[TargetOutput]) -> torch.Tensor:
    """Mean |log depth - log reference depth| of the targets' final depth: how far adapting has moved the
    depth from what the unadapted network predicts on the same clip. Depths (B, 1, H, W) -> scalar."""
    pairs = [(out.depths[-1].float(), ref.depths[-1].float()) for out, ref in zip(outputs, reference)]
    return torch.stack([(d.clamp_min(1e-3).log() - r.clamp_min(1e-3).log()).abs().mean() for d, r in pairs]).mean()


def _clip(net_scan: Scan, start: int, length: int, device: torch.device) -> tuple[torch.Tensor, ...]:
    """Frames start .. start + length - 1 of the network-size scan: images (1, V, 3, H, W), K (1, 3, 3),
    camera_to_world (1, V, 4, 4)."""
    idx = list(range(start, start + length))
    images = torch.stack([image_tensor(net_scan, i) for i in idx])[None]
    K = torch.from_numpy(net_scan.intrinsics.K).float()[None]
    poses = torch.from_numpy(net_scan.camera_to_world[idx]).float()[None]
    return images.to(device), K.to(device), poses.to(device)


def _step_loss(model: ESTNet, adapted: ESTNet, net_scan: Scan, start: int, depth_range: torch.Tensor,
               opts: AdaptOptions, bf16: bool) -> torch.Tensor:
    """The adaptation loss of `adapted` on the clip of `net_scan` starting at frame `start`."""
    device = depth_range.device
    images, K, poses = _clip(net_scan, start, opts.clip_length, device)
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
        outputs = adapted(images, K, poses, depth_range)
        if opts.anchor:
            with torch.no_grad():
                reference = model(images, K, poses, depth_range)
    loss = self_supervised_loss(images, K, poses, outputs, opts.smoothness)
    return loss + opts.anchor * anchor_loss(outputs, reference) if opts.anchor else loss


def adapted_copy(model: ESTNet, net_scan: Scan, depth_range: tuple[float, float], opts: AdaptOptions,
                 bf16: bool = False) -> tuple[ESTNet, dict]:
    """A copy of `model` fine-tuned on `net_scan` (the scan at the network's size, `depth.views.network_view`)
    with `self_supervised_loss` (+ `opts.anchor` x `anchor_loss` against `model`); the model passed in is left as
    it was. Returns (the copy in eval mode, what happened: steps, seconds, the mean loss of the first and of the
    last ten steps)."""
    opts.validate()
    if len(net_scan) < opts.clip_length:
        raise ReconError(f"test-time adaptation needs at least {opts.clip_length} frames, got {len(net_scan)}")
    device = next(model.parameters()).device
    adapted = copy.deepcopy(model).eval()  # eval: the frozen BatchNorm statistics stay as trained
    params = [p for p in adapted.parameters() if p.requires_grad]
    optimiser = torch.optim.Adam(params, lr=opts.lr)
    starts = torch.randperm(len(net_scan) - opts.clip_length + 1,
                            generator=torch.Generator().manual_seed(opts.seed)).tolist()
    rng = torch.tensor([depth_range], dtype=torch.float32, device=device)
    losses, started = [], time.perf_counter()
    for step in range(opts.steps):
        with torch.enable_grad():  # also when the caller runs under no_grad
            loss = _step_loss(model, adapted, net_scan, starts[step % len(starts)], rng, opts, bf16)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        losses.append(float(loss.detach()))
        if (step + 1) % 10 == 0:
            log.info("depth: adapting the network to the scan, step %d of %d, loss %.4f", step + 1, opts.steps,
                     losses[-1])
    window = max(min(10, len(losses) // 2), 1)
    summary = {"steps": opts.steps, "lr": opts.lr, "seconds": time.perf_counter() - started,
               "loss_start": sum(losses[:window]) / window if losses else None,
               "loss_end": sum(losses[-window:]) / window if losses else None}
    return adapted, summary
