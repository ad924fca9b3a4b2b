"""`recon train`: train the EST depth network on scans with GT depth, or on streamed synthetic rooms."""
from __future__ import annotations

import argparse
import datetime as dt
import logging
import os
import time

from apps import options

log = logging.getLogger(__name__)

# Held-out synthetic rooms for validation clips: training streams use seeds far below.
VAL_SEED = 900_001
VAL_CLIPS = 8


def register(subparsers):
    subparsers.add_parser(
        "train", help="train the EST depth network on scans with ground-truth depth", arguments=add_arguments,
        description="Train on 5-frame clips (3 targets) with the multi-stage loss. Writes last.pt (resumable), "
                    "step_NNNNNN.pt at every validation, log.jsonl and model.pt to --out. Run under torchrun for "
                    "several GPUs.")


def _add_synthetic_arguments(p) -> None:
    p.add_argument("--synthetic", action="store_true",
                   help="train on an endless stream of synthetic rooms (clean and sensor-degraded clips, several "
                        "cameras and aspect ratios) instead of scans; needs --max-steps or a deadline")
    p.add_argument("--close-ups", action="store_true",
                   help="with --synthetic: every third clip from a walk close to walls and furniture, in rooms up to "
                        "12 m across (3-7 times the share of depth under 1 m)")
    p.add_argument("--clip-keyframe-distance", type=float, nargs="+", default=[0.2], metavar="D",
                   help="with --synthetic: pose distance between a clip's frames (default 0.2); MIN MAX: each room "
                        "draws its own, so the same depth shows a different parallax from room to room")


def add_arguments(p) -> None:
    p.add_argument("scans", nargs="*", help="training scans (any supported format with GT depth)")
    _add_synthetic_arguments(p)
    p.add_argument("--format", default="auto", help="input format of the scans (default: auto-detect)")
    options.add_selection(p)
    p.add_argument("--val", nargs="*", default=[], metavar="SCAN",
                   help="validation scans (default with --synthetic: 8 clips of held-out synthetic rooms)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder for checkpoints and logs")
    p.add_argument("--config", help="network config: lite, compact or paper (default: the config stored in the "
                                     "--init or --resume weights, else lite)")
    p.add_argument("--depth-range", nargs=2, type=float, default=None, metavar=("MIN", "MAX"),
                   help="planes of every synthetic clip, in metres, recorded in the weights (default: the range the "
                        "--init or --resume weights were trained on, else 0.25 10)")
    stop = p.add_argument_group("when to stop (the first that comes)")
    stop.add_argument("--max-steps", type=int, default=None, metavar="N", help="total optimiser steps")
    stop.add_argument("--deadline", default=None, metavar="HH:MM", help="UTC wall-clock time (next occurrence)")
    stop.add_argument("--minutes", type=float, default=None, help="wall-clock minutes from now")
    stop.add_argument("--epochs", type=int, default=10, help="passes over the scans (default 10)")
    _add_optimisation_arguments(p)
    data = p.add_argument_group("data")
    data.add_argument("--low-res", default="160x128", metavar="WxH",
                      help="clip size before --full-res-after (default 160x128; 'none' = always the config's)")
    data.add_argument("--full-res-after", type=float, default=0.7,
                      help="share of the horizon trained at --low-res (default 0.7)")
    data.add_argument("--frame-gap", type=int, default=1, help="scan frames between clip frames (default 1)")
    data.add_argument("--no-augment", action="store_true", help="disable photometric (and scale) augmentation")
    data.add_argument("--scale-jitter", type=float, default=0.0, metavar="J",
                      help="scale each clip's room by exp(U(-J, J)), depth and baselines together, so scale "
                           "must come from the poses (default 0: off)")
    data.add_argument("--reverse-share", type=float, default=0.0, metavar="P",
                      help="share of clips played backwards in time (default 0); the synthetic walks look where "
                           "they go, so without it the ESTM memory only ever sees a camera that advances")
    data.add_argument("--seed", type=int, default=0, help="seed of the model init and the synthetic stream")
    files = p.add_argument_group("checkpoints")
    files.add_argument("--val-every", type=int, default=100, metavar="STEPS", help="(default 100)")
    files.add_argument("--checkpoint-every", type=int, default=100, metavar="STEPS", help="last.pt (default 100)")
    files.add_argument("--log-every", type=int, default=10, metavar="STEPS", help="(default 10)")
    files.add_argument("--resume", default=None, metavar="CKPT", help="continue exactly from a last.pt")
    files.add_argument("--init", default=None, metavar="WEIGHTS",
                       help="start from these weights (a shipped name such as lite, or a file) with a fresh "
                            "optimiser and warm-up")
    files.add_argument("--backbone", default=None, metavar="PATH",
                       help="ResNet weights for the ContextNet encoder (resnet configs)")
    files.add_argument("--fp16-export", action="store_true", help="store model.pt weights as float16")
    run_ = p.add_argument_group("hardware")
    run_.add_argument("--amp", nargs="?", const="bf16", choices=("auto", "bf16", "fp16", "off"), default="auto",
                      help="mixed precision: auto (the default: bf16 where the GPU or CPU computes it in hardware, "
                           "e.g. AMX, else off), bf16 (when given alone), fp16 with a gradient scaler, or off")
    run_.add_argument("--compile", action="store_true", help="torch.compile the model")
    run_.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    run_.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    run_.add_argument("--workers", type=int, default=0,
                      help="data loader worker processes (with --synthetic each renders rooms of its own)")
    p.set_defaults(func=run)


