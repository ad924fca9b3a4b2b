"""Training loop for the EST network: clips -> joint prediction of the middle frames -> multi-stage L1.

Paper optimiser settings are the defaults (Adam, lr 4e-5, betas (0.9, 0.999), weight
decay 1e-5, lr halved every 2 epochs). Checkpoints (`last.pt`) hold the model,
optimiser, scheduler, step, epoch, config and a description of the data, so a run
resumes exactly where it stopped. Mixed precision (`amp`: bf16 autocast, or fp16 autocast
with a gradient scaler whose state the checkpoint keeps) and torch.compile are options; under `torchrun` the model is wrapped in DistributedDataParallel and
map-style data is sharded with a DistributedSampler; only rank 0 writes files. Streamed
data (`StreamingClips` over an endless generator) needs `steps_per_epoch` for the epoch-based
lr schedule and `max_steps` to stop; on resume the stream starts again from its beginning
(pass another seed to the generator to see new scenes).
"""
from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import torch
import torch.distributed as dist
from torch.utils.data import DataLoader, Dataset, DistributedSampler, IterableDataset

from recon.errors import ReconError

from .checkpoint import load_checkpoint, save_checkpoint
from .config import ESTConfig, get_config
from .inference import resolve_device
from .loss import multi_stage_l1
from .model import ESTNet

log = logging.getLogger(__name__)


@dataclass
class TrainOptions:
    config: str = "compact"  # named network config (ignored when a config object is passed)
    epochs: int = 10
    max_steps: int | None = None  # stop after this many optimiser steps (across epochs)
    steps_per_epoch: int | None = None  # epoch length in steps (streamed data has no natural end)
    batch_size: int = 1
    lr: float = 4e-5
    betas: tuple[float, float] = (0.9, 0.999)
    weight_decay: float = 1e-5
    lr_halve_every: int = 2  # epochs
    val_every: int = 1000  # steps; validation also runs at the end of every epoch
    checkpoint_every: int = 1000  # steps; a checkpoint is also written at the end of every epoch
    log_every: int = 50
    amp: str | None = None  # mixed precision: "bf16" autocast, or "fp16" autocast with a gradient scaler
    compile: bool = False  # torch.compile the model
    device: str = "auto"
    num_workers: int = 0
    seed: int = 0
    backbone: str | None = None  # external ResNet weights for the ContextNet encoder
    fp16_export: bool = False  # store the final `model.pt` weights as float16


@dataclass
class TrainResult:
    steps: int
    epochs: int
    losses: list[float] = field(default_factory=list)  # training loss per step (this process)
    validation: list[dict] = field(default_factory=list)
    checkpoint: Path | None = None
    model_path: Path | None = None


