"""The one training loop for the EST network: clips -> joint prediction of the middle frames -> loss.

Everything the shipped weights need lives here (`recon train` is a thin CLI over `train`):
- stopping at `max_steps` or at a wall-clock `deadline`, whichever comes first;
- the paper's schedule (Adam, lr halved every `lr_halve_every` epochs) or warm-up + cosine decay over
  the run's horizon (steps or time), restarted by `init` (shipped weights, fresh optimiser);
- a resolution schedule (`low_res` clips for the first `full_res_after` of the horizon: the network
  is size-agnostic, and small clips are about 4x cheaper);
- exact resume from `last.pt` (model, optimiser, scheduler, gradient scaler, step, training time);
- a weights file per validation (`step_NNNNNN.pt`) so a checkpoint can be chosen afterwards, and a
  `log.jsonl` with one record per logged step and validation;
- mixed precision (bf16 autocast, or fp16 with a gradient scaler), torch.compile, and DDP under
  torchrun (map-style data sharded with a DistributedSampler; only rank 0 writes files).
A pretrained encoder's trainable blocks learn at `encoder_lr_scale` times the rate.
"""
from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import torch
import torch.distributed as dist
from torch.utils.data import DataLoader, Dataset, DistributedSampler, IterableDataset

from recon.errors import ReconError

from .checkpoint import load_checkpoint, load_weights, save_checkpoint
from .config import ESTConfig, get_config
from .data import ShapeBatches, resize_clip
from .device import computes_bf16, describe_device, resolve_device
from .loss import LOSSES, multi_stage_loss
from .model import ESTNet

log = logging.getLogger(__name__)
SCHEDULES = ("step", "cosine")
AMP_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


@dataclass
class TrainOptions:
    config: str = "compact"  # named network config (ignored when a config object is passed)
    epochs: int = 10
    max_steps: int | None = None  # stop after this many optimiser steps (across epochs and sessions)
    deadline: float | None = None  # stop at this wall-clock time (time.time() seconds)
    steps_per_epoch: int | None = None  # epoch length in steps (streamed data has no natural end)
    batch_size: int = 1
    lr: float = 4e-5
    betas: tuple[float, float] = (0.9, 0.999)
    weight_decay: float = 1e-5
    schedule: str = "step"  # "step": paper (halve every lr_halve_every epochs); "cosine": warm-up + cosine
    lr_halve_every: int = 2  # epochs
    warmup_steps: int = 50  # cosine: linear warm-up after the start or an `init`
    min_lr_ratio: float = 0.05  # cosine: final lr / lr
    encoder_lr_scale: float = 0.1  # lr factor of a pretrained encoder's trainable blocks
    grad_clip: float | None = None  # clip the gradient norm to this
    loss: str = "l1"  # "l1" (paper: metres) or "log_l1" (log depth: relative error, as Abs Rel)
    grad_weight: float = 0.0  # weight of the log-depth gradient term on the full-resolution output
    near_factor: float = 1.0  # depth too near weighs this many times depth too far (depth/loss.py)
    near_margin: float = 0.0  # ... only beyond this fraction of the truth (0: every near error)
    hold_statistics: bool = False  # BatchNorm keeps its running statistics in training (ESTNet.hold_statistics)
    low_res: tuple[int, int] | None = None  # (width, height) of clips before `full_res_after`
    full_res_after: float = 0.7  # share of the horizon (steps or time) trained at low_res
    val_every: int = 1000  # steps; validation also runs at the end of every epoch
    checkpoint_every: int = 1000  # steps; a checkpoint is also written at the end of every epoch
    log_every: int = 50
    amp: str | None = None  # mixed precision: "bf16" autocast, "fp16" autocast with a gradient scaler, or
    # "auto": bf16 where the device computes it in hardware (depth.device.computes_bf16), else none
    compile: bool = False  # torch.compile the model
    device: str = "auto"
    num_workers: int = 0
    seed: int = 0
    init: str | None = None  # start from these weights (a shipped name or a file), fresh optimiser
    backbone: str | None = None  # external ResNet weights for the ContextNet encoder (resnet configs)
    fp16_export: bool = False  # store the final `model.pt` weights as float16

    def validate(self) -> "TrainOptions":
        if self.amp not in (None, "auto", *AMP_DTYPES):
            raise ReconError(f"unknown mixed precision {self.amp!r} (auto, bf16 or fp16)")
        if self.schedule not in SCHEDULES:
            raise ReconError(f"unknown lr schedule {self.schedule!r} ({' or '.join(SCHEDULES)})")
        if self.loss not in LOSSES:
            raise ReconError(f"unknown training loss {self.loss!r} ({' or '.join(LOSSES)})")
        if self.grad_weight < 0:
            raise ReconError(f"the gradient weight must be >= 0, not {self.grad_weight}")
        if not self.near_factor > 0:
            raise ReconError(f"the near factor must be > 0, not {self.near_factor}")
        if not 0 <= self.near_margin < 1:
            raise ReconError(f"the near margin must be in [0, 1), not {self.near_margin}")
        if self.schedule == "cosine" and self.max_steps is None and self.deadline is None:
            raise ReconError("the cosine schedule needs a horizon: max_steps or a deadline")
        return self


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


