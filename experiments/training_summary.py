"""Summarise a training run's log.jsonl (scripts/train_default_weights.py) as Markdown for the model card.

    python experiments/training_summary.py runs/compact_cpu [--every 100]
"""
from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run")
    p.add_argument("--every", type=int, default=100, help="steps per row of the loss curve")
    args = p.parse_args(argv)
    recs = [json.loads(line) for line in (Path(args.run) / "log.jsonl").read_text().splitlines() if line.strip()]
    train = [r for r in recs if r["kind"] == "train"]
    val = {r["step"]: r for r in recs if r["kind"] == "val"}
    if not train:
        print("no training records")
        return 1
    by_size: dict[str, list[float]] = {}
    for r in train:
        by_size.setdefault("x".join(map(str, r.get("size", ["?", "?"]))), []).append(r["clips_per_s"])
    last = train[-1]
    print(f"steps {last['step']}, training time {last['trained_s'] / 60:.1f} min (excluding validation), "
          f"mean load average {statistics.mean(r['load'] for r in train):.1f}")
    for size, rates in by_size.items():
        print(f"- clips/s at {size}: median {statistics.median(rates):.3f} over {len(rates) * train[0]['step']} steps")
    print()
    print("| steps | mean training loss | lr at end | validation loss | validation Abs Rel (D3) |")
    print("|---|---|---|---|---|")
    lo = 0
    for hi in range(args.every, last["step"] + args.every, args.every):
        window = [r for r in train if lo < r["step"] <= hi]
        if window:
            v = val.get(hi) or val.get(window[-1]["step"])
            vtxt = f"{v['loss']:.3f} | {v['abs_rel']:.4f}" if v else "- | -"
            print(f"| {lo + 1}-{window[-1]['step']} | {statistics.mean(r['loss'] for r in window):.3f} | "
                  f"{window[-1]['lr']:.1e} | {vtxt} |")
        lo = hi
    final = max(val)
    if final > last["step"] - (last["step"] % args.every or args.every):
        print(f"\nfinal validation (step {final}): loss {val[final]['loss']:.3f}, Abs Rel {val[final]['abs_rel']:.4f}")
    if 0 in val:
        print(f"\nvalidation before training (random weights): loss {val[0]['loss']:.3f}, Abs Rel {val[0]['abs_rel']:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
