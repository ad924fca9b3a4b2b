"""`recon train`: train the EST depth network on canonical scans with GT depth."""
from __future__ import annotations

import argparse
import logging

from apps.common import add_selection_args

log = logging.getLogger(__name__)


def register(subparsers):
    p = subparsers.add_parser(
        "train", help="train the EST depth network on scans with ground-truth depth",
        description="Train on 5-frame clips (3 targets) with the multi-stage L1 loss. Writes last.pt "
                    "(resumable) and model.pt (weights) to --out. Run under torchrun for several GPUs.")
    p.add_argument("scans", nargs="*", help="training scans (any supported format with GT depth)")
    p.add_argument("--synthetic", action="store_true",
                   help="train on an endless stream of synthetic rooms (recon.synthetic) instead of scans; "
                        "needs --max-steps")
    p.add_argument("--steps-per-epoch", type=int, default=None, metavar="N",
                   help="epoch length for the lr schedule (default: one pass over the scans; 1000 with --synthetic)")
    p.add_argument("--format", default="auto", help="input format of the scans (default: auto-detect)")
    add_selection_args(p)
    p.add_argument("--val", nargs="*", default=[], metavar="SCAN", help="validation scans")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder for checkpoints")
    p.add_argument("--config", default="compact", help="network config: paper or compact (default compact)")
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--max-steps", type=int, default=None, metavar="N")
    p.add_argument("--batch-size", type=int, default=1)
    p.add_argument("--lr", type=float, default=4e-5)
    p.add_argument("--weight-decay", type=float, default=1e-5)
    p.add_argument("--lr-halve-every", type=int, default=2, metavar="EPOCHS")
    p.add_argument("--frame-gap", type=int, default=1, help="scan frames between clip frames (default 1)")
    p.add_argument("--no-augment", action="store_true", help="disable photometric augmentation")
    p.add_argument("--val-every", type=int, default=1000, metavar="STEPS")
    p.add_argument("--checkpoint-every", type=int, default=1000, metavar="STEPS")
    p.add_argument("--amp", nargs="?", const="bf16", choices=("bf16", "fp16"), default=None,
                   help="mixed precision: bf16 (default when given), or fp16 with a gradient scaler (GPUs "
                        "without bf16)")
    p.add_argument("--compile", action="store_true", help="torch.compile the model")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--workers", type=int, default=0, help="data loader worker processes")
    p.add_argument("--resume", default=None, metavar="CKPT", help="continue from a last.pt checkpoint")
    p.add_argument("--backbone", default=None, metavar="PATH", help="ResNet weights for the ContextNet encoder")
    p.add_argument("--fp16-export", action="store_true", help="store model.pt weights as float16")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import os

    from depth.config import get_config
    from depth.data import ClipDataset, ClipOptions, StreamingClips
    from depth.train import TrainOptions, train
    from poses.readers import open_scan
    from recon.errors import ReconError

    cfg = get_config(args.config)
    clip = ClipOptions(frame_gap=args.frame_gap, width=cfg.image_width, height=cfg.image_height,
                       augment=not args.no_augment)

    def scans(paths):
        return [open_scan(p, args.format).select(args.start, args.stride, args.max_frames) for p in paths]

    if args.synthetic == bool(args.scans):
        raise ReconError("recon train: give training scans or --synthetic (one of the two)")
    steps_per_epoch = args.steps_per_epoch
    if args.synthetic:
        from recon.synthetic import iter_training_scans

        if args.max_steps is None:
            raise ReconError("recon train --synthetic: the stream is endless, pass --max-steps")
        steps_per_epoch = steps_per_epoch or 1000
        rank = int(os.environ.get("RANK", "0"))
        stream = iter_training_scans(seed=args.seed + 1000 * rank, clip_frames=clip.clip_length,
                                     width=cfg.image_width, height=cfg.image_height)
        train_data = StreamingClips(stream, clip, seed=args.seed + rank)
    else:
        train_data = ClipDataset(scans(args.scans), clip, seed=args.seed)
    val_data = ClipDataset(scans(args.val), ClipOptions(**{**clip.__dict__, "augment": False})) if args.val else None
    opts = TrainOptions(config=args.config, epochs=args.epochs, max_steps=args.max_steps,
                        steps_per_epoch=steps_per_epoch, batch_size=args.batch_size,
                        lr=args.lr, weight_decay=args.weight_decay, lr_halve_every=args.lr_halve_every,
                        val_every=args.val_every, checkpoint_every=args.checkpoint_every, amp=args.amp,
                        compile=args.compile, device=args.device, num_workers=args.workers, seed=args.seed,
                        backbone=args.backbone, fp16_export=args.fp16_export)
    log.info("training %s on %s (%d validation clips)", cfg.name,
             "synthetic rooms" if args.synthetic else f"{len(train_data)} clips", len(val_data) if val_data else 0)
    result = train(train_data, args.out, opts, val_data=val_data, resume=args.resume,
                   progress=lambda step, loss: log.debug("step %d loss %.4f", step, loss))
    last = f", last loss {result.losses[-1]:.4f}" if result.losses else ""
    print(f"trained {result.steps} steps ({result.epochs} epochs){last}; weights {result.model_path}")
    return 0
