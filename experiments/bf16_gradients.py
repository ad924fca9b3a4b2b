"""How far bf16 autocast moves a training clip's gradient, against how far an imperceptible input noise does.

    python experiments/bf16_gradients.py --weights compact --clips 6 --threads 1

For each clip of the synthetic training stream (as `recon train --synthetic --close-ups` draws them)
the model in train mode computes the loss gradient four ways from the same weights and BatchNorm
statistics: fp32, fp32 again (must agree to 1.000), bf16 autocast, and fp32 with N(0, 1e-3) added to
the images (a quarter of one 8-bit grey level). It prints the loss of each and the cosine similarity of
each gradient with the fp32 one, and last the cosine between consecutive clips' fp32 gradients (the
sampling noise of batch-1 training). Measured 2026-12-06 in docs/depth.md "Training precision".
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def gradient(model, state: dict, params: list, clip: dict, bf16: bool = False, noise: float = 0.0
             ) -> tuple[float, torch.Tensor]:
    """Loss and flattened gradient of one clip from the weights and statistics in `state`."""
    from depth.train import clip_loss

    model.load_state_dict(state)
    model.zero_grad(set_to_none=True)
    batch = {k: v.unsqueeze(0) for k, v in clip.items()}
    if noise:
        gen = torch.Generator().manual_seed(5)
        batch["images"] = (batch["images"] + noise * torch.randn(batch["images"].shape, generator=gen)).clamp(0, 1)
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        loss, _, _ = clip_loss(model, batch)
    loss.backward()
    return float(loss.detach()), torch.cat([p.grad.flatten() for p in params])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default="compact")
    p.add_argument("--clips", type=int, default=6)
    p.add_argument("--seed", type=int, default=777, help="training-stream seed")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)

    from depth.checkpoint import build_model, load_checkpoint, trained_depth_range
    from depth.data import ClipOptions, StreamingClips
    from recon.synthetic import iter_training_mix

    ck = load_checkpoint(args.weights)
    model = build_model(ck).train()
    cfg = ck.config
    opts = ClipOptions(width=cfg.image_width, height=cfg.image_height, scale_jitter=0.4, reverse_share=0.5)
    depth_range = trained_depth_range(args.weights) or (0.25, 10.0)
    stream = iter(StreamingClips(iter_training_mix(args.seed, depth_range, close_ups=True), opts, seed=3))
    params = [q for q in model.parameters() if q.requires_grad]
    state = {k: v.clone() for k, v in model.state_dict().items()}
    cos = torch.nn.functional.cosine_similarity
    previous = None
    for i in range(args.clips):
        clip = next(stream)
        l32, g32 = gradient(model, state, params, clip)
        l_again, g_again = gradient(model, state, params, clip)
        l16, g16 = gradient(model, state, params, clip, bf16=True)
        l_noise, g_noise = gradient(model, state, params, clip, noise=1e-3)
        print(f"clip {i}: loss fp32 {l32:.4f} (again {l_again:.4f}, cos {float(cos(g32, g_again, 0)):.3f}) | "
              f"bf16 {l16:.4f}, cos {float(cos(g32, g16, 0)):.3f} | images + 1e-3 noise {l_noise:.4f}, "
              f"cos {float(cos(g32, g_noise, 0)):.3f}"
              + ("" if previous is None else f" | cos with the previous clip's {float(cos(g32, previous, 0)):.3f}"),
              flush=True)
        previous = g32
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
