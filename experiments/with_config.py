"""Write a copy of a checkpoint with configuration fields changed that add no weights, to score trained weights
under a changed forward pass (e.g. `refine_keeps_scale`) like any other checkpoint.

    python experiments/with_config.py runs/lite_v18/step_007513.pt --set refine_keeps_scale=true \
        --out runs/lite_v18/step_007513_keep.pt

The weights must load strictly into the changed network; the metadata is kept, with `config_changed` added.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint")
    p.add_argument("--set", action="append", required=True, metavar="FIELD=JSON", help="e.g. refine_keeps_scale=true")
    p.add_argument("--out", required=True, help="checkpoint file to write")
    args = p.parse_args(argv)

    from depth.checkpoint import build_model, load_checkpoint, save_checkpoint

    ck = load_checkpoint(args.checkpoint)
    changes = {k: json.loads(v) for k, v in (item.split("=", 1) for item in args.set)}
    ck = dataclasses.replace(ck, config=ck.config.replace(**changes))
    metadata = dict(ck.metadata, config_changed=changes)
    save_checkpoint(args.out, build_model(ck), ck.config, metadata=metadata, fp16=True)
    print(f"{args.out}: {args.checkpoint} with {changes}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
