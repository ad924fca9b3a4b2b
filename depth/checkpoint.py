"""One-file checkpoints: network config + weights + metadata (+ optimiser state for resuming).

`--weights compact` resolves to depth/weights/compact.pt (shipped with the package);
anything else is a path. Weights may be stored as float16 (half the size) and come
back as float32. Loading checks the file is ours, readable and of the expected config.
"""
from __future__ import annotations

import os
import pickle
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from recon.errors import ReconError, naming
from recon.io import atomic_path

from .config import CONFIGS, ESTConfig

FORMAT = "recon-est-depth"
VERSION = 1
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"


@dataclass
class Checkpoint:
    """What a checkpoint file holds. `training` is the resumable state (optimiser, scheduler,
    step, epoch) or empty for shipped weights; `metadata` says what it was trained on."""

    config: ESTConfig
    state_dict: dict[str, torch.Tensor]
    metadata: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    source: str = "checkpoint"  # the file it came from, for messages


def resolve_weights(name_or_path: str | os.PathLike) -> Path:
    """A shipped weights name (e.g. `compact`) -> depth/weights/<name>.pt, else the path itself."""
    text = str(name_or_path)
    if text in CONFIGS or (os.sep not in text and not text.endswith(".pt") and "." not in text):
        path = WEIGHTS_DIR / f"{text}.pt"
        if not path.is_file():
            raise ReconError(f"no shipped depth weights named {text!r} ({path} is missing); train some with "
                             "`recon train`, pass --weights PATH, or use --mode planesweep (needs no weights)")
        return path
    path = Path(text)
    if not path.is_file():
        raise ReconError(f"{path}: depth weights file not found")
    return path


def save_checkpoint(path: str | os.PathLike, model: torch.nn.Module, config: ESTConfig,
                    metadata: dict[str, Any] | None = None, training: dict[str, Any] | None = None,
                    fp16: bool = False) -> Path:
    """Write a checkpoint atomically. `fp16` stores floating-point tensors as float16. A pretrained
    encoder's frozen tensors are left out (they load from their package) and the package is recorded."""
    stored = model.stored_state_dict() if hasattr(model, "stored_state_dict") else model.state_dict()
    state = {k: (v.detach().to("cpu", torch.float16) if fp16 and v.is_floating_point() else v.detach().cpu())
             for k, v in stored.items()}
    doc = {"format": FORMAT, "version": VERSION, "config": config.to_dict(), "state_dict": state,
           "storage": "float16" if fp16 else "float32", "metadata": dict(metadata or {}),
           "training": dict(training or {}), "pretrained": pretrained_record(config)}
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(doc, tmp)
    return path


def pretrained_record(config: ESTConfig) -> dict | None:
    """Which package and file a config's frozen encoder loads from (None for the resnet configs)."""
    if config.encoder == "resnet":
        return None
    from .model.efficientnet import LITE0_WEIGHTS

    return {"encoder": config.encoder, "package": LITE0_WEIGHTS.package, "sha256": LITE0_WEIGHTS.sha256}


