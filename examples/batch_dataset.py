"""Run every scan of a dataset folder and print the summary's means (local process pool or Ray).

    python examples/batch_dataset.py DATASET_DIR OUT_DIR [--engine ray]
"""
import argparse

from apps.batch import run_batch
from apps.pipeline import InputConfig, RunConfig


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset")
    p.add_argument("out")
    p.add_argument("--engine", choices=["local", "ray"], default="local")
    p.add_argument("--workers", type=int, default=1)
    args = p.parse_args()
    summary = run_batch(args.dataset, args.out, RunConfig(InputConfig(), ""),
                        engine=args.engine, workers=args.workers,
                        on_result=lambda r: print(r["name"], r["status"], r.get("error", "")))
    print(summary["counts"], {k: v for k, v in summary["mean"].items() if v is not None})


if __name__ == "__main__":
    main()
