"""`recon bench cli`: how long the command line takes to answer, against a bare Python start in the same run.

Each command runs `--repeats` times in a fresh interpreter, alternating with the baseline; the
best time counts (the machine is shared). `recon --help` must stay under a second: it builds no
command's options, so it imports none of torch, Open3D, trimesh or pycolmap.
"""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from apps.common import print_json

ROOT = Path(__file__).resolve().parents[2]
COMMANDS = {"python (baseline)": ["-c", "pass"], "recon --version": ["-m", "apps.cli", "--version"],
            "recon --help": ["-m", "apps.cli", "--help"], "recon eval --help": ["-m", "apps.cli", "eval", "--help"],
            "recon run --help": ["-m", "apps.cli", "run", "--help"]}
TARGET_S = {"recon --help": 1.0, "recon --version": 1.0}


def add_arguments(parser):
    parser.add_argument("--repeats", type=int, default=5, help="runs of each command (the best counts)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _seconds(args: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   check=True)
    return time.perf_counter() - start


def run(args) -> int:
    from rich.console import Console
    from rich.table import Table

    best = {name: float("inf") for name in COMMANDS}
    for _ in range(max(1, args.repeats)):
        for name, command in COMMANDS.items():
            best[name] = min(best[name], _seconds(command))
    base = best["python (baseline)"]
    rows = {name: {"seconds": round(s, 3), "x_python": round(s / base, 1), "target_s": TARGET_S.get(name),
                   "met": s < TARGET_S[name] if name in TARGET_S else None} for name, s in best.items()}
    if args.json:
        print_json(rows)
        return 0
    table = Table(title=f"command-line start-up (best of {args.repeats})")
    for column in ("command", "seconds", "x bare python", "target"):
        table.add_column(column)
    for name, r in rows.items():
        target = "" if r["target_s"] is None else f"< {r['target_s']:g} s: {'met' if r['met'] else 'NOT met'}"
        table.add_row(name, f"{r['seconds']:.3f}", f"{r['x_python']:.1f}", target)
    Console().print(table)
    return 0
