"""Summarise training runs' log.jsonl (`recon train`) as Markdown for the model card; several runs
in the order they continued each other make one cumulative log.

    python experiments/training_summary.py runs/lite_v2 runs/lite_v3 [--every 200]
"""
from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path


def read_log(run: Path) -> list[dict]:
    """The run's records; a resumed run logs its steps again from the checkpoint: the later record wins."""
    recs = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines() if line.strip()]
    latest = {(r["kind"], r["step"]): r for r in recs}
    return sorted(latest.values(), key=lambda r: (r["step"], r["kind"]))


def throughput(train: list[dict]) -> dict[str, list[float]]:
    """Clips per second between consecutive training records, by clip size."""
    rates: dict[str, list[float]] = {}
    for a, b in zip(train, train[1:]):
        if b["trained_s"] > a["trained_s"] and b["step"] > a["step"]:
            size = "x".join(map(str, b.get("size", ["?", "?"])[::-1]))
            rates.setdefault(size, []).append((b["step"] - a["step"]) / (b["trained_s"] - a["trained_s"]))
    return rates


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+")
    p.add_argument("--every", type=int, default=200, help="steps per row of the loss curve")
    args = p.parse_args(argv)
    train, val = [], {}
    for run in args.runs:
        recs = read_log(Path(run))
        run_train = [r for r in recs if r["kind"] == "train"]
        if run_train:
            rates = throughput(run_train)
            print(f"{run}: steps {run_train[0]['step']}-{run_train[-1]['step']}, "
                  f"mean load average {statistics.mean(r['load'] for r in run_train):.1f}; clips/s "
                  + ", ".join(f"{s} {statistics.median(v):.3f}" for s, v in rates.items()))
        start = run_train[0]["step"] if run_train else float("inf")  # a continuation replaces the steps it redid
        train = [r for r in train if r["step"] < start] + run_train
        val = {s: v for s, v in val.items() if s < start} | {r["step"]: r for r in recs if r["kind"] == "val"}
    if not train:
        print("no training records")
        return 1
    print("\n| steps | mean training loss | lr at end | validation loss | validation Abs Rel (D3) |")
    print("|---|---|---|---|---|")
    if 0 in val:
        print(f"| 0 (before training) | - | - | {val[0]['loss']:.3f} | {val[0]['abs_rel']:.4f} |")
    lo = train[0]["step"] - train[0]["step"] % args.every
    for hi in range(lo + args.every, train[-1]["step"] + args.every, args.every):
        window = [r for r in train if lo < r["step"] <= hi]
        if window:
            v = val.get(max((s for s in val if lo < s <= hi), default=-1))
            vtxt = f"{v['loss']:.3f} | {v['abs_rel']:.4f}" if v else "- | -"
            print(f"| {lo + 1}-{window[-1]['step']} | {statistics.mean(r['loss'] for r in window):.3f} | "
                  f"{window[-1]['lr']:.1e} | {vtxt} |")
        lo = hi
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
