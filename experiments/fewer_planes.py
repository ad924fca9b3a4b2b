"""Carry trained weights to a network with fewer depth planes, as the start of a fine-tune.

    python experiments/fewer_planes.py lite-preview --planes 32 --out runs/lite32_init.pt

Only three layers know the plane count: the context decoder's last two convolutions (one output channel
per plane, and the skip convolution reads them back) and the refinement's first convolution (context and
plane logits, one channel each per plane). Every other weight is copied. A layer that writes one channel per
plane gets the old channels linearly interpolated at the new planes' positions (the planes keep their range
and spacing, so new plane j sits at old index j * (D - 1) / (N - 1)); a layer that reads them gets the
transpose of that interpolation, so it sums the same signal it summed before. BatchNorm statistics of
plane channels are interpolated like the channels. The metadata is kept, with `planes_changed` added.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def interpolation(old: int, new: int) -> torch.Tensor:
    """(new, old) matrix: row j linearly interpolates `old` plane values at new plane j's position."""
    position = torch.linspace(0.0, old - 1, new, dtype=torch.float64)
    below = position.floor().long().clamp(max=old - 2)
    frac = position - below
    m = torch.zeros(new, old, dtype=torch.float64)
    m[torch.arange(new), below] = 1 - frac
    m[torch.arange(new), below + 1] = frac
    return m


def _mix(t: torch.Tensor, m: torch.Tensor, axis: int, start: int = 0) -> torch.Tensor:
    """`t` with its block of m.shape[1] entries at `start` on `axis` replaced by m @ that block."""
    n = m.shape[1]
    block = torch.tensordot(m, t.narrow(axis, start, n).movedim(axis, 0).double(), dims=([1], [0]))
    rest = t.shape[axis] - start - n
    return torch.cat([t.narrow(axis, 0, start), block.movedim(0, axis).to(t.dtype), t.narrow(axis, start + n, rest)],
                     axis)


def fewer_planes(state: dict[str, torch.Tensor], old: int, new: int) -> dict[str, torch.Tensor]:
    """A state dict for `new` planes from one trained with `old` (see the module docstring)."""
    writes = interpolation(old, new)  # (new, old): a new plane channel from the old ones
    reads = interpolation(new, old).T  # (new, old): B^T, where B (old, new) rebuilds old channels from new ones
    state = dict(state)
    last = max(int(k.split(".")[2]) for k in state if k.startswith("context.up_convs."))
    for layer in (f"context.up_convs.{last}.", f"context.skip_convs.{last}."):
        for key in [k for k in state if k.startswith(layer) and state[k].ndim >= 1]:
            state[key] = _mix(state[key], writes, 0)
    skip = f"context.skip_convs.{last}.0.weight"
    state[skip] = _mix(state[skip], reads, 1)
    refine = "refine.stage1_in.0.weight"  # reads cat([context, logits]): two blocks of planes
    state[refine] = _mix(_mix(state[refine], reads, 1, old), reads, 1, 0)
    return state


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint")
    p.add_argument("--planes", type=int, required=True)
    p.add_argument("--out", required=True, help="checkpoint file to write")
    args = p.parse_args(argv)

    from depth.checkpoint import build_model, load_checkpoint, save_checkpoint

    ck = load_checkpoint(args.checkpoint)
    old = ck.config.num_planes
    if not 2 <= args.planes < old:
        raise SystemExit(f"--planes must be between 2 and {old - 1}")
    ck = dataclasses.replace(ck, config=ck.config.replace(num_planes=args.planes),
                             state_dict=fewer_planes(ck.state_dict, old, args.planes))
    metadata = dict(ck.metadata, planes_changed={"from": old, "to": args.planes, "weights": args.checkpoint})
    save_checkpoint(args.out, build_model(ck), ck.config, metadata=metadata)
    print(f"{args.out}: {args.checkpoint} carried from {old} to {args.planes} planes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
