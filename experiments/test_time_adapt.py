"""Does adapting the network to the scan itself help? Self-supervised test-time adaptation on held-out scans.

    python experiments/test_time_adapt.py --weights compact --cache runs/select_k35/scans --out runs/tta --steps 60

For each held-out selection scan: fine-tune a copy of the weights on the scan's own clips (5 consecutive frames,
the middle three as targets, as training makes them) with a photometric loss only: each target's predicted depth
warps its clip neighbours into it (`depth.geometry.plane_sweep_warp`, one depth per pixel), scored by
0.85 SSIM + 0.15 L1, the lower of the two per pixel, where warping beats not warping at all (Monodepth2's
auto-mask), plus a small edge-aware smoothness of the normalised inverse depth. The GT depth is never read
by the loss, only by the scores. Then ESTM runs on the scan with the adapted weights and is scored as selection
scores (Abs Rel; mesh F culled / unculled), next to the same weights unadapted. `--data FOLDER --stride N` runs
one other scan instead (every N-th frame at 320x256): how 7-Scenes is reported with settings fixed on the
held-out scans, never chosen on it.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def ssim_distance(x, y):
    """(1 - SSIM) / 2 over 3x3 windows, averaged over channels: (B, C, H, W) x2 -> (B, 1, H, W)."""
    import torch.nn.functional as F

    def pool(t):
        return F.avg_pool2d(F.pad(t, (1, 1, 1, 1), mode="reflect"), 3, 1)

    mx, my = pool(x), pool(y)
    sx, sy, sxy = pool(x * x) - mx * mx, pool(y * y) - my * my, pool(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    ssim = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sx + sy + c2))
    return ((1 - ssim) / 2).clamp(0, 1).mean(1, keepdim=True)


def photometric_error(ref, other):
    """(B, 3, H, W) x2 -> (B, 1, H, W): 0.85 SSIM distance + 0.15 mean absolute difference."""
    return 0.85 * ssim_distance(ref, other) + 0.15 * (ref - other).abs().mean(1, keepdim=True)


def smoothness(depth, image):
    """Edge-aware smoothness of the mean-normalised inverse depth. depth (B, 1, H, W), image (B, 3, H, W)."""
    disp = 1.0 / depth.clamp_min(1e-3)
    disp = disp / disp.mean((2, 3), keepdim=True)
    dx, dy = (disp[..., :, 1:] - disp[..., :, :-1]).abs(), (disp[..., 1:, :] - disp[..., :-1, :]).abs()
    ix = (image[..., :, 1:] - image[..., :, :-1]).abs().mean(1, keepdim=True)
    iy = (image[..., 1:, :] - image[..., :-1, :]).abs().mean(1, keepdim=True)
    return (dx * (-ix).exp()).mean() + (dy * (-iy).exp()).mean()


def self_supervised_loss(batch, outputs, smooth_weight: float = 1e-3):
    """Photometric loss of every target's full-resolution depth against its clip neighbours (targets 1..V-2,
    neighbours all other clip frames)."""
    import torch

    from depth.geometry import plane_sweep_warp

    images, K, poses = batch["images"], batch["K"], batch["camera_to_world"]
    total = images.new_zeros(())
    for t, out in enumerate(outputs, start=1):
        depth, ref = out.depths[-1].float(), images[:, t]
        warped_err, identity_err = [], []
        for s in range(images.shape[1]):
            if s == t:
                continue
            warped, valid = plane_sweep_warp(images[:, s], K, K, poses[:, t], poses[:, s], depth,
                                             ref_size=depth.shape[-2:])
            err = photometric_error(ref, warped[:, :, 0])
            warped_err.append(torch.where(valid, err, torch.full_like(err, 1e3)))
            identity_err.append(photometric_error(ref, images[:, s]) + 1e-5)
        best, _ = torch.stack(warped_err).min(0)
        keep = (best < torch.stack(identity_err).min(0)[0]) & (best < 1e2)
        total = total + (best * keep).sum() / keep.sum().clamp_min(1) + smooth_weight * smoothness(depth, ref)
    return total / len(outputs)


def adapt(weights: str, scan, steps: int, lr: float, depth_range, seed: int, log) -> "torch.nn.Module":
    """A copy of `weights` fine-tuned on `scan`'s clips with `self_supervised_loss`; returns the model."""
    import torch

    from depth.checkpoint import build_model, load_checkpoint
    from depth.data import ClipOptions, make_clip

    model = build_model(load_checkpoint(weights))
    model.eval()  # batch statistics of one clip would drift the frozen BatchNorm layers
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=lr)
    clip_opts = ClipOptions(width=scan.intrinsics.width, height=scan.intrinsics.height, augment=False)
    starts = torch.randperm(len(scan) - clip_opts.clip_length + 1, generator=torch.Generator().manual_seed(seed))
    for step in range(steps):
        clip = make_clip(scan, int(starts[step % len(starts)]), clip_opts)
        batch = {k: v[None] for k, v in clip.items() if k != "depth"}
        batch["depth_range"] = torch.tensor([depth_range], dtype=torch.float32)
        loss = self_supervised_loss(batch, model(batch["images"], batch["K"], batch["camera_to_world"],
                                                 batch["depth_range"]))
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 10 == 0 or step == steps - 1:
            log(f"step {step} loss {float(loss.detach()):.4f}")
    return model


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default="compact")
    p.add_argument("--cache", type=Path, default=Path("runs/select_k35/scans"))
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scans", default="")
    p.add_argument("--steps", type=int, default=60)
    p.add_argument("--lr", type=float, default=1e-5)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data", type=Path, default=None, help="one scan folder instead of the held-out scans")
    p.add_argument("--stride", type=int, default=10, help="with --data: every N-th frame")
    args = p.parse_args(argv)

    import torch

    from depth.checkpoint import load_checkpoint, save_checkpoint, trained_depth_range
    from experiments.results_7scenes import TableOptions, depth_table, mesh_scores
    from experiments.select_checkpoint import heldout_scans, unculled_fscore
    from recon.readers import open_scan

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    wanted = set(filter(None, args.scans.split(",")))
    depth_range = trained_depth_range(args.weights)
    results = {}
    scans = {args.data.name: open_scan(args.data).select(0, args.stride).resized(320, 256)} if args.data \
        else heldout_scans(args.cache)
    for scan_name, scan in scans.items():
        if wanted and scan_name not in wanted:
            continue
        t0 = time.time()
        model = adapt(args.weights, scan, args.steps, args.lr, depth_range, args.seed,
                      log=lambda s: print(f"{scan_name}: {s}", flush=True))
        adapted = args.out / f"{scan_name}_adapted.pt"
        args.out.mkdir(parents=True, exist_ok=True)
        save_checkpoint(adapted, model, load_checkpoint(args.weights).config,
                        metadata={"adapted_to": scan_name, "steps": args.steps, "lr": args.lr})
        adapt_s = time.time() - t0
        for name, weights in (("as shipped", args.weights), ("adapted", str(adapted))):
            folder = args.out / name.replace(" ", "_") / scan_name
            opts = TableOptions(weights=weights, rows=("estm_m2",), depth_range=depth_range, mesh=False)
            row = depth_table(scan, folder, opts, log=lambda s: None)["rows"]["estm_m2"]
            mesh = mesh_scores(scan, folder, TableOptions(), log=lambda s: None)
            results.setdefault(scan_name, {})[name] = {"abs_rel": row["abs_rel"], "mesh_f": mesh["fscore"],
                                                       "mesh_f_unculled": unculled_fscore(folder, "estm_m2")}
            print(f"{scan_name} {name}: Abs Rel {row['abs_rel']:.4f}  mesh F {mesh['fscore']:.3f} / "
                  f"{results[scan_name][name]['mesh_f_unculled']:.3f} unculled", flush=True)
        results[scan_name]["adapt_s"] = adapt_s
        (args.out / "summary.json").write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
