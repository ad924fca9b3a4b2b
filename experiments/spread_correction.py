"""Does the narrow sweep's correction carry over to the pixels it could not match?

    python experiments/spread_correction.py --select runs/select/compact [--sigmas 16,32,64] [--layers 0,8]

`--mode hybrid` moves a pixel off the network's depth only where the images match distinctively; on blank
walls it keeps the network's depth, which is 10-20 % off in blobs (docs/depth.md, "A 2D refiner after the
frozen network"). Those errors are smooth, so the log-ratio between the refined and the network's depth,
known on the matched pixels, may say how far off the network is on the blank pixels around them. Here it
is spread by normalised convolution (a Gaussian of `sigma` pixels, weighted by the match's NCC), optionally
within layers of the network's log-depth so that it does not cross occluding edges, and applied where the
spread has support. Rows per held-out scan (stored maps of `select_checkpoint.py --hybrid`, never
7-Scenes): ESTM, hybrid, hybrid + spread correction; Abs Rel and unfiltered mesh P / R / F at 5 cm.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def spread(values: np.ndarray, weight: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian normalised convolution: (blur(w v), blur(w)), both (H, W)."""
    k = int(4 * sigma) | 1
    return (cv2.GaussianBlur(weight * values, (k, k), sigma, borderType=cv2.BORDER_REFLECT),
            cv2.GaussianBlur(weight, (k, k), sigma, borderType=cv2.BORDER_REFLECT))


def spread_log_ratio(log_ratio: np.ndarray, weight: np.ndarray, log_depth: np.ndarray, sigma: float,
                     layers: int, sigma_log: float) -> tuple[np.ndarray, np.ndarray]:
    """The weighted log-ratio spread to every pixel -> (ratio, support), (H, W) each. With `layers` > 0 the
    spread runs per layer of the network's log-depth (Gaussian memberships of width `sigma_log`), and a pixel
    reads the layers it belongs to: a coarse bilateral grid, so the correction stays on its own surface."""
    if layers <= 0:
        num, den = spread(log_ratio, weight, sigma)
    else:
        centres = np.linspace(log_depth.min(), log_depth.max(), layers)
        num = np.zeros_like(log_ratio)
        den = np.zeros_like(log_ratio)
        for c in centres:
            member = np.exp(-0.5 * ((log_depth - c) / sigma_log) ** 2).astype(np.float32)
            n, d = spread(log_ratio, weight * member, sigma)
            num += member * n
            den += member * d
    return num / np.maximum(den, 1e-6), den


def correct(net: np.ndarray, hybrid: np.ndarray, score: np.ndarray, sigma: float, layers: int, sigma_log: float,
            support: float) -> np.ndarray:
    """The hybrid's map with the unmatched pixels scaled by the spread correction (faded out below `support`)."""
    matched = (hybrid != net) & (net > 0) & (hybrid > 0)
    log_ratio = np.where(matched, np.log(np.maximum(hybrid, 1e-3) / np.maximum(net, 1e-3)), 0).astype(np.float32)
    weight = np.where(matched, score, 0).astype(np.float32)
    log_depth = np.log(np.maximum(net, 1e-3)).astype(np.float32)
    ratio, den = spread_log_ratio(log_ratio, weight, log_depth, sigma, layers, sigma_log)
    fade = den / (den + support)
    out = net * np.exp(ratio * fade)
    return np.where(matched | (net <= 0), hybrid, out).astype(np.float32)


def write_row(scan, run: Path, row: str, sigma: float, layers: int, sigma_log: float, support: float) -> dict:
    """Write the corrected maps to run/row; returns the mean relative error of the pixels the sweep left
    unmatched, before (`network`) and after (`corrected`) the correction."""
    from recon.io import load_confidence_map, load_depth_map, save_depth_map

    net_dir, hyb_dir, out = run / "estm_m2", run / "hybrid", run / row
    out.mkdir(parents=True, exist_ok=True)
    summary = json.loads((hyb_dir / "depth.json").read_text())
    index = {f.name: i for i, f in enumerate(scan.frames)}
    errors = {"network": [], "corrected": []}
    for f in summary["frames"]:
        name = f["name"]
        net, hyb = load_depth_map(net_dir, name), load_depth_map(hyb_dir, name)
        conf = load_confidence_map(hyb_dir, name)
        corrected = correct(net, hyb, conf, sigma, layers, sigma_log, support)
        save_depth_map(out, name, corrected, conf)
        gt = cv2.resize(scan.depth(index[name]), net.shape[::-1], interpolation=cv2.INTER_NEAREST)
        unmatched = (hyb == net) & (gt > 0) & (net > 0)
        for key, depth in (("network", net), ("corrected", corrected)):
            errors[key].append(np.abs(depth[unmatched] - gt[unmatched]) / gt[unmatched])
    (out / "depth.json").write_text(json.dumps({**summary, "mode": f"hybrid + spread correction ({row})"}))
    return {f"unmatched_{k}": float(np.concatenate(v).mean()) for k, v in errors.items()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--select", default="runs/select/compact", help="a weights' folder of select_checkpoint.py --hybrid")
    p.add_argument("--scans-cache", default="runs/select/scans")
    p.add_argument("--sigmas", default="16,32,64")
    p.add_argument("--layers", default="0,8")
    p.add_argument("--sigma-log", type=float, default=0.1)
    p.add_argument("--support", type=float, default=0.02)
    p.add_argument("--scans", default="")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--mesh", action="store_true", help="also fuse and score each row's mesh (about 15 s a row)")
    p.add_argument("--out", default="runs/spread_correction.json")
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    from experiments.guided_sweep import score
    from experiments.select_checkpoint import heldout_scans

    results = {}
    for name, scan in heldout_scans(Path(args.scans_cache)).items():
        run = Path(args.select) / name
        if (args.scans and name not in args.scans.split(",")) or not (run / "hybrid").is_dir():
            continue
        rows, unmatched = ["estm_m2", "hybrid"], {}
        for sigma in map(float, args.sigmas.split(",")):
            for layers in map(int, args.layers.split(",")):
                row = f"spread_s{sigma:g}_l{layers}" + (f"_g{args.sigma_log:g}" if layers else "") + \
                      (f"_k{args.support:g}" if args.support != 0.02 else "")
                unmatched[row] = write_row(scan, run, row, sigma, layers, args.sigma_log, args.support)
                rows.append(row)
                print(f"{name} {row:28s} unmatched pixels' mean relative error {unmatched[row]['unmatched_network']:.4f}"
                      f" -> {unmatched[row]['unmatched_corrected']:.4f}", flush=True)
        results[name] = dict(unmatched)
        for row in rows if args.mesh else ():
            m = score(scan, run, row, "depth/weights/compact.pt")
            results[name][row] = {**unmatched.get(row, {}), **m}
            print(f"{name} {row:28s} abs_rel {m['abs_rel']:.4f} within5 {m['within_5cm']:.3f} "
                  f"P {m['prec']:.3f} R {m['recall']:.3f} F {m['F']:.3f}", flush=True)
    Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