def clip_loss(model: torch.nn.Module, batch: dict, loss: str = "l1", grad_weight: float = 0.0,
              near_factor: float = 1.0, near_margin: float = 0.0) -> tuple[torch.Tensor, list[float], list]:
    """Joint prediction of the middle frames of a clip batch and its loss.

    batch: images (B, V, 3, H, W), K (B, 3, 3), camera_to_world (B, V, 4, 4), depth (B, V, H, W),
    depth_range (B, 2). Returns loss, per-stage error and the per-target outputs.
    """
    outputs = model(batch["images"], batch["K"], batch["camera_to_world"], batch["depth_range"])
    total, per_stage = multi_stage_loss([o.depths for o in outputs], batch["depth"][:, 1:-1], loss,
                                        grad_weight=grad_weight, near_factor=near_factor,
                                        near_margin=near_margin)
    return total, per_stage, outputs


@torch.no_grad()
def validate(model: torch.nn.Module, loader, device: torch.device) -> dict:
    """Mean multi-stage L1 loss and Abs Rel of the full-resolution output over a validation loader."""
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


def parameter_groups(model: ESTNet, lr: float, encoder_lr_scale: float) -> list[dict]:
    """Trainable parameters: the pretrained encoder's at a reduced rate, the rest at `lr`."""
    encoder = [p for n, p in model.named_parameters() if p.requires_grad and n.startswith("encoder.")]
    rest = [p for n, p in model.named_parameters() if p.requires_grad and not n.startswith("encoder.")]
    groups = [{"params": rest, "lr": lr, "base_lr": lr}]
    if encoder:
        groups.append({"params": encoder, "lr": lr * encoder_lr_scale, "base_lr": lr * encoder_lr_scale})
    return groups


class Trainer:
    """State of one training run; `train` drives it. Methods are the loop's steps."""

    def __init__(self, opts: TrainOptions, out_dir: Path, cfg: ESTConfig, describe: Callable[[], dict]):
        self.opts, self.out_dir, self.cfg, self.describe = opts.validate(), out_dir, cfg, describe
        self.rank, self.world, self.created_group = _distributed()
        self.device = resolve_device(opts.device)
        if opts.amp == "auto":  # the options in checkpoint metadata say what ran
            self.opts = replace(self.opts, amp="bf16" if computes_bf16(self.device) else None)
            log.info("precision: %s (auto)", self.opts.amp or "fp32")
        if self.world > 1 and self.device.type == "cuda":
            self.device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
            torch.cuda.set_device(self.device)
        torch.manual_seed(opts.seed + self.rank)
        self.model = ESTNet(cfg)
        if opts.hold_statistics:
            self.model.hold_statistics()
        if opts.backbone:
            self.model.context.load_backbone(opts.backbone)
        self.model.to(self.device).train()
        self.optimizer = torch.optim.Adam(parameter_groups(self.model, opts.lr, opts.encoder_lr_scale),
                                          lr=opts.lr, betas=tuple(opts.betas), weight_decay=opts.weight_decay)
        self.scaler = torch.amp.GradScaler(self.device.type, enabled=self.opts.amp == "fp16")
        self.step = self.epoch = self.warm_from = 0  # warm_from: the step this schedule began at
        self.trained_s = 0.0  # all training time of these weights, earlier runs included
        self.schedule_s = 0.0  # training time of this schedule before this process started
        self.started = time.time()
        self.result = TrainResult(0, 0)
        self.history: list[dict] = []  # the runs these weights came from (init chain), oldest first

    # -- starting points -------------------------------------------------------------------
    def initialise(self, weights: str) -> None:
        """Shipped or trained weights, a fresh optimiser and a new warm-up; their step count carries on."""
        ck = load_checkpoint(weights, expected=self.cfg)
        load_weights(self.model, ck.state_dict, ck.source)
        self.step = self.warm_from = int(ck.metadata.get("steps", 0))
        self.trained_s = float(ck.metadata.get("trained_s", 0.0))
        earlier = {k: ck.metadata.get(k) for k in ("steps", "trained_s", "data", "hardware", "time")}
        self.history = list(ck.metadata.get("history") or []) + [{"weights": str(weights), **earlier}]
        log.info("initialised from %s (trained %d steps), fresh optimiser", weights, self.step)

    def resume(self, path: str | os.PathLike) -> None:
        ck = load_checkpoint(path, expected=self.cfg)
        if not ck.training:
            raise ReconError(f"{path}: holds weights only, no training state to resume from")
        load_weights(self.model, ck.state_dict, ck.source)
        self.optimizer.load_state_dict(ck.training["optimizer"])
        t = ck.training
        self.step, self.epoch = int(t["step"]), int(t.get("epoch", 0))
        self.warm_from = int(t.get("warm_from", 0))
        self.trained_s = float(t.get("trained_s", 0.0))
        self.schedule_s = float(t.get("schedule_s", self.trained_s))
        self.history = list(ck.metadata.get("history") or [])
        if ck.metadata.get("data") != self.describe():  # the run goes on with other data: keep what came before
            self.history.append({"resumed_at_step": self.step, "data": ck.metadata.get("data"),
                                 "hardware": ck.metadata.get("hardware")})
        if t.get("grad_scaler"):
            self.scaler.load_state_dict(t["grad_scaler"])
        log.info("resumed from %s at step %d, epoch %d", path, self.step, self.epoch)

    # -- schedule ------------------------------------------------------------------------------
    def progress(self) -> float:
        """Share of the run's horizon done (0..1): steps against max_steps, time against the deadline."""
        shares = []
        if self.opts.max_steps:
            shares.append((self.step - self.warm_from) / max(self.opts.max_steps - self.warm_from, 1))
        if self.opts.deadline is not None:
            total = self.schedule_s + max(self.opts.deadline - self.started, 1.0)
            shares.append((self.schedule_s + time.time() - self.started) / total)
        return min(max(shares, default=0.0), 1.0)

    def lr_factor(self) -> float:
        if self.opts.schedule == "step":
            return 0.5 ** (self.epoch // max(self.opts.lr_halve_every, 1))
        warm = min(1.0, (self.step - self.warm_from + 1) / max(self.opts.warmup_steps, 1))
        cosine = 0.5 * (1 + math.cos(math.pi * self.progress()))
        return warm * (self.opts.min_lr_ratio + (1 - self.opts.min_lr_ratio) * cosine)

    def apply_lr(self) -> float:
        factor = self.lr_factor()
        for group in self.optimizer.param_groups:
            group["lr"] = group["base_lr"] * factor
        return self.optimizer.param_groups[0]["lr"]

    def clip_size(self) -> tuple[int, int] | None:
        """The low-res clip size while the resolution schedule says so, else None (data's own size)."""
        if self.opts.low_res and self.progress() < self.opts.full_res_after:
            return tuple(self.opts.low_res)
        return None

    def finished(self) -> bool:
        return ((self.opts.max_steps is not None and self.step >= self.opts.max_steps)
                or (self.opts.deadline is not None and time.time() >= self.opts.deadline))

    # -- files ---------------------------------------------------------------------------------
    def metadata(self) -> dict:
        return {"data": self.describe(), "steps": self.step, "epochs": self.epoch,
                "trained_s": round(self.trained_s, 1), "options": asdict(self.opts), "history": self.history,
                "hardware": describe_device(self.device),
                "validation": self.result.validation[-1] if self.result.validation else None,
                "time": time.strftime("%Y-%m-%dT%H:%M:%S")}

    def save_last(self) -> None:
        if self.rank == 0:
            schedule_s = self.schedule_s + time.time() - self.started
            training = {"optimizer": self.optimizer.state_dict(), "step": self.step, "epoch": self.epoch,
                        "warm_from": self.warm_from, "trained_s": self.trained_s, "schedule_s": schedule_s,
                        "grad_scaler": self.scaler.state_dict() if self.scaler.is_enabled() else None}
            self.result.checkpoint = save_checkpoint(self.out_dir / "last.pt", self.model, self.cfg,
                                                     self.metadata(), training)

    def record(self, entry: dict) -> None:
        if self.rank == 0:
            with open(self.out_dir / "log.jsonl", "a") as f:
                f.write(json.dumps(entry) + "\n")

    def run_validation(self, loader) -> None:
        if loader is None or self.rank != 0:
            return
        t0 = time.time()
        metrics = {"step": self.step, **validate(self.model, loader, self.device)}
        self.result.validation.append(metrics)
        self.record({"kind": "val", "trained_s": round(self.trained_s, 1), **metrics,
                     "val_s": round(time.time() - t0, 1)})
        log.info("validation at step %d: loss %.4f, abs rel %.4f", self.step, metrics["loss"], metrics["abs_rel"])
        save_checkpoint(self.out_dir / f"step_{self.step:06d}.pt", self.model, self.cfg, self.metadata(), fp16=True)

    # -- one step --------------------------------------------------------------------------------
    def train_step(self, net: torch.nn.Module, batch: dict) -> float | None:
        """One optimiser step on a batch; None when the loss was not finite (the batch is skipped)."""
        t0 = time.time()
        size = self.clip_size()
        if size is not None:
            portrait = batch["images"].shape[-2] > batch["images"].shape[-1]
            batch = resize_clip(batch, *(size[::-1] if portrait else size))
        batch = _to(batch, self.device)
        self.apply_lr()
        amp = AMP_DTYPES.get(self.opts.amp)
        with torch.autocast(self.device.type, dtype=amp or torch.float32, enabled=amp is not None):
            loss, per_stage, _ = clip_loss(net, batch, self.opts.loss, self.opts.grad_weight,
                                           self.opts.near_factor, self.opts.near_margin)
        value = float(loss.detach())
        if not math.isfinite(value):
            log.warning("step %d: non-finite loss, batch skipped", self.step)
            return None
        self.optimizer.zero_grad(set_to_none=True)
        self.scaler.scale(loss).backward()
        if self.opts.grad_clip:
            self.scaler.unscale_(self.optimizer)
            torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.opts.grad_clip)
        self.scaler.step(self.optimizer)  # skips the step when fp16 gradients overflowed
        self.scaler.update()
        self.step += 1
        self.trained_s += time.time() - t0
        if self.rank == 0 and self.step % self.opts.log_every == 0:
            lr = self.optimizer.param_groups[0]["lr"]
            self.record({"kind": "train", "step": self.step, "loss": value, "stages": [round(x, 4) for x in per_stage],
                         "lr": lr, "trained_s": round(self.trained_s, 1), "size": list(batch["images"].shape[-2:][::-1]),
                         "load": os.getloadavg()[0]})
            log.info("step %d epoch %d loss %.4f lr %.2e size %dx%d", self.step, self.epoch, value, lr,
                     batch["images"].shape[-1], batch["images"].shape[-2])
        return value


