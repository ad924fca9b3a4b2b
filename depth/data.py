"""Training clips from canonical scans: 5 consecutive (key)frames, GT depth, photometric augmentation.

`ClipDataset` indexes clips of a finite list of scans (random access, shuffling);
`StreamingClips` draws clips from any iterable of scans (e.g. the synthetic-scene
generator), so training can consume scenes as they are produced; given a function of the
data-loader worker's index instead, each worker draws its own stream.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset, IterableDataset, default_collate, get_worker_info

from recon.errors import ReconError
from recon.scan import Scan

from .geometry import scale_intrinsics


@dataclass(frozen=True)
class ClipOptions:
    clip_length: int = 5  # frames per clip; the middle clip_length - 2 are targets
    frame_gap: int = 1  # step between clip frames (in scan frames)
    width: int = 320  # network input size
    height: int = 256
    augment: bool = True
    brightness: float = 0.2  # max relative change
    contrast: float = 0.2
    saturation: float = 0.2
    gamma: float = 0.2
    depth_margin: float = 0.1  # range from GT: [min * (1 - m), max * (1 + m)] when metadata has none
    scale_jitter: float = 0.0  # with augment: scene scaled by exp(U(-j, j)) per clip (depth and baselines)
    reverse_share: float = 0.0  # with augment: this share of clips runs backwards in time (walks filmed forwards
    #                             would otherwise teach the memory that the camera always advances)
    keep_orientation: bool = True  # portrait scans get a portrait clip (width and height swapped)


def _augment(images: torch.Tensor, opts: ClipOptions, gen: torch.Generator) -> torch.Tensor:
    """Photometric jitter, the same draw for every frame of a clip (keeps matching consistent).

    images (V, 3, H, W) in [0, 1] -> same shape.
    """
    def draw(amount):
        return 1.0 + (torch.rand((), generator=gen).item() * 2 - 1) * amount

    x = images.clamp(0, 1) ** draw(opts.gamma)
    x = x * draw(opts.brightness)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = (x - mean) * draw(opts.contrast) + mean
    gray = x.mean(dim=1, keepdim=True)
    x = (x - gray) * draw(opts.saturation) + gray
    return x.clamp(0, 1)


def _scale_scene(depth: torch.Tensor, camera_to_world: torch.Tensor, jitter: float, gen: torch.Generator
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """The clip's room made larger or smaller by one factor exp(U(-jitter, jitter)): the images stay
    the same, depth and camera positions scale together. A room's apparent size then says nothing
    about its metres, so the network has to take scale from the baselines (the poses), not from
    what rooms usually look like. depth (V, H, W), camera_to_world (V, 4, 4) -> the same shapes."""
    factor = float(np.exp((torch.rand((), generator=gen).item() * 2 - 1) * jitter))
    scaled = camera_to_world.clone()
    scaled[:, :3, 3] *= factor
    return depth * factor, scaled


def make_clip(scan: Scan, start: int, opts: ClipOptions, gen: torch.Generator | None = None) -> dict:
    """One clip as tensors: images (V, 3, H, W) in [0, 1], K (3, 3) at H x W, camera_to_world
    (V, 4, 4), depth (V, H, W) metres (0 = invalid), depth_range (2,)."""
    idx = [start + k * opts.frame_gap for k in range(opts.clip_length)]
    if opts.augment and gen is not None and opts.reverse_share > 0 \
            and torch.rand((), generator=gen).item() < opts.reverse_share:
        idx.reverse()
    portrait = opts.keep_orientation and (scan.intrinsics.height > scan.intrinsics.width) != (opts.height > opts.width)
    net = scan.resized(opts.height, opts.width) if portrait else scan.resized(opts.width, opts.height)
    images, depths = [], []
    for i in idx:
        images.append(torch.from_numpy(np.ascontiguousarray(net.image(i))).permute(2, 0, 1).float() / 255.0)
        d = net.depth(i)
        if d is None:
            raise ReconError(f"{scan.root or 'scan'} frame {scan.frames[i].name}: training needs GT depth")
        depths.append(torch.from_numpy(np.nan_to_num(d, nan=0.0, posinf=0.0)))
    images, depth = torch.stack(images), torch.stack(depths)
    camera_to_world = torch.from_numpy(scan.camera_to_world[idx]).float()
    if opts.augment and gen is not None:
        images = _augment(images, opts, gen)
        if opts.scale_jitter > 0:
            depth, camera_to_world = _scale_scene(depth, camera_to_world, opts.scale_jitter, gen)
    if scan.metadata.depth_range is not None:
        lo, hi = scan.metadata.depth_range
    else:
        valid = depth[depth > 0]
        if valid.numel() == 0:
            raise ReconError(f"{scan.root or 'scan'}: clip at frame {start} has no valid GT depth")
        lo, hi = float(valid.min()) * (1 - opts.depth_margin), float(valid.max()) * (1 + opts.depth_margin)
    depth = torch.where((depth >= lo) & (depth <= hi), depth, torch.zeros_like(depth))
    return {"images": images, "K": torch.from_numpy(net.intrinsics.K).float(),
            "camera_to_world": camera_to_world,
            "depth": depth, "depth_range": torch.tensor([lo, hi], dtype=torch.float32)}


def resize_clip(batch: dict, width: int, height: int) -> dict:
    """A clip batch at another size: images area-averaged, depth nearest (as `Scan.resized`), K following.

    batch: images (B, V, 3, H, W), depth (B, V, H, W), K (B, 3, 3) -> the same keys at height x width.
    """
    b, v, _, h, w = batch["images"].shape
    if (w, h) == (width, height):
        return batch
    images = F.interpolate(batch["images"].flatten(0, 1), (height, width), mode="area").unflatten(0, (b, v))
    depth = F.interpolate(batch["depth"], (height, width), mode="nearest")
    return {**batch, "images": images, "depth": depth, "K": scale_intrinsics(batch["K"], width / w, height / h)}


def _describe_clips(opts: ClipOptions) -> dict:
    """The clip settings that checkpoint metadata records."""
    return {"clip_length": opts.clip_length, "frame_gap": opts.frame_gap, "size": [opts.width, opts.height],
            "scale_jitter": opts.scale_jitter, **({"reverse_share": opts.reverse_share} if opts.reverse_share else {})}


def _clip_starts(scan: Scan, opts: ClipOptions) -> range:
    span = (opts.clip_length - 1) * opts.frame_gap
    return range(0, max(len(scan) - span, 0))


class ClipDataset(Dataset):
    """All clips of a list of scans (each scan validated and required to have GT depth)."""

    def __init__(self, scans: Iterable[Scan], opts: ClipOptions = ClipOptions(), seed: int = 0):
        self.scans = [s.validate() for s in scans]
        self.opts, self.seed = opts, seed
        self.index = [(k, start) for k, s in enumerate(self.scans) for start in _clip_starts(s, opts)]
        if not self.index:
            raise ReconError(f"no training clips: every scan is shorter than {opts.clip_length} frames "
                             f"at frame gap {opts.frame_gap}")
        self.epoch = 0

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict:
        k, start = self.index[i]
        gen = torch.Generator().manual_seed(hash((self.seed, self.epoch, i)) & 0x7FFFFFFF)
        return make_clip(self.scans[k], start, self.opts, gen)

    def describe(self) -> dict:
        """What the data is, for checkpoint metadata."""
        return {"scans": [str(s.root or s.metadata.source) for s in self.scans], "clips": len(self),
                **_describe_clips(self.opts)}


class StreamingClips(IterableDataset):
    """Clips drawn from an iterable of scans as it yields them (every clip of each scan, in order).

    `scans` is the iterable, or a picklable function of the data-loader worker's index (0 without
    workers) returning that worker's iterable, so workers do not all yield the same clips.
    `describe` says what the stream is, for checkpoint metadata."""

    def __init__(self, scans: Iterable[Scan] | Callable[[int], Iterable[Scan]], opts: ClipOptions = ClipOptions(),
                 seed: int = 0, describe: dict | None = None):
        self.scans, self.opts, self.seed, self.about = scans, opts, seed, dict(describe or {})

    def __iter__(self) -> Iterator[dict]:
        worker = get_worker_info()
        shard = worker.id if worker is not None else 0
        if not callable(self.scans) and worker is not None and worker.num_workers > 1:
            raise ReconError("streamed training clips with several loader workers need a stream per worker "
                             "(a function of the worker's index), or every worker yields the same clips")
        scans = self.scans(shard) if callable(self.scans) else self.scans
        gen = torch.Generator().manual_seed(self.seed + 1_000_003 * shard)
        for scan in scans:
            scan.validate()
            for start in _clip_starts(scan, self.opts):
                yield make_clip(scan, start, self.opts, gen)

    def describe(self) -> dict:
        return {"stream": type(self.scans).__name__, **self.about, **_describe_clips(self.opts)}



class ShapeBatches(IterableDataset):
    """Batches of `batch_size` equally shaped clips from a stream of clips (a portrait clip and a landscape
    one cannot share a batch): clips wait in one bucket per shape until theirs is full."""

    def __init__(self, clips: IterableDataset, batch_size: int):
        self.clips, self.batch_size = clips, batch_size

    def __iter__(self) -> Iterator[dict]:
        buckets: dict[tuple, list[dict]] = {}
        for clip in self.clips:
            bucket = buckets.setdefault(tuple(clip["images"].shape), [])
            bucket.append(clip)
            if len(bucket) == self.batch_size:
                yield default_collate(bucket)
                bucket.clear()