"""The learned inference modes over a scan: ESTM (temporal memory), joint and independent.

Frames are fitted to the network size (`depth.views.network_view`: stretched whole, or scaled to
cover it and centre-cropped so the aspect ratio is kept), predicted there and resampled back to the
scan's size; with `crop`, pixels outside the window get depth 0 (invalid) and confidence 0.

  independent  each frame alone with its sources; the EST transformer sees no memory.
  joint        consecutive groups of `joint_group` frames predicted together, as in
               training: every frame of the group attends to the others.
  estm         frames in order; the EST transformer reads a memory of the last N
               frames' key/value volumes (`TemporalMemory`), the oldest dropped first.

With `mirror_pass` (estm, independent) a second pass runs over the left-right mirrored video, and each
pixel keeps the more confident of the two depths.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import os
from typing import Callable, Iterator

import numpy as np
import torch
import torch.nn.functional as F

from recon.errors import ReconError
from recon.scan import Scan

from .checkpoint import build_model, load_checkpoint
from .config import get_config
from .device import resolve_device, resolve_precision
from .model import ESTNet, MemoryEntry, TargetOutput, TargetState
from .options import (NETWORK_MODES, DepthOptions, FrameDepth, check_scan, frame_sources, scan_depth_range,
                      stored_size)
from .views import describe_view, image_tensor, network_view, to_scan_pixels, view_message

log = logging.getLogger(__name__)


class TemporalMemory:
    """The ESTM memory: key/value volumes of the last `size` estimated frames (FIFO)."""

    def __init__(self, size: int):
        if size < 0:
            raise ReconError(f"ESTM memory size must be >= 0, got {size}")
        self._entries: collections.deque[MemoryEntry] = collections.deque(maxlen=size)

    def add(self, entry: MemoryEntry) -> None:
        self._entries.append(entry.detached())

    @property
    def entries(self) -> list[MemoryEntry]:
        return list(self._entries)

    @property
    def names(self) -> list[str]:
        return [e.name for e in self._entries]

    def __len__(self) -> int:
        return len(self._entries)


MIRROR = np.diag([-1.0, 1.0, 1.0, 1.0])


def mirror_intrinsics(K: np.ndarray, width: int) -> np.ndarray:
    """K of the left-right mirrored image (pixel centres at integers): cx -> width - 1 - cx. (3, 3) -> (3, 3)"""
    out = np.array(K, dtype=np.float64)
    out[0, 2] = width - 1 - out[0, 2]
    return out


def mirror_pose(camera_to_world: np.ndarray) -> np.ndarray:
    """The camera-to-world pose in the mirrored world (x -> -x in world and camera alike), so that the
    mirrored images, mirrored K and these poses form a consistent scan. (..., 4, 4) -> (..., 4, 4)"""
    return MIRROR @ camera_to_world @ MIRROR


class _Pass:
    """One pass of the network over a scan: the fitted view, cached per-frame features, the calls."""

    def __init__(self, estimator: "DepthEstimator", scan: Scan, opts: DepthOptions, capacity: int = 12,
                 mirrored: bool = False):
        cfg, device = estimator.config, estimator.device
        self.scan, self.device, self.mirrored = scan, device, mirrored
        self.sources = frame_sources(scan, opts.sources)
        self.net_scan = network_view(scan, cfg.image_width, cfg.image_height, opts.fit)
        log.info("%s", view_message(describe_view(scan.intrinsics.size, cfg.image_width, cfg.image_height, opts.fit)))
        self.output_size = stored_size(scan.intrinsics.size, (cfg.image_width, cfg.image_height), opts.full_resolution)
        intr = self.net_scan.intrinsics
        K = mirror_intrinsics(intr.K, intr.width) if mirrored else intr.K
        self.K = torch.from_numpy(K).float()[None].to(device)
        self.depth_range = torch.tensor([scan_depth_range(scan, opts.depth_range)], device=device)
        self.features, self.prepare_call, self.finish_call = estimator.network_calls(opts.compile)
        self.normalise = estimator.model.normalise
        self.bf16 = resolve_precision(opts.precision, device) == "bf16"
        self._cache: collections.OrderedDict[int, tuple[torch.Tensor, torch.Tensor]] = collections.OrderedDict()
        self.capacity = capacity

    def precision(self):
        """Autocast is entered per network call, never across a `yield` (it would leak into the caller)."""
        return torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.bf16)

    def frame(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(normalised image (1, 3, H, W), features (1, F, H/4, W/4)) of frame i (small LRU cache)."""
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        image = self.normalise(image_tensor(self.net_scan, i)[None].to(self.device))
        if self.mirrored:
            image = image.flip(-1)
        self._cache[i] = item = (image, self.features(image))
        if len(self._cache) > self.capacity:
            self._cache.popitem(last=False)
        return item

    def pose(self, idx) -> torch.Tensor:
        pose = self.scan.camera_to_world[idx]
        return torch.from_numpy(mirror_pose(pose) if self.mirrored else pose).float().to(self.device)

    def prepare(self, i: int) -> TargetState:
        with self.precision():
            image, feats = self.frame(i)
            src_feats = torch.stack([self.frame(j)[1] for j in self.sources[i]], 1)
            return self.prepare_call(image, feats, src_feats, self.K, self.pose([i]), self.pose(self.sources[i])[None],
                                     self.depth_range)

    def finish(self, state: TargetState, memories: list[MemoryEntry]) -> TargetOutput:
        with self.precision():
            return self.finish_call(state, memories)

    def maps(self, out: TargetOutput) -> tuple[torch.Tensor, torch.Tensor]:
        """(final depth, confidence) on the network grid, (1, 1, h, w) each, mirrored back if need be."""
        depth, confidence = out.depths[3].float(), out.confidence.float()
        return (depth.flip(-1), confidence.flip(-1)) if self.mirrored else (depth, confidence)

    def result(self, i: int, depth: torch.Tensor, confidence: torch.Tensor) -> FrameDepth:
        view = (self.net_scan, self.output_size)
        d = to_scan_pixels(depth, *view)[0, 0].cpu().numpy()
        conf = to_scan_pixels(confidence, *view)[0, 0].cpu().numpy()
        if not np.all(np.isfinite(d)):
            raise ReconError(f"frame {self.scan.frames[i].name}: the network produced non-finite depth")
        return FrameDepth(i, self.scan.frames[i].name, d.astype(np.float32), conf.astype(np.float32),
                          list(self.sources[i]))


