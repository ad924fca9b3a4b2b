"""Run every scan of a dataset folder and print the summary's means (local process pool or Ray).

    python examples/batch_dataset.py DATASET_DIR OUT_DIR [--engine ray] [--mode estm|planesweep|...]
"""
import argparse

from apps.batch import run_batch
from apps.pipeline import InputConfig, RunConfig
from depth.options import DepthOptions


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset")
    p.add_argument("out")
    p.add_argument("--engine", choices=["local", "ray"], default="local")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--mode", default="estm", help="depth: estm (default, the shipped network) ... planesweep")
    args = p.parse_args()
    summary = run_batch(args.dataset, args.out, RunConfig(InputConfig(), "", depth=DepthOptions(mode=args.mode)),
                        engine=args.engine, workers=args.workers,
                        on_result=lambda r: print(r["name"], r["status"], r.get("error", "")))
    print(summary["counts"], {k: v for k, v in summary["mean"].items() if v is not None})


if __name__ == "__main__":
    main()
