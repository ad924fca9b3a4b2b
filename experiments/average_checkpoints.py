"""Average the weights of several checkpoints of one network into one checkpoint file, to score it like any other.

    python experiments/average_checkpoints.py runs/lite_v13/step_005200.pt runs/lite_v13/step_005300.pt \
        runs/lite_v13/step_005336.pt --out runs/lite_v13/mean_005200_005336.pt
    python experiments/average_checkpoints.py runs/lite_h13 runs/lite_h14 --last 4 --out runs/soup.pt

A run folder stands for its last `--last` step files (`step_NNNNNN.pt`, by step), the ends of sibling runs
that each session screens, so a fresh machine needs no hand-made list.

Late checkpoints of a CPU run at batch size 1 differ in held-out error from one to the next; their mean
is one network as fast as each. Measured on `runs/lite_v13` (docs/model_card.md): no gain over the last
checkpoint once the learning rate has decayed. Sibling fine-tunes of one parent (different seeds and starts,
each off the held-out optimum in its own direction) average better: the mean of `runs/compact_k20` to `k23`
beat each of them and shipped as `compact-preview` on 2026-12-05 (docs/model_card.md).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def expand_runs(paths: list[str], last: int) -> list[str]:
    """Checkpoint files as given, each run folder replaced by its `last` highest-step `step_*.pt` files."""
    files = []
    for path in map(Path, paths):
        if not path.is_dir():
            files.append(str(path))
            continue
        steps = sorted(path.glob("step_*.pt"))[-last:]
        if not steps:
            raise SystemExit(f"average_checkpoints: no step_*.pt in {path}")
        files.extend(map(str, steps))
    return files


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoints", nargs="+",
                   help="checkpoints of one network, or run folders; the last one's metadata is kept")
    p.add_argument("--last", type=int, default=4, help="step files taken from each run folder (its last ones)")
    p.add_argument("--out", required=True, help="checkpoint file to write")
    args = p.parse_args(argv)

    from depth.checkpoint import average_checkpoints, build_model, save_checkpoint

    files = expand_runs(args.checkpoints, args.last)
    mean = average_checkpoints(files)
    save_checkpoint(args.out, build_model(mean), mean.config, metadata=mean.metadata, fp16=True)
    print(f"{args.out}: mean of {len(files)} checkpoints: {' '.join(files)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
