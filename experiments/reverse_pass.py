"""Does a second ESTM pass run backwards in time help? (held-out scans only, never 7-Scenes)

    python experiments/reverse_pass.py --forward runs/select/compact --out runs/reverse

Why: the ESTM memory only looks back, so the first frames of a walk have an empty or short memory and score
worst (docs/depth.md, "Where the demo room's error lies"). A pass over the reversed video gives every frame the
memory of the frames after it; each pixel then keeps the depth of the more confident pass, as the mirrored pass
does. Reuses the forward maps of `experiments/select_checkpoint.py` (`<forward>/<scan>/estm_m2`).
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def merge_by_confidence(first: Path, second: Path, out: Path, names: list[str]) -> None:
    """Each pixel keeps the depth (and confidence) of the folder whose confidence is higher there."""
    from recon.io import load_confidence_map, load_depth_map, save_depth_map

    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        d1, c1 = load_depth_map(first, name), load_confidence_map(first, name)
        d2, c2 = load_depth_map(second, name), load_confidence_map(second, name)
        take = c2 > c1
        save_depth_map(out, name, np.where(take, d2, d1), np.where(take, c2, c1))
    shutil.copy(first / "depth.json", out / "depth.json")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--forward", type=Path, default=Path("runs/select/compact"))
    p.add_argument("--weights", default="compact")
    p.add_argument("--out", type=Path, default=Path("runs/reverse"))
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    import torch

    torch.set_num_threads(args.threads)
    from depth.checkpoint import trained_depth_range
    from depth.inference import estimate_depth
    from depth.metrics import evaluate_depth_folder
    from depth.options import DepthOptions
    from experiments.results_7scenes import TableOptions, mesh_scores
    from experiments.select_checkpoint import heldout_scans

    results = {}
    for name, scan in heldout_scans(args.forward.parent / "scans").items():  # where select_checkpoint keeps them
        folder = args.out / name
        forward = folder / "estm_m2"
        if not forward.is_dir():
            shutil.copytree(args.forward / name / "estm_m2", forward)
        backward_scan = scan.subset(list(range(len(scan) - 1, -1, -1)))
        opts = DepthOptions(mode="estm", weights=args.weights, memory_size=2, depth_range=trained_depth_range(args.weights))
        estimate_depth(backward_scan, folder / "estm_rev", opts, resume=True)
        merge_by_confidence(forward, folder / "estm_rev", folder / "estm_fb", scan.names)
        results[name] = {}
        for row in ("estm_m2", "estm_rev", "estm_fb"):
            m = evaluate_depth_folder(folder / row, scan, 1e-3, 10.0)
            mesh = mesh_scores(scan, folder, TableOptions(mesh_row=row), log=lambda s: None)
            results[name][row] = {"abs_rel": m["abs_rel"], "a1": m["a1"], "flicker": m["flicker"],
                                  "prec": mesh["prec"], "recall": mesh["recall"], "fscore": mesh["fscore"]}
            print(f"{name} {row}: Abs Rel {m['abs_rel']:.4f}  flicker {m['flicker']:.4f}  "
                  f"mesh P {mesh['prec']:.3f} R {mesh['recall']:.3f} F {mesh['fscore']:.3f}", flush=True)
    for row in ("estm_m2", "estm_rev", "estm_fb"):
        print(f"{row}: mean Abs Rel {np.mean([r[row]['abs_rel'] for r in results.values()]):.4f}  "
              f"mean F {np.mean([r[row]['fscore'] for r in results.values()]):.3f}")
    (args.out / "summary.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