def _add_optimisation_arguments(p) -> None:
    opt = p.add_argument_group("optimisation")
    opt.add_argument("--schedule", choices=("step", "cosine"), default="cosine",
                     help="lr: 'step' halves every --lr-halve-every epochs (paper); 'cosine' warms up, then decays "
                          "to --min-lr-ratio over the horizon (default cosine)")
    opt.add_argument("--lr", type=float, default=5e-4, help="peak learning rate (default 5e-4; paper 4e-5)")
    opt.add_argument("--min-lr-ratio", type=float, default=0.05, help="cosine: final lr / lr (default 0.05)")
    opt.add_argument("--warmup-steps", type=int, default=50, help="cosine: warm-up steps (default 50)")
    opt.add_argument("--lr-halve-every", type=int, default=2, metavar="EPOCHS", help="step schedule (default 2)")
    opt.add_argument("--encoder-lr-scale", type=float, default=0.1,
                     help="lr factor of the pretrained encoder's trainable blocks (default 0.1)")
    opt.add_argument("--weight-decay", type=float, default=1e-5)
    opt.add_argument("--grad-clip", type=float, default=5.0, help="gradient-norm clip (default 5; 0 = off)")
    opt.add_argument("--loss", choices=("l1", "log_l1"), default="l1",
                     help="per-pixel error: l1 in metres (paper; the default: lower held-out Abs Rel than log-L1, "
                          "docs/model_card.md lite_v15) or l1 of log depth")
    opt.add_argument("--grad-weight", type=float, default=0.0, metavar="W",
                     help="add W x the multi-scale gradient of the log-depth error of the full-resolution "
                          "output, which rewards edges where the ground truth has them (default 0: off)")
    opt.add_argument("--near-factor", type=float, default=1.0, metavar="F",
                     help="weigh depth that is too near F times as much as depth too far: fusion turns it into "
                          "surfaces in front of the true ones, which the mesh evaluation never culls (default 1: "
                          "symmetric)")
    opt.add_argument("--near-margin", type=float, default=0.0, metavar="M",
                     help="apply --near-factor only to the part of a near error beyond the fraction M of the "
                          "true depth, so small errors and the map's scale keep the symmetric loss (default 0)")
    opt.add_argument("--hold-statistics", action="store_true",
                     help="every BatchNorm normalises with its running statistics in training as at inference, "
                          "so a batch-1 fine-tune does not drag them towards its last clip (default: off)")
    opt.add_argument("--batch-size", type=int, default=1)