def _loaders(trainer: Trainer, train_data, val_data) -> tuple[DataLoader, DistributedSampler | None, DataLoader | None]:
    opts, streamed = trainer.opts, isinstance(train_data, IterableDataset)
    sampler = (DistributedSampler(train_data, trainer.world, trainer.rank, shuffle=True, seed=opts.seed)
               if trainer.world > 1 and not streamed else None)
    shuffle = sampler is None and not streamed
    # CUDA cannot be used in forked workers (the synthetic renderer casts rays on the GPU where Open3D is missing)
    context = "spawn" if opts.num_workers and trainer.device.type == "cuda" else None
    if streamed and opts.batch_size > 1:  # streams mix orientations: batch clips of one shape together
        loader = DataLoader(ShapeBatches(train_data, opts.batch_size), None, num_workers=opts.num_workers,
                            multiprocessing_context=context)
    else:
        loader = DataLoader(train_data, opts.batch_size, shuffle=shuffle, sampler=sampler,
                            num_workers=opts.num_workers, multiprocessing_context=context,
                            generator=torch.Generator().manual_seed(opts.seed) if shuffle else None)
    return loader, sampler, DataLoader(val_data, 1) if val_data is not None else None


def train(train_data: Dataset | IterableDataset, out_dir: str | os.PathLike, opts: TrainOptions = TrainOptions(),
          val_data: Dataset | None = None, resume: str | os.PathLike | None = None,
          model_config: ESTConfig | None = None,
          progress: Callable[[int, float], None] | None = None) -> TrainResult:
    """Train (or resume, or continue from `opts.init`) an ESTNet on clips from `train_data` (see
    depth.data); files go to `out_dir`. `progress(step, loss)` is called after every step on rank 0."""
    cfg = model_config or get_config(opts.config)
    if opts.schedule == "cosine" and opts.max_steps is None and opts.deadline is None and hasattr(train_data, "__len__"):
        opts = replace(opts, max_steps=opts.epochs * math.ceil(len(train_data) / opts.batch_size))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    trainer = Trainer(opts, out_dir, cfg, getattr(train_data, "describe", lambda: {"dataset": type(train_data).__name__}))
    if resume is not None and opts.init:
        raise ReconError("training: resume and init exclude each other")
    if resume is not None:
        trainer.resume(resume)
    elif opts.init:
        trainer.initialise(opts.init)
    net: torch.nn.Module = trainer.model
    if trainer.world > 1:
        net = torch.nn.parallel.DistributedDataParallel(
            net, device_ids=[trainer.device.index] if trainer.device.type == "cuda" else None)
    if opts.compile:  # one graph per clip shape: with dynamic shapes inductor fails on the second (torch 2.13)
        net = torch.compile(net, dynamic=False)
    loader, sampler, val_loader = _loaders(trainer, train_data, val_data)
    _loop(trainer, net, loader, sampler, val_loader, train_data, progress)
    result = trainer.result
    result.steps, result.epochs = trainer.step, trainer.epoch
    trainer.save_last()
    if trainer.rank == 0:
        result.model_path = save_checkpoint(out_dir / "model.pt", trainer.model, cfg, trainer.metadata(),
                                            fp16=opts.fp16_export)
    if trainer.created_group:
        dist.destroy_process_group()
    return result


def _loop(trainer: Trainer, net, loader, sampler, val_loader, train_data, progress) -> None:
    opts = trainer.opts
    if trainer.step == 0 or opts.init:
        trainer.run_validation(val_loader)

    def end_epoch() -> None:
        trainer.epoch += 1
        trainer.apply_lr()
        trainer.run_validation(val_loader)
        trainer.save_last()

    while trainer.epoch < opts.epochs and not trainer.finished():
        if sampler is not None:
            sampler.set_epoch(trainer.epoch)
        if hasattr(train_data, "epoch"):
            train_data.epoch = trainer.epoch
        for batch in loader:
            loss = trainer.train_step(net, batch)
            if loss is None:
                continue
            trainer.result.losses.append(loss)
            if progress and trainer.rank == 0:
                progress(trainer.step, loss)
            if opts.val_every and trainer.step % opts.val_every == 0:
                trainer.run_validation(val_loader)
            if opts.checkpoint_every and trainer.step % opts.checkpoint_every == 0:
                trainer.save_last()
            if opts.steps_per_epoch and trainer.step % opts.steps_per_epoch == 0:
                end_epoch()
            if trainer.finished() or trainer.epoch >= opts.epochs:
                break
        else:
            if not opts.steps_per_epoch:
                end_epoch()
    if opts.val_every and (not trainer.result.validation or trainer.result.validation[-1]["step"] != trainer.step):
        trainer.run_validation(val_loader)
