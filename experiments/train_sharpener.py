"""Can a 2D network after the frozen EST network make its depth follow the image? Trains one on a bank.

    python experiments/train_sharpener.py runs/sharpen_bank/*.pt --steps 2500 --batch 4 --crop 192 \
        --channels 32 --prior --out runs/sharpen_prior_a

The network's maps are smooth where the scene has occluding edges (docs/depth.md, "Edges, measured").
`EdgeSharpener` follows the displacement-field idea of Ramamonjisoa et al. (CVPR 2020): a small U-Net reads
the image and the depth and predicts a 2D shift per pixel, and the output is the depth sampled at the
shifted position, so pixels on either side of a ramp fetch the plateau on their own side and every output
value is one the input had. `--residual` adds a per-pixel depth factor; `--prior` (`PriorRefiner`) predicts
both from the frozen ImageNet EfficientNet-Lite0 pyramid instead of a U-Net trained from scratch.

The bank comes from experiments/sharpen_bank.py (training-stream rooms only). The last `--val-share` of
each bank file is held back; every `--val-every` steps it is scored as the network left it and as
sharpened: Abs Rel and occluding-edge precision / recall / F (depth.metrics). Writes `sharpener.pt` (state
dict + options) and `log.jsonl` under --out; `experiments/guided_depth.py --sharpener` scores it on the held-out
scans' stored maps.
"""
from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1), nn.ReLU(inplace=True))


