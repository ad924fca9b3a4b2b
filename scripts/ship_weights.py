"""Write a shipped weights file (depth/weights/compact.pt or compact-cpu-preview.pt) from a selected checkpoint.

    python scripts/ship_weights.py runs/compact_cpu/step_001200.pt --run runs/compact_cpu \
        --selection runs/select/summary.json

Refuses unless the checkpoint's ESTM beats the plane sweep on the held-out synthetic scans of
the selection summary (mean Abs Rel and mean delta<1.25). The file is the default `compact`
(what `recon run` uses) only when ESTM's meshes also beat the plane sweep's on every held-out
scan of the summary (synthetic rooms and ICL-NUIM; mesh F-score against the GT-depth fusion);
otherwise it is `compact-cpu-preview`, used on request. Stores float16 weights (no optimiser
state) with metadata: data, steps, hardware, wall time, clip validation, held-out figures.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint")
    p.add_argument("--run", required=True, help="training run folder (log.jsonl)")
    p.add_argument("--selection", required=True, help="summary.json of scripts/select_checkpoint.py")
    p.add_argument("--out", default=None, help="output file (default: by the rules above)")
    args = p.parse_args(argv)

    from depth.checkpoint import build_model, load_checkpoint, save_checkpoint
    from depth.config import COMPACT

    ck = load_checkpoint(args.checkpoint, expected=COMPACT)
    sel = json.loads(Path(args.selection).read_text())
    key = f"{Path(args.checkpoint).stem}:estm_m2"
    synth = [n for n in sel["planesweep"] if n.startswith("synthetic")]
    if key not in sel or not all(n in sel[key] for n in synth):
        raise SystemExit(f"{args.selection}: no held-out figures for {key}")

    def mean(row, metric):
        return statistics.mean(sel[row][n][metric] for n in synth)

    est = {"abs_rel": mean(key, "abs_rel"), "a1": mean(key, "a1")}
    ps = {"abs_rel": mean("planesweep", "abs_rel"), "a1": mean("planesweep", "a1")}
    print(f"held-out synthetic ({', '.join(synth)}): ESTM abs_rel {est['abs_rel']:.4f} a1 {est['a1']:.3f}; "
          f"plane sweep abs_rel {ps['abs_rel']:.4f} a1 {ps['a1']:.3f}")
    if not (est["abs_rel"] < ps["abs_rel"] and est["a1"] > ps["a1"]):
        print("not shipped: ESTM does not beat the plane sweep on the held-out synthetic scans")
        return 1
    heldout = [n for n in sel["planesweep"] if n in sel[key]]
    mesh_f = {n: (sel[key][n]["mesh_fscore"], sel["planesweep"][n]["mesh_fscore"]) for n in heldout}
    as_default = all(e > p for e, p in mesh_f.values())
    print("held-out meshes, F-score ESTM / plane sweep: "
          + ", ".join(f"{n} {e:.3f} / {p:.3f}" for n, (e, p) in mesh_f.items()) + " -> "
          + ("the default `compact`" if as_default else "a preview (`compact-cpu-preview`), not the default"))
    out_path = Path(args.out) if args.out else ROOT / "depth" / "weights" / (
        "compact.pt" if as_default else "compact-cpu-preview.pt")
    recs = [json.loads(x) for x in (Path(args.run) / "log.jsonl").read_text().splitlines() if x.strip()]
    train = [r for r in recs if r["kind"] == "train"]
    val = [r for r in recs if r["kind"] == "val"]
    meta = dict(ck.metadata)
    meta.update({
        "validation": {"clips": [v for v in val if v["step"] == meta.get("steps")] or val[-1:],
                       "heldout_scans": {k: v for k, v in sel.items() if k in (key, "planesweep")
                                         or k.endswith("_baselines:independent")},
                       "selection": "lowest clip-validation Abs Rel on held-out synthetic rooms; "
                                    "never 7-Scenes"},
        "wall_time_s": round(train[-1]["trained_s"], 1) if train else None,
        "clips_per_s_cpu": {"median": statistics.median(r["clips_per_s"] for r in train)} if train else None,
        "source_checkpoint": str(args.checkpoint),
    })
    out = save_checkpoint(out_path, build_model(ck), COMPACT, meta, fp16=True)
    print(f"shipped {out} ({out.stat().st_size / 1e6:.2f} MB, float16)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