def _distributed() -> tuple[int, int, bool]:
    """(rank, world size, whether this call created the process group) under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    created = world > 1 and not dist.is_initialized()
    if created:
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    return (dist.get_rank(), world, created) if world > 1 else (0, 1, False)


def _to(batch: dict, device: torch.device) -> dict:
    return {k: v.to(device, non_blocking=True) for k, v in batch.items()}


def clip_loss(model: torch.nn.Module, batch: dict) -> tuple[torch.Tensor, list[float], list]:
    """Joint prediction of the middle frames of a clip batch and its loss.

    batch: images (B, V, 3, H, W), K (B, 3, 3), camera_to_world (B, V, 4, 4), depth (B, V, H, W),
    depth_range (B, 2). Returns loss, per-stage L1 and the per-target outputs.
    """
    outputs = model(batch["images"], batch["K"], batch["camera_to_world"], batch["depth_range"])
    loss, per_stage = multi_stage_l1([o.depths for o in outputs], batch["depth"][:, 1:-1])
    return loss, per_stage, outputs


@torch.no_grad()
def validate(model: torch.nn.Module, loader, device: torch.device) -> dict:
    """Mean loss and Abs Rel of the full-resolution output over a validation loader."""
    model.eval()
    losses, abs_rels = [], []
    for batch in loader:
        batch = _to(batch, device)
        loss, _, outputs = clip_loss(model, batch)
        losses.append(float(loss))
        for t, out in enumerate(outputs):
            gt = batch["depth"][:, t + 1:t + 2]
            valid = gt > 0
            if valid.any():
                abs_rels.append(float(((out.depths[3] - gt).abs() / gt.clamp_min(1e-6))[valid].mean()))
    model.train()
    return {"loss": sum(losses) / max(len(losses), 1), "abs_rel": sum(abs_rels) / max(len(abs_rels), 1)}


def train(train_data: Dataset | IterableDataset, out_dir: str | os.PathLike, opts: TrainOptions = TrainOptions(),
          val_data: Dataset | None = None, resume: str | os.PathLike | None = None,
          model_config: ESTConfig | None = None,
          progress: Callable[[int, float], None] | None = None) -> TrainResult:
    """Train (or resume) an ESTNet on clips from `train_data` (see depth.data); files go to `out_dir`.

    `progress(step, loss)` is called after every optimiser step on rank 0.
    """
    rank, world, created_group = _distributed()
    device = resolve_device(opts.device)
    if world > 1 and device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    torch.manual_seed(opts.seed + rank)
    cfg = model_config or get_config(opts.config)
    out_dir = Path(out_dir)
    model = ESTNet(cfg)
    if opts.backbone:
        model.context.load_backbone(opts.backbone)
    model.to(device).train()
    optimizer = torch.optim.Adam(model.parameters(), lr=opts.lr, betas=tuple(opts.betas),
                                 weight_decay=opts.weight_decay)
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=max(opts.lr_halve_every, 1), gamma=0.5)
    if opts.amp not in (None, "bf16", "fp16"):
        raise ReconError(f"unknown mixed precision {opts.amp!r} (bf16 or fp16)")
    amp_dtype = {"bf16": torch.bfloat16, "fp16": torch.float16}.get(opts.amp)
    # fp16 has a narrow exponent: scale the loss so small gradients do not flush to zero.
    scaler = torch.amp.GradScaler(device.type, enabled=opts.amp == "fp16")
    step, epoch = 0, 0
    if resume is not None:
        ckpt = load_checkpoint(resume, expected=cfg)
        if not ckpt.training:
            raise ReconError(f"{resume}: holds weights only, no training state to resume from")
        model.load_state_dict(ckpt.state_dict)
        optimizer.load_state_dict(ckpt.training["optimizer"])
        scheduler.load_state_dict(ckpt.training["scheduler"])
        step, epoch = int(ckpt.training["step"]), int(ckpt.training["epoch"])
        if ckpt.training.get("grad_scaler"):
            scaler.load_state_dict(ckpt.training["grad_scaler"])
        log.info("resumed from %s at step %d, epoch %d", resume, step, epoch)
    net: torch.nn.Module = model
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(
            model, device_ids=[device.index] if device.type == "cuda" else None)
    if opts.compile:
        net = torch.compile(net)
    sampler = (DistributedSampler(train_data, world, rank, shuffle=True, seed=opts.seed)
               if world > 1 and not isinstance(train_data, IterableDataset) else None)
    shuffle = sampler is None and not isinstance(train_data, IterableDataset)
    loader = DataLoader(train_data, opts.batch_size, shuffle=shuffle, sampler=sampler,
                        num_workers=opts.num_workers, drop_last=False,
                        generator=torch.Generator().manual_seed(opts.seed) if shuffle else None)
    val_loader = DataLoader(val_data, 1) if val_data is not None else None
    describe = getattr(train_data, "describe", lambda: {"dataset": type(train_data).__name__})
    result = TrainResult(step, epoch)

    def checkpoint(final: bool = False) -> None:
        if rank != 0:
            return
        meta = {"data": describe(), "steps": step, "epochs": epoch, "options": asdict(opts),
                "validation": result.validation[-1:] or None, "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
        training = {"optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict(),
                    "step": step, "epoch": epoch, "grad_scaler": scaler.state_dict() if scaler.is_enabled() else None}
        result.checkpoint = save_checkpoint(out_dir / "last.pt", model, cfg, meta, training)
        if final:
            result.model_path = save_checkpoint(out_dir / "model.pt", model, cfg, meta, fp16=opts.fp16_export)

    def run_validation() -> None:
        if val_loader is not None and rank == 0:
            metrics = {"step": step, **validate(model, val_loader, device)}
            result.validation.append(metrics)
            log.info("validation at step %d: loss %.4f, abs rel %.4f", step, metrics["loss"], metrics["abs_rel"])

    def end_epoch() -> None:
        nonlocal epoch
        epoch += 1
        scheduler.step()
        run_validation()
        checkpoint()

    done = opts.max_steps is not None and step >= opts.max_steps
    while epoch < opts.epochs and not done:
        if sampler is not None:
            sampler.set_epoch(epoch)
        if hasattr(train_data, "epoch"):
            train_data.epoch = epoch
        for batch in loader:
            batch = _to(batch, device)
            with torch.autocast(device.type, dtype=amp_dtype or torch.float32, enabled=amp_dtype is not None):
                loss, per_stage, _ = clip_loss(net, batch)
            if not math.isfinite(float(loss.detach())):
                raise ReconError(f"training diverged at step {step} (loss {float(loss.detach())})")
            optimizer.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
            scaler.step(optimizer)  # skips the step when fp16 gradients overflowed
            scaler.update()
            step += 1
            result.losses.append(float(loss.detach()))
            if rank == 0:
                if progress:
                    progress(step, result.losses[-1])
                if step % opts.log_every == 0:
                    log.info("step %d epoch %d loss %.4f stages %s lr %.2e", step, epoch, result.losses[-1],
                             [round(x, 4) for x in per_stage], optimizer.param_groups[0]["lr"])
            if opts.val_every and step % opts.val_every == 0:
                run_validation()
            if opts.checkpoint_every and step % opts.checkpoint_every == 0:
                checkpoint()
            if opts.steps_per_epoch and step % opts.steps_per_epoch == 0:
                end_epoch()
                done = epoch >= opts.epochs
            if opts.max_steps is not None and step >= opts.max_steps:
                done = True
            if done:
                break
        else:
            if not opts.steps_per_epoch:
                end_epoch()
    result.steps, result.epochs = step, epoch
    checkpoint(final=True)
    if created_group:
        dist.destroy_process_group()
    return result