def shift_sample(depth: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """depth (B, 1, H, W); shift (B, 2, H, W) in pixels (x, y) -> depth sampled at p + shift (B, 1, H, W),
    bilinear, clamped to the border."""
    b, _, h, w = depth.shape
    ys, xs = torch.meshgrid(torch.arange(h, device=depth.device, dtype=depth.dtype),
                            torch.arange(w, device=depth.device, dtype=depth.dtype), indexing="ij")
    x = (xs + shift[:, 0] + 0.5) * (2.0 / w) - 1.0
    y = (ys + shift[:, 1] + 0.5) * (2.0 / h) - 1.0
    return F.grid_sample(depth, torch.stack([x, y], -1), mode="bilinear", padding_mode="border", align_corners=False)


def normalise_image(image: torch.Tensor) -> torch.Tensor:
    """RGB in [0, 1] (B, 3, H, W) -> ImageNet-normalised, as the network's own input."""
    from depth.model.network import IMAGENET_MEAN, IMAGENET_STD

    return (image - image.new_tensor(IMAGENET_MEAN).view(1, 3, 1, 1)) / image.new_tensor(IMAGENET_STD).view(1, 3, 1, 1)


def depth_cues(depth: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) m and (B, 1, h, w) -> (B, 2, H, W): log depth minus its per-map mean (the scene's shape, not
    its scale) and the confidence at the depth's size."""
    log_depth = torch.log(depth.clamp_min(1e-3))
    conf = F.interpolate(confidence, depth.shape[-2:], mode="bilinear", align_corners=False)
    return torch.cat([log_depth - log_depth.mean(dim=(2, 3), keepdim=True), conf], 1)


def apply_head(depth: torch.Tensor, out: torch.Tensor, max_shift: float, max_log_residual: float) -> torch.Tensor:
    """depth (B, 1, H, W); out (B, 2 or 3, H, W) raw -> depth shifted by max_shift * tanh(out[:2]) pixels, then
    scaled by exp(max_log_residual * tanh(out[2])) when there is a third channel."""
    sharpened = shift_sample(depth, max_shift * torch.tanh(out[:, :2]))
    if out.shape[1] == 3:
        sharpened = sharpened * torch.exp(max_log_residual * torch.tanh(out[:, 2:]))
    return sharpened


class EdgeSharpener(nn.Module):
    """(depth (B, 1, H, W) m, normalised image (B, 3, H, W), confidence (B, 1, h, w)) -> sharpened depth
    (B, 1, H, W). A U-Net with one level per entry of `channels` (full resolution, then each half the
    last); the shift is at most `max_shift` pixels. With `residual`, the shifted depth is also scaled by a
    predicted factor exp(+-`max_log_residual`), which can correct depth, not only move it. Both start at zero
    (the last convolution is zero-initialised), so an untrained sharpener is the identity."""

    def __init__(self, channels: tuple[int, ...] = (16, 24, 32, 48), max_shift: float = 12.0,
                 residual: bool = False, max_log_residual: float = 0.5):
        super().__init__()
        self.max_shift, self.max_log_residual = max_shift, max_log_residual
        widths = (5, *channels)
        self.down = nn.ModuleList(nn.Sequential(_conv(widths[i], widths[i + 1], 1 if i == 0 else 2),
                                                _conv(widths[i + 1], widths[i + 1])) for i in range(len(channels)))
        self.up = nn.ModuleList(_conv(channels[i + 1] + channels[i], channels[i]) for i in range(len(channels) - 1))
        self.head = nn.Conv2d(channels[0], 3 if residual else 2, 3, 1, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, depth: torch.Tensor, image: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
        skips = []
        x = torch.cat([image, depth_cues(depth, confidence)], 1)
        for down in self.down:
            x = down(x)
            skips.append(x)
        for up, skip in zip(reversed(self.up), reversed(skips[:-1])):
            x = up(torch.cat([F.interpolate(x, skip.shape[-2:], mode="bilinear", align_corners=False), skip], 1))
        return apply_head(depth, self.head(x), self.max_shift, self.max_log_residual)


class PriorRefiner(nn.Module):
    """The sharpener's shift and depth factor predicted by a decoder over the frozen ImageNet EfficientNet-Lite0
    pyramid (the monocular prior the EST stage lacks), with the log depth and confidence pooled into each
    level. Same inputs and output as `EdgeSharpener(residual=True)`; identity at initialisation."""

    def __init__(self, width: int = 32, max_shift: float = 12.0, max_log_residual: float = 0.5):
        from depth.model.efficientnet import EfficientNetLite, load_pretrained

        super().__init__()
        self.max_shift, self.max_log_residual = max_shift, max_log_residual
        self.encoder = load_pretrained(EfficientNetLite(classifier=False)).requires_grad_(False)
        self.lateral = nn.ModuleList(_conv(c + 2, width) for c in self.encoder.channels)
        self.up = nn.ModuleList(_conv(2 * width, width) for _ in self.encoder.channels[:-1])
        self.full = _conv(width + 5, 16)
        self.head = nn.Conv2d(16, 3, 3, 1, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def train(self, mode: bool = True):
        super().train(mode)
        self.encoder.eval()
        return self

    def forward(self, depth: torch.Tensor, image: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
        cues = depth_cues(depth, confidence)
        with torch.no_grad():
            feats = self.encoder.pyramid(image)
        lat = [lateral(torch.cat([f, F.adaptive_avg_pool2d(cues, f.shape[-2:])], 1))
               for lateral, f in zip(self.lateral, feats)]
        x = lat[-1]
        for up, skip in zip(reversed(self.up), reversed(lat[:-1])):
            x = up(torch.cat([F.interpolate(x, skip.shape[-2:], mode="bilinear", align_corners=False), skip], 1))
        x = F.interpolate(x, depth.shape[-2:], mode="bilinear", align_corners=False)
        return apply_head(depth, self.head(self.full(torch.cat([x, image, cues], 1))), self.max_shift,
                          self.max_log_residual)


def to_batch(samples: list[dict], crop: int | None, rng: random.Random) -> dict:
    """Samples -> batch tensors: image (B, 3, H, W) in [0, 1], depth / gt (B, 1, H, W), confidence
    (B, 1, h, w), each optionally cropped to crop x crop (the confidence's crop follows at 1/4) and
    mirrored left-right at random."""
    out = {"image": [], "depth": [], "gt": [], "confidence": []}
    for s in samples:
        image, depth, gt, conf = s["image"].float() / 255, s["depth"].float()[None], s["gt"].float()[None], \
            s["confidence"].float()[None]
        if crop:
            h, w = depth.shape[-2:]
            y, x = 4 * rng.randrange((h - crop) // 4 + 1), 4 * rng.randrange((w - crop) // 4 + 1)
            image, depth, gt = (t[..., y:y + crop, x:x + crop] for t in (image, depth, gt))
            conf = conf[..., y // 4:(y + crop) // 4, x // 4:(x + crop) // 4]
        if rng.random() < 0.5:
            image, depth, gt, conf = (t.flip(-1) for t in (image, depth, gt, conf))
        for k, v in zip(("image", "depth", "gt", "confidence"), (image, depth, gt, conf)):
            out[k].append(v)
    return {k: torch.stack(v) for k, v in out.items()}


def loss_fn(pred: torch.Tensor, gt: torch.Tensor, grad_weight: float) -> torch.Tensor:
    from depth.loss import log_gradient_error

    valid = gt > 0
    target = torch.where(valid, gt, torch.ones_like(gt))
    log_l1 = ((torch.log(pred.clamp_min(1e-3)) - torch.log(target)).abs() * valid).sum() / valid.sum().clamp_min(1)
    return log_l1 + grad_weight * log_gradient_error(pred, target, valid)


@torch.no_grad()
def score(model, samples: list[dict]) -> dict:
    """Abs Rel, log L1 and edge P/R/F of the network's maps and of the sharpened ones over `samples`."""
    import numpy as np

    from depth.metrics import edge_counts, edge_scores

    rows = {"input": [], "sharpened": []}
    counts = {"input": [], "sharpened": []}
    for s in samples:
        b = to_batch([s], None, random.Random(0))
        pred = model(b["depth"], normalise_image(b["image"]), b["confidence"])
        gt = b["gt"][0, 0].numpy()
        valid = gt > 0
        for name, d in (("input", b["depth"][0, 0].numpy()), ("sharpened", pred[0, 0].numpy())):
            rows[name].append((np.abs(d[valid] - gt[valid]) / gt[valid]).mean() if valid.any() else np.nan)
            counts[name].append(edge_counts(d, gt, valid))
    return {name: {"abs_rel": float(np.nanmean(rows[name])), **edge_scores(counts[name])} for name in rows}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("banks", nargs="+")
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--crop", type=int, default=192)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--grad-weight", type=float, default=1.0)
    p.add_argument("--channels", type=int, nargs="+", default=[16, 24, 32, 48])
    p.add_argument("--residual", action="store_true", help="also a depth factor per pixel")
    p.add_argument("--prior", action="store_true", help="PriorRefiner (pretrained encoder) instead")
    p.add_argument("--val-share", type=float, default=0.1)
    p.add_argument("--val-every", type=int, default=500)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = random.Random(args.seed)
    train, val = [], []
    for path in args.banks:
        samples = torch.load(path)
        cut = int(len(samples) * (1 - args.val_share))
        train += samples[:cut]
        val += samples[cut:]
    model = PriorRefiner(args.channels[0]) if args.prior else EdgeSharpener(tuple(args.channels), residual=args.residual)
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=args.lr)
    warmup = max(1, args.steps // 20)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, (s + 1) / warmup) * 0.5 * (
        1 + math.cos(math.pi * min(1.0, s / args.steps))))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = (out / "log.jsonl").open("a")
    print(f"{len(train)} training samples, {len(val)} validation samples", flush=True)
    t0, running = time.time(), []
    for step in range(1, args.steps + 1):
        b = to_batch(rng.sample(train, args.batch), args.crop, rng)
        pred = model(b["depth"], normalise_image(b["image"]), b["confidence"])
        loss = loss_fn(pred, b["gt"], args.grad_weight)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
        running.append(float(loss.detach()))
        if step % 50 == 0:
            entry = {"step": step, "loss": sum(running) / len(running), "s": round(time.time() - t0)}
            running = []
            print(json.dumps(entry), flush=True)
            log.write(json.dumps(entry) + "\n")
        if step % args.val_every == 0 or step == args.steps:
            model.eval()
            entry = {"step": step, "val": score(model, val)}
            model.train()
            print(json.dumps(entry), flush=True)
            log.write(json.dumps(entry) + "\n")
            log.flush()
            torch.save({"state_dict": model.state_dict(), "options": vars(args)}, out / "sharpener.pt")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