def deadline_time(args: argparse.Namespace) -> float | None:
    """--deadline HH:MM (UTC, next occurrence) and/or --minutes -> the earlier, as time.time() seconds."""
    from recon.errors import ReconError

    times = []
    if args.minutes is not None:
        times.append(time.time() + 60 * args.minutes)
    if args.deadline:
        try:
            hh, mm = (int(x) for x in args.deadline.split(":"))
            now = dt.datetime.now(dt.timezone.utc)
            when = now.replace(hour=hh, minute=mm, second=0, microsecond=0)
        except ValueError:
            raise ReconError(f"--deadline: expected HH:MM (UTC), got {args.deadline!r}") from None
        times.append((when + dt.timedelta(days=1) if when <= now else when).timestamp())
    return min(times) if times else None


def _size(text: str) -> tuple[int, int] | None:
    from apps.common import parse_size

    return None if text.lower() == "none" else parse_size(text, "--low-res", multiple=32)


def stream_seed(args: argparse.Namespace, rank: int) -> int:
    """The synthetic stream's seed: --seed for a fresh run; for a resumed or initialised one, a seed drawn
    from (--seed, rank, the step it starts at), so a continued run sees new rooms, not the first ones again."""
    import numpy as np

    from depth.checkpoint import load_checkpoint

    step = 0
    if args.resume:
        step = int(load_checkpoint(args.resume).training.get("step", 0))
    elif args.init:
        step = int(load_checkpoint(args.init).metadata.get("steps", 0))
    if step == 0 and rank == 0:
        return args.seed
    return int(np.random.SeedSequence([args.seed, rank, step]).generate_state(1)[0] & 0x3FFFFFFF)


def synthetic_depth_range(args: argparse.Namespace) -> tuple[float, float]:
    """--depth-range, else the range the starting weights were trained on (a plane index means a depth only
    within it, docs/depth.md), else 0.25-10 m."""
    from depth.checkpoint import trained_depth_range

    if args.depth_range is not None:
        return tuple(args.depth_range)
    return trained_depth_range(args.init or args.resume) or (0.25, 10.0)


def training_stream(seed: int, depth_range: tuple[float, float], close_ups: bool, shard: int,
                    keyframe_distance: float | tuple[float, float] = 0.2):
    """Loader worker `shard`'s synthetic stream: shard 0 (also the only one without workers) draws from `seed`
    itself, every other worker from a seed of its own, so workers render different rooms."""
    import numpy as np

    from recon.synthetic import iter_training_mix

    if shard:
        seed = int(np.random.SeedSequence([seed, 1 << 20, shard]).generate_state(1)[0] & 0x3FFFFFFF)
    return iter_training_mix(seed, depth_range, keyframe_distance, close_ups=close_ups)