def more_confident(maps: list[tuple[torch.Tensor, torch.Tensor]]) -> tuple[torch.Tensor, torch.Tensor]:
    """One (depth, confidence) from several passes over the same frame: per pixel, the pass whose
    confidence is highest. (Their geometric mean measured better depth but blurrier meshes: docs/depth.md.)
    Each pass: depth (1, 1, H, W), confidence (1, 1, h, w) on a grid as fine or coarser."""
    if len(maps) == 1:
        return maps[0]
    depths, confidences = torch.stack([m[0] for m in maps]), torch.stack([m[1] for m in maps])
    best = confidences.argmax(0, keepdim=True)
    best_fine = F.interpolate(best[0].float(), size=depths.shape[-2:], mode="nearest").long()[None]
    return depths.gather(0, best_fine)[0], confidences.gather(0, best)[0]


def _copied(value):
    """A copy of a call's outputs: the tensors, in dataclasses, tuples and lists."""
    if isinstance(value, torch.Tensor):
        return value.clone()
    if dataclasses.is_dataclass(value):
        return dataclasses.replace(value, **{f.name: _copied(getattr(value, f.name))
                                             for f in dataclasses.fields(value) if f.init})
    if isinstance(value, (list, tuple)):
        return type(value)(_copied(v) for v in value)
    return value


def _graph_replay(call: Callable) -> Callable:
    """`call` (compiled with CUDA graphs) returning copies: a graph's next replay overwrites its output
    buffers, while a pass keeps features and memory entries over several frames."""

    def replay(*args, **kwargs):
        torch.compiler.cudagraph_mark_step_begin()
        return _copied(call(*args, **kwargs))

    return replay


