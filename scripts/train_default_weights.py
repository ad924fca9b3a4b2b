"""Train the shipped `compact` depth weights on streamed synthetic rooms, against a wall-clock deadline.

Why a script beside `recon train`: a short CPU budget wants a schedule tied to the time left
(warm-up, then cosine decay of the learning rate until the deadline), a fixed depth range shared
with inference on real video, a mix of clean and sensor-degraded clips, and a weights file per
validation so a checkpoint can be picked afterwards on held-out synthetic rooms (never on 7-Scenes).
The loop reuses depth.train (loss, validation) and depth.checkpoint (file format).

    OMP_NUM_THREADS=1 python scripts/train_default_weights.py --out runs/compact_cpu --deadline 00:25

Writes to --out: train.log (text), log.jsonl (one JSON object per logged step / validation),
last.pt (resumable), step_NNNNNN.pt (weights at each validation).
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import itertools
import json
import logging
import math
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from depth.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402
from depth.config import get_config  # noqa: E402
from depth.data import ClipDataset, ClipOptions, make_clip  # noqa: E402
from depth.model import ESTNet  # noqa: E402
from depth.train import clip_loss, validate  # noqa: E402

log = logging.getLogger("train_default_weights")

# The depth range of every clip (training and validation) and the default for real video:
# a fixed indoor range, so the planes mean the same thing at training and at inference.
DEPTH_RANGE = (0.25, 6.0)
VAL_SEED = 900_001  # held-out rooms: training streams use seeds 0..99
VAL_CLIPS = 8


def with_range(scan, depth_range=DEPTH_RANGE):
    scan.metadata = dataclasses.replace(scan.metadata, depth_range=tuple(depth_range))
    return scan


def training_stream(seed: int, width: int, height: int, keyframe_distance: float = 0.2):
    """Alternate clean clips and clips with realistic sensor effects (noise, blur, exposure, JPEG).

    Keyframes 0.2 apart (pose distance) rather than the stream's default 0.1: neighbours then have
    about the baseline inference picks for sources (0.15 m), so the matching volume carries signal.
    """
    from recon.synthetic import SensorEffects, iter_training_scans

    clean = iter_training_scans(seed=seed, width=width, height=height, keyframe_distance=keyframe_distance)
    noisy = iter_training_scans(seed=seed + 50, width=width, height=height, effects=SensorEffects.realistic(),
                                keyframe_distance=keyframe_distance)
    for a, b in zip(clean, noisy):
        yield with_range(a)
        yield with_range(b)


def validation_scans(width: int, height: int, n: int = VAL_CLIPS):
    """Held-out synthetic clips: 2 clips from each of n/2 rooms, half with sensor effects."""
    from recon.synthetic import SensorEffects, iter_training_scans

    clean = iter_training_scans(seed=VAL_SEED, width=width, height=height, clips_per_scene=2, keyframe_distance=0.2)
    noisy = iter_training_scans(seed=VAL_SEED + 1, width=width, height=height, clips_per_scene=2,
                                effects=SensorEffects.realistic(), keyframe_distance=0.2)
    scans = list(itertools.islice(clean, n // 2)) + list(itertools.islice(noisy, n - n // 2))
    return [with_range(s) for s in scans]


def lr_at(elapsed: float, total: float, step: int, opts) -> float:
    warm = min(1.0, (step + 1) / opts.warmup_steps)
    frac = min(max(elapsed / max(total, 1.0), 0.0), 1.0)
    return opts.lr * warm * (opts.min_lr_ratio + (1 - opts.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * frac)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True)
    p.add_argument("--deadline", required=True, help="UTC time HH:MM (next occurrence) to stop training")
    p.add_argument("--config", default="compact")
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--min-lr-ratio", type=float, default=0.05)
    p.add_argument("--warmup-steps", type=int, default=50)
    p.add_argument("--weight-decay", type=float, default=1e-5)
    p.add_argument("--grad-clip", type=float, default=5.0)
    p.add_argument("--val-every", type=int, default=100)
    p.add_argument("--log-every", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", default=None, help="a last.pt with optimiser state: continue exactly")
    p.add_argument("--init", default=None, metavar="WEIGHTS",
                   help="start from these weights (e.g. compact, the shipped file) with a fresh optimiser")
    p.add_argument("--max-steps", type=int, default=None)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--low-res", default="160x128", help="clip size for the first part of training (the network "
                   "is size-agnostic; low resolution is ~4x cheaper per clip)")
    p.add_argument("--full-res-after", type=float, default=0.7,
                   help="share of the time budget after which clips switch to the config's size")
    args = p.parse_args(argv)

    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s",
                        handlers=[logging.FileHandler(out / "train.log"), logging.StreamHandler()])
    now = dt.datetime.now(dt.timezone.utc)
    hh, mm = (int(x) for x in args.deadline.split(":"))
    deadline = now.replace(hour=hh, minute=mm, second=0, microsecond=0)
    if deadline <= now:
        deadline += dt.timedelta(days=1)
    t_end = time.time() + (deadline - now).total_seconds()

    if args.init and args.resume:
        p.error("--init and --resume exclude each other")
    cfg = get_config(args.config)
    torch.manual_seed(args.seed)
    model = ESTNet(cfg).train()
    opt = torch.optim.Adam(model.parameters(), lr=args.lr, betas=(0.9, 0.999), weight_decay=args.weight_decay)
    step, trained_s, clips_seen = 0, 0.0, 0
    earlier_seeds: list[int] = []
    if args.init:
        ck = load_checkpoint(args.init, expected=cfg)
        model.load_state_dict({k: v.float() for k, v in ck.state_dict.items()})
        step, clips_seen = int(ck.metadata.get("steps", 0)), int(ck.metadata.get("clips_seen", 0))
        earlier_seeds = list(ck.metadata.get("data", {}).get("train_seeds", []))
        log.info("initialised from %s (trained %d steps), fresh optimiser", args.init, step)
    if args.resume:
        ck = load_checkpoint(args.resume, expected=cfg)
        model.load_state_dict(ck.state_dict)
        opt.load_state_dict(ck.training["optimizer"])
        step, trained_s = int(ck.training["step"]), float(ck.training.get("trained_s", 0.0))
        clips_seen = int(ck.training.get("clips_seen", step))
        earlier_seeds = list(ck.metadata.get("data", {}).get("train_seeds", []))
        log.info("resumed from %s at step %d", args.resume, step)
    warm_from = step if args.init else 0  # a fresh optimiser warms up again
    t_start = time.time()
    prior_s = trained_s
    total = prior_s + (t_end - t_start)  # the lr schedule runs on wall time up to the deadline

    low_w, low_h = (int(x) for x in args.low_res.split("x"))
    clip_low = ClipOptions(width=low_w, height=low_h, augment=True)
    clip_full = ClipOptions(width=cfg.image_width, height=cfg.image_height, augment=True)
    val_data = ClipDataset(validation_scans(cfg.image_width, cfg.image_height),
                           ClipOptions(width=cfg.image_width, height=cfg.image_height, augment=False))
    val_loader = torch.utils.data.DataLoader(val_data, 1)
    log.info("config %s, %d parameters, %d validation clips, depth range %s, deadline %s UTC",
             cfg.name, sum(p.numel() for p in model.parameters()), len(val_data), DEPTH_RANGE, deadline)

    gen = torch.Generator().manual_seed(args.seed + step)
    stream_seed = args.seed + 1 + step // 1000
    stream = training_stream(stream_seed, cfg.image_width, cfg.image_height)
    size_switched = False
    jsonl = open(out / "log.jsonl", "a")

    def record(obj):
        jsonl.write(json.dumps(obj) + "\n")
        jsonl.flush()

    meta_base = {"data": {"train": "recon.synthetic.iter_training_scans, clean + SensorEffects.realistic() "
                                   "alternating, 5-keyframe clips (keyframe distance 0.2)",
                          "train_seeds": sorted(set(earlier_seeds) | {stream_seed, stream_seed + 50}),
                          "val_seeds": [VAL_SEED, VAL_SEED + 1],
                          "depth_range": list(DEPTH_RANGE)},
                 "hardware": f"CPU, {args.threads} thread(s), shared 2-core machine", "options": vars(args)}

    def checkpoint(name, weights_only=False, validation=None):
        meta = {**meta_base, "steps": step, "clips_seen": clips_seen, "trained_s": round(trained_s, 1),
                "validation": validation, "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
        training = None if weights_only else {"optimizer": opt.state_dict(), "step": step, "trained_s": trained_s,
                                              "clips_seen": clips_seen}
        save_checkpoint(out / name, model, cfg, meta, training)

    def run_val():
        t0 = time.time()
        v = validate(model, val_loader, torch.device("cpu"))
        v = {"kind": "val", "step": step, "trained_s": round(trained_s, 1), **v, "val_s": round(time.time() - t0, 1)}
        record(v)
        log.info("VAL step %d loss %.4f abs_rel %.4f (%.0f s)", step, v["loss"], v["abs_rel"], v["val_s"])
        checkpoint(f"step_{step:06d}.pt", weights_only=True, validation=v)
        checkpoint("last.pt")

    if step == 0:
        run_val()
    window_loss, window_t, data_s = [], time.time(), 0.0
    while time.time() < t_end and (args.max_steps is None or step < args.max_steps):
        t0 = time.time()
        scan = next(stream)
        scan.validate()
        full = (prior_s + time.time() - t_start) >= args.full_res_after * total
        if full and not size_switched:
            size_switched = True
            log.info("step %d: switching training clips to %dx%d", step, cfg.image_width, cfg.image_height)
            record({"kind": "event", "step": step, "event": "full resolution"})
        batch = make_clip(scan, 0, clip_full if full else clip_low, gen)
        batch = {k: v.unsqueeze(0) for k, v in batch.items()}
        t1 = time.time()
        data_s += t1 - t0
        lr = lr_at(prior_s + time.time() - t_start, total, step - warm_from, args)
        for g in opt.param_groups:
            g["lr"] = lr
        loss, per_stage, _ = clip_loss(model, batch)
        if not math.isfinite(float(loss.detach())):
            log.warning("step %d: non-finite loss, clip skipped", step)
            continue
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gnorm = float(torch.nn.utils.clip_grad_norm_(model.parameters(), args.grad_clip))
        opt.step()
        step += 1
        clips_seen += 1
        trained_s += time.time() - t0
        window_loss.append(float(loss.detach()))
        if step % args.log_every == 0:
            el = time.time() - window_t
            rec = {"kind": "train", "step": step, "loss": sum(window_loss) / len(window_loss),
                   "stages": [round(x, 4) for x in per_stage], "lr": lr, "grad_norm": round(gnorm, 3),
                   "clips_per_s": round(len(window_loss) / el, 3), "data_share": round(data_s / el, 3),
                   "trained_s": round(trained_s, 1), "load": os.getloadavg()[0],
                   "size": [batch["images"].shape[-1], batch["images"].shape[-2]]}
            record(rec)
            log.info("step %d loss %.4f lr %.2e gnorm %.2f %.3f clips/s (data %.0f%%) load %.1f", step, rec["loss"],
                     lr, gnorm, rec["clips_per_s"], 100 * rec["data_share"], rec["load"])
            window_loss, window_t, data_s = [], time.time(), 0.0
        if step % args.val_every == 0:
            run_val()
    if step % args.val_every:
        run_val()
    log.info("done: %d steps, %.0f s of training", step, trained_s)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