def _data(args: argparse.Namespace, cfg):
    from depth.data import ClipDataset, ClipOptions, StreamingClips
    from recon.errors import ReconError

    clip = ClipOptions(frame_gap=args.frame_gap, width=cfg.image_width, height=cfg.image_height,
                       augment=not args.no_augment, scale_jitter=args.scale_jitter,
                       reverse_share=args.reverse_share)
    plain = ClipOptions(**{**clip.__dict__, "augment": False})

    def scans(paths):
        from recon.readers import open_scan

        return [open_scan(p, args.format).select(args.start, args.stride, args.max_frames) for p in paths]

    if args.synthetic == bool(args.scans):
        raise ReconError("recon train: give training scans or --synthetic (one of the two)")
    if not 0 <= args.reverse_share <= 1:
        raise ReconError(f"--reverse-share is a share of clips, in [0, 1]; got {args.reverse_share}")
    if not 1 <= len(args.clip_keyframe_distance) <= 2:
        raise ReconError("--clip-keyframe-distance takes one distance or a MIN MAX range")
    if not args.synthetic:
        val = ClipDataset(scans(args.val), plain) if args.val else None
        return ClipDataset(scans(args.scans), clip, seed=args.seed), val
    import functools
    import itertools

    from recon.synthetic import iter_training_mix

    rank = int(os.environ.get("RANK", "0"))
    depth_range = synthetic_depth_range(args)
    distances = args.clip_keyframe_distance
    distance = distances[0] if len(distances) == 1 else tuple(distances)
    stream = functools.partial(training_stream, stream_seed(args, rank), depth_range, args.close_ups,
                               keyframe_distance=distance)
    if args.val:
        val = ClipDataset(scans(args.val), plain)
    else:
        held_out = iter_training_mix(VAL_SEED, depth_range, clips_per_scene=2)
        val = ClipDataset(list(itertools.islice(held_out, VAL_CLIPS)), plain)
    return StreamingClips(stream, clip, seed=args.seed + rank, describe={
        "train": "recon.synthetic.iter_training_mix", "train_seed": stream_seed(args, rank), "val_seed": VAL_SEED,
        "depth_range": list(depth_range), **({"close_ups": True} if args.close_ups else {}),
        **({"clip_keyframe_distance": args.clip_keyframe_distance} if args.clip_keyframe_distance != [0.2] else {}),
        **({"workers": args.workers} if args.workers > 1 else {})}), val


def _config(args: argparse.Namespace):
    """The named --config, else the one the starting weights were trained with (so weights trained under a
    changed config, e.g. `refine_keeps_scale`, train on as they are), else `lite`."""
    from depth.checkpoint import load_checkpoint
    from depth.config import get_config

    start = args.init or args.resume
    if args.config is None and start is not None:
        return load_checkpoint(start).config
    return get_config(args.config or "lite")


def run(args: argparse.Namespace) -> int:
    import torch

    from depth.train import TrainOptions, train
    from recon.errors import ReconError

    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = _config(args)
    deadline = deadline_time(args)
    if args.synthetic and args.max_steps is None and deadline is None:
        raise ReconError("recon train --synthetic: the stream is endless, pass --max-steps, --deadline or --minutes")
    train_data, val_data = _data(args, cfg)
    opts = TrainOptions(
        config=cfg.name, epochs=args.epochs, max_steps=args.max_steps, deadline=deadline,
        batch_size=args.batch_size, lr=args.lr, weight_decay=args.weight_decay, schedule=args.schedule,
        lr_halve_every=args.lr_halve_every, warmup_steps=args.warmup_steps, min_lr_ratio=args.min_lr_ratio,
        encoder_lr_scale=args.encoder_lr_scale, grad_clip=args.grad_clip or None, loss=args.loss,
        grad_weight=args.grad_weight, near_factor=args.near_factor, near_margin=args.near_margin,
        hold_statistics=args.hold_statistics,
        low_res=_size(args.low_res), full_res_after=args.full_res_after, val_every=args.val_every,
        checkpoint_every=args.checkpoint_every, log_every=args.log_every,
        amp=None if args.amp == "off" else args.amp, compile=args.compile, device=args.device,
        num_workers=args.workers, seed=args.seed, init=args.init, backbone=args.backbone, fp16_export=args.fp16_export)
    log.info("training %s on %s (%d validation clips)", cfg.name,
             "synthetic rooms" if args.synthetic else f"{len(train_data)} clips", len(val_data) if val_data else 0)
    result = train(train_data, args.out, opts, val_data=val_data, resume=args.resume, model_config=cfg)
    last = f", last loss {result.losses[-1]:.4f}" if result.losses else ""
    print(f"trained {result.steps} steps ({result.epochs} epochs){last}; weights {result.model_path}")
    return 0
