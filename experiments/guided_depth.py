"""Does an image-guided filter on finished depth maps make them follow the image, and fuse better?

    python experiments/guided_depth.py runs/select/compact_k20_010000 --radius 4 8 --eps 1e-3 1e-2 \
        --out runs/guided

Reads the ESTM maps that experiments/select_checkpoint.py wrote for one checkpoint (`<folder>/<scan>/estm_m2`),
filters each with He et al.'s guided filter (the frame's grey image as guide, in inverse depth so near edges
weigh as much as far ones) and, with `--sharpener`, with a trained edge sharpener, and scores the result the way selection does: Abs Rel and flicker on the GT
depth, mesh precision / recall / F after the default filter and fusion. No network runs, so a setting costs
only the fusion. Held-out scans only (never 7-Scenes).
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def box_mean(x, r: int):
    """(H, W) float -> the mean over the (2r+1)^2 window around each pixel, inside the image."""
    import cv2

    return cv2.blur(x, (2 * r + 1, 2 * r + 1), borderType=cv2.BORDER_REFLECT)


def guided_filter(guide, src, r: int, eps: float):
    """guide, src (H, W) float32 -> src filtered so its edges follow the guide's (He, Sun, Tang 2010)."""
    mean_i, mean_p = box_mean(guide, r), box_mean(src, r)
    cov_ip = box_mean(guide * src, r) - mean_i * mean_p
    var_i = box_mean(guide * guide, r) - mean_i * mean_i
    a = cov_ip / (var_i + eps)
    b = mean_p - a * mean_i
    return box_mean(a, r) * guide + box_mean(b, r)


def guided(r: int, eps: float):
    """A per-frame filter (depth, RGB uint8, confidence -> depth): the guided filter in inverse depth."""
    import cv2
    import numpy as np

    def run(depth, rgb, confidence):
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
        inv = 1.0 / np.maximum(depth, 1e-3)
        return 1.0 / np.maximum(guided_filter(grey, inv, r, eps), 1e-3)

    return run


def sharpener(path: str, size: tuple[int, int]):
    """A per-frame filter running a trained `EdgeSharpener` (experiments/train_sharpener.py) at the network
    size (w, h): maps of another aspect are stretched to it and back, as inference does."""
    import cv2
    import numpy as np
    import torch

    from experiments.train_sharpener import EdgeSharpener, PriorRefiner, normalise_image

    saved = torch.load(path)
    options = saved["options"]
    if options.get("prior"):
        model = PriorRefiner(options["channels"][0])
    else:
        model = EdgeSharpener(tuple(options["channels"]), residual=options.get("residual", False))
    model.eval()
    model.load_state_dict(saved["state_dict"])

    def run(depth, rgb, confidence):
        h, w = depth.shape
        d = torch.from_numpy(cv2.resize(depth, size, interpolation=cv2.INTER_LINEAR))[None, None]
        c = torch.from_numpy(cv2.resize(confidence.astype(np.float32), size))[None, None]
        image = torch.from_numpy(cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)).permute(2, 0, 1)[None] / 255.0
        with torch.no_grad():
            out = model(d, normalise_image(image), c)[0, 0].numpy()
        return cv2.resize(out, (w, h), interpolation=cv2.INTER_NEAREST)

    return run


def filter_folder(scan, src: Path, dst: Path, run) -> None:
    """Every map of `src` through `run(depth, RGB uint8 at the map's size, confidence)`, written to `dst`."""
    import cv2
    import numpy as np

    from recon.io import load_confidence_map, load_depth_map, save_depth_map

    dst.mkdir(parents=True, exist_ok=True)
    shutil.copy(src / "depth.json", dst / "depth.json")
    for i, name in enumerate(scan.names):
        depth = load_depth_map(src, name)
        confidence = load_confidence_map(src, name)
        h, w = depth.shape
        rgb = cv2.resize(scan.image(i), (w, h), interpolation=cv2.INTER_AREA)
        out = np.clip(run(depth, rgb, confidence), depth.min(), depth.max()).astype(np.float32)
        save_depth_map(dst, name, np.where(depth > 0, out, 0), confidence)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("select_folder", help="a checkpoint's folder under runs/select")
    p.add_argument("--radius", type=int, nargs="*", default=[4], help="guided-filter radii (none: no guided rows)")
    p.add_argument("--eps", type=float, nargs="+", default=[1e-2])
    p.add_argument("--sharpener", default=None, help="also a trained edge sharpener (experiments/train_sharpener.py)")
    p.add_argument("--scans", nargs="*", default=None, help="held-out scan names (default: all)")
    p.add_argument("--out", default="runs/guided")
    args = p.parse_args(argv)

    from depth.metrics import evaluate_depth_folder
    from experiments.results_7scenes import TableOptions, mesh_scores
    from experiments.select_checkpoint import heldout_scans

    src_root, out = Path(args.select_folder), Path(args.out)
    scans = heldout_scans(src_root.parent / "scans")
    results_path = out / "results.json"
    results = json.loads(results_path.read_text()) if results_path.is_file() else {}
    settings = [("none", None)] + [(f"r{r}_eps{e:g}", guided(r, e)) for r in args.radius for e in args.eps]
    if args.sharpener:
        settings.append(("sharpener", sharpener(args.sharpener, (320, 256))))
    for scan_name, scan in scans.items():
        if args.scans and scan_name not in args.scans:
            continue
        for label, run in settings:
            folder = out / label / scan_name
            if label == "none":
                folder.mkdir(parents=True, exist_ok=True)
                shutil.copytree(src_root / scan_name / "estm_m2", folder / "estm_m2", dirs_exist_ok=True)
            else:
                filter_folder(scan, src_root / scan_name / "estm_m2", folder / "estm_m2", run)
            m = evaluate_depth_folder(folder / "estm_m2", scan, 1e-3, 10.0)
            mesh = mesh_scores(scan, folder, TableOptions(mesh_row="estm_m2"), log=lambda s: None)
            row = {"abs_rel": m["abs_rel"], "a1": m["a1"], "flicker": m["flicker"], "edge_f": m["edge_f"],
                   **{f"mesh_{k}": mesh[k] for k in ("prec", "recall", "fscore")}}
            results.setdefault(label, {})[scan_name] = row
            print(f"{scan_name} {label}: abs_rel {row['abs_rel']:.4f} a1 {row['a1']:.3f} edge F {row['edge_f']:.3f} flicker {row['flicker']:.4f} "
                  f"mesh P/R/F {row['mesh_prec']:.3f} / {row['mesh_recall']:.3f} / {row['mesh_fscore']:.3f}", flush=True)
            results_path.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