class DepthEstimator:
    """A loaded network on a device, ready to run the learned modes over scans."""

    def __init__(self, model: ESTNet, device: torch.device | str = "cpu",
                 trained_depth_range: tuple[float, float] | None = None):
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.config = model.cfg
        # The planes the network was trained on: its context volume is tied to plane indices, so it
        # should sweep the same range unless the caller says otherwise.
        self.trained_depth_range = trained_depth_range
        self._compiled: tuple[Callable, Callable, Callable] | None = None

    def network_calls(self, compile: bool = False) -> tuple[Callable, Callable, Callable]:
        """The network's (frame_features, prepare, finish), compiled by torch.compile when asked (once).

        Shapes are static (one network size), so compiling pays off: the ESTM loop calls these
        three per frame, and the memory's growth from 0 to N entries costs N + 1 compiles. On CUDA
        they are also recorded as CUDA graphs: an eager `paper` frame launches about 1,400 kernels and
        waits on those launches more than on the GPU (docs/depth.md "On a GPU").
        """
        m = self.model
        if not compile:
            return m.frame_features, m.prepare, m.finish
        if self._compiled is None:
            graphs = self.device.type == "cuda"
            calls = (torch.compile(f, dynamic=False, mode="reduce-overhead" if graphs else None)
                     for f in (m.frame_features, m.prepare, m.finish))
            self._compiled = tuple(_graph_replay(c) if graphs else c for c in calls)
        return self._compiled

    @classmethod
    def from_weights(cls, weights: str | os.PathLike, device: str = "auto", config: str | None = None,
                     ) -> "DepthEstimator":
        """Load shipped weights by name (`lite`) or a checkpoint path; `config` names the expected config."""
        ckpt = load_checkpoint(weights, expected=get_config(config) if config else None)
        rng = (ckpt.metadata.get("data") or {}).get("depth_range")
        return cls(build_model(ckpt), resolve_device(device), tuple(float(x) for x in rng) if rng else None)

    @torch.no_grad()
    def run(self, scan: Scan, opts: DepthOptions = DepthOptions(), memory: TemporalMemory | None = None,
            skip: frozenset[int] = frozenset()) -> Iterator[FrameDepth]:
        """Yield every frame's depth in order. `memory` (ESTM) can be passed in to inspect it;
        `skip` lists frame indices not to compute: any frames in independent mode; in estm mode the
        first frames in order, with `memory` holding the entries of the last N of them (a resume)."""
        if opts.mode not in NETWORK_MODES:
            raise ReconError(f"mode {opts.mode!r} is not a network mode ({', '.join(NETWORK_MODES)})")
        opts.validate()
        check_scan(scan)
        run = _Pass(self, scan, opts)
        if opts.mode == "joint":
            yield from self._joint(run, opts.joint_group)
            return
        size = self.config.memory_size if opts.memory_size is None else opts.memory_size
        passes = [(run, memory if memory is not None else TemporalMemory(size))]
        if opts.mirror_pass:
            passes.append((_Pass(self, scan, opts, mirrored=True), TemporalMemory(size)))
        for i in run.sources:
            if i in skip:
                if opts.mode == "estm" and opts.mirror_pass:  # a resume: only the first pass's memory was stored
                    self._step(*passes[1], i, opts.mode)
                continue
            maps = [pass_.maps(self._step(pass_, pass_memory, i, opts.mode)) for pass_, pass_memory in passes]
            yield run.result(i, *more_confident(maps))

    @staticmethod
    def _step(run: _Pass, memory: TemporalMemory, i: int, mode: str) -> TargetOutput:
        """Frame i through the network; in estm mode it reads `memory` and is then added to it."""
        out = run.finish(run.prepare(i), memory.entries if mode == "estm" else [])
        if mode == "estm":
            out.memory.name = run.scan.frames[i].name
            memory.add(out.memory)
        return out

    @staticmethod
    def _joint(run: _Pass, group_size: int) -> Iterator[FrameDepth]:
        order = list(run.sources)
        for start in range(0, len(order), group_size):
            group = order[start:start + group_size]
            states = [run.prepare(i) for i in group]
            entries = [MemoryEntry(s.key, s.value, s.camera_to_world) for s in states]
            for k, (i, state) in enumerate(zip(group, states)):
                out = run.finish(state, [e for j, e in enumerate(entries) if j != k])
                entries[k] = out.memory
                yield run.result(i, *run.maps(out))