def load_checkpoint(name_or_path: str | os.PathLike, expected: ESTConfig | None = None) -> Checkpoint:
    """Read a checkpoint (tensors on CPU, float32). Raises ReconError for a file that is not
    a depth checkpoint, is corrupt, or holds another configuration than `expected`."""
    path = resolve_weights(name_or_path)
    try:
        doc = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch's messages run to several lines, and advise the unsafe weights_only=False
        pickled_objects = isinstance(exc, pickle.UnpicklingError) and zipfile.is_zipfile(path)
        what = ("empty file" if path.stat().st_size == 0 else
                "it holds more than tensors, and is not unpickled for safety" if pickled_objects
                else "truncated, damaged or not a torch file")
        raise ReconError(f"{path}: unreadable depth checkpoint ({what})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ReconError(f"{path}: not a depth network checkpoint (no '{FORMAT}' header)")
    if doc.get("version") != VERSION:
        raise ReconError(f"{path}: unsupported checkpoint version {doc.get('version')!r}")
    if not isinstance(doc.get("config"), dict) or not isinstance(doc.get("state_dict"), dict):
        raise ReconError(f"{path}: damaged depth checkpoint (no network config or tensors)")
    with naming(path):
        config = ESTConfig.from_dict(doc["config"])
    if expected is not None and config != expected:
        diff = [k for k, v in config.to_dict().items() if expected.to_dict()[k] != v]
        raise ReconError(f"{path}: checkpoint is for depth config {config.name!r}, expected {expected.name!r} "
                         f"(differs in {', '.join(diff)})")
    state = {k: v.float() if v.is_floating_point() else v for k, v in doc["state_dict"].items()}
    return Checkpoint(config, state, doc.get("metadata", {}), doc.get("training", {}), str(path))


def average_checkpoints(names_or_paths: list[str | os.PathLike]) -> Checkpoint:
    """The mean of several checkpoints of one network (weight averaging along a run, SWA style: one network
    as fast as each; what it gained on `lite` is in docs/model_card.md). Floating-point tensors are averaged, integer ones (BatchNorm step counts) taken from the last; the
    last checkpoint's metadata is kept, with `averaged_from` naming the inputs."""
    if not names_or_paths:
        raise ReconError("average_checkpoints: no checkpoints given")
    checkpoints = [load_checkpoint(p) for p in names_or_paths]
    last = checkpoints[-1]
    for ck in checkpoints[:-1]:
        if ck.config != last.config or set(ck.state_dict) != set(last.state_dict):
            raise ReconError(f"{ck.source}: cannot average with {last.source} (another network)")
    state = {k: (torch.stack([ck.state_dict[k] for ck in checkpoints]).mean(0) if v.is_floating_point() else v)
             for k, v in last.state_dict.items()}
    metadata = dict(last.metadata, averaged_from=[ck.source for ck in checkpoints])
    return Checkpoint(last.config, state, metadata, source=f"mean of {len(checkpoints)} checkpoints")


def build_model(checkpoint: Checkpoint) -> torch.nn.Module:
    """An ESTNet of the checkpoint's config with its weights (eval mode, CPU)."""
    from .model import ESTNet

    model = ESTNet(checkpoint.config)  # loads a pretrained encoder from its package
    load_weights(model, checkpoint.state_dict, checkpoint.source)
    return model.eval()


def load_weights(model: torch.nn.Module, state: dict[str, torch.Tensor], source: str = "checkpoint") -> None:
    """Load a checkpoint's tensors: every one must fit, and only package-loaded tensors may be absent."""
    own = model.state_dict()
    wrong = [f"{k} {tuple(v.shape)} vs {tuple(own[k].shape)}" for k, v in state.items()
             if k in own and own[k].shape != v.shape]
    unknown = sorted(set(state) - set(own))
    absent = sorted(set(own) - set(state) - model.pretrained_keys())
    if wrong or unknown or absent:
        what = (f"shape mismatch {wrong[0]}" if wrong else f"unknown tensor {unknown[0]}" if unknown
                else f"missing tensor {absent[0]}")
        raise ReconError(f"{source}: weights do not fit the {model.cfg.name!r} network ({what})")
    model.load_state_dict(state, strict=False)


# The shipped default (depth/weights/compact.pt, docs/model_card.md): what learned modes load unless told otherwise.
DEFAULT_WEIGHTS = "compact"
INDOOR_DEPTH_RANGE = (0.25, 6.0)  # metres: planes for a metric indoor scan that states no range of its own


def trained_depth_range(weights: str | os.PathLike | None) -> tuple[float, float] | None:
    """The depth range a checkpoint's training data spanned (metadata `data.depth_range`), if it says."""
    if weights is None:
        return None
    rng = (load_checkpoint(weights).metadata.get("data") or {}).get("depth_range")
    return (float(rng[0]), float(rng[1])) if rng else None


def weights_digest(name_or_path: str | os.PathLike | None) -> str | None:
    """A short content hash of a weights file, so cached depth is redone when the file changes."""
    if name_or_path is None:
        return None
    import hashlib

    return hashlib.sha1(resolve_weights(name_or_path).read_bytes()).hexdigest()[:16]
