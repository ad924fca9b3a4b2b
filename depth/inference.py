"""Depth for every frame of a canonical scan: ESTM, joint, independent or classical plane sweep.

Frames are fitted to the network size (intrinsics follow through `Scan.resized` and
`Scan.cropped`): stretched whole, or scaled to cover it and centre-cropped so the aspect ratio
is kept (`DepthOptions.fit`). The depth is predicted there and resampled back to the scan's
size; with `crop`, pixels outside the window get depth 0 (invalid) and confidence 0. Each frame's sources are
chosen by pose distance (`depth.selection.select_sources`). Results go to
`recon.io.save_depth_map` (depth + confidence per frame) plus a `depth.json` summary.

Modes:
  independent  each frame alone with its sources; the EST transformer sees no memory.
  joint        consecutive groups of `joint_group` frames predicted together, as in
               training: every frame of the group attends to the others.
  estm         frames in order; the EST transformer reads a memory of the last N
               frames' key/value volumes (`TemporalMemory`), the oldest dropped first.
  planesweep   the classical baseline (`depth.planesweep`), no weights needed.
"""
from __future__ import annotations

import collections
import json
import logging
import os
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch
import torch.nn.functional as F

from recon.errors import ReconError
from recon.io import atomic_path, load_depth_map, save_depth_map, write_json_atomic
from recon.scan import Scan

from .checkpoint import build_model, load_checkpoint, weights_digest
from .config import get_config
from .model import ESTNet, MemoryEntry
from .planesweep import PlaneSweepOptions, plane_sweep_depth, to_gray
from .selection import select_sources

log = logging.getLogger(__name__)

MODES = ("estm", "joint", "independent", "planesweep")
PRECISIONS = ("fp32", "bf16")
FITS = ("stretch", "crop")


@dataclass
class DepthOptions:
    """How to run the depth stage. `depth_range` overrides the scan's metadata range."""

    mode: str = "estm"
    window: str = "offline"  # sources before and after ("offline") or before only ("online")
    memory_size: int | None = None  # ESTM memory length N; None = the network config's (2)
    depth_range: tuple[float, float] | None = None
    num_sources: int = 2
    source_baseline: float = 0.15  # translation the sources should ideally have (DeepVideoMVS)
    min_baseline: float = 0.02  # closer frames cannot triangulate and never serve
    source_window: int = 10  # frames on each side considered as sources
    joint_group: int = 3
    device: str = "auto"
    config: str | None = None  # expected network config name; None accepts the checkpoint's
    precision: str = "fp32"  # "bf16": autocast the network to bfloat16 (CUDA, and CPUs with bf16 units)
    fit: str = "stretch"  # "stretch" the frame to the network size, or "crop" it (aspect kept, borders lost)
    compile: bool = False  # torch.compile the network (a one-off compile of about a minute, then faster frames)
    planesweep: PlaneSweepOptions = field(default_factory=PlaneSweepOptions)


@dataclass
class FrameDepth:
    """One frame's result at the scan's resolution."""

    index: int
    name: str
    depth: np.ndarray  # (H, W) float32 metres, 0 = invalid
    confidence: np.ndarray  # (H, W) float32 in [0, 1]
    sources: list[int]


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


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ReconError("--device cuda requested but no CUDA device is available")
    if name not in ("cpu", "cuda"):
        raise ReconError(f"unknown device {name!r} (auto, cpu or cuda)")
    return torch.device(name)


def scan_depth_range(scan: Scan, override: tuple[float, float] | None = None) -> tuple[float, float]:
    """The depth range to sweep: the override, else the scan's metadata; validated."""
    rng = override or scan.metadata.depth_range
    if rng is None:
        raise ReconError(f"{scan.root or 'scan'}: no depth range in the scan metadata; pass one "
                         "(--depth-range MIN MAX, in scan units)")
    lo, hi = float(rng[0]), float(rng[1])
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ReconError(f"invalid depth range {rng!r}: need 0 < min < max")
    return lo, hi


def network_view(scan: Scan, width: int, height: int, fit: str = "stretch") -> Scan:
    """`scan` as the network sees it: width x height images, intrinsics following.

    "stretch" resizes the whole frame (pixels turn non-square when the aspect ratios differ);
    "crop" scales the frame to cover width x height and keeps the centre window.
    """
    if fit not in FITS:
        raise ReconError(f"unknown fit {fit!r} (expected one of {', '.join(FITS)})")
    if fit == "stretch":
        return scan.resized(width, height)
    W, H = scan.intrinsics.size
    scale = max(width / W, height / H)
    cover_w, cover_h = max(width, round(W * scale)), max(height, round(H * scale))
    return scan.resized(cover_w, cover_h).cropped((cover_w - width) // 2, (cover_h - height) // 2, width, height)


def to_scan_pixels(maps: torch.Tensor, net_scan: Scan, size: tuple[int, int]) -> torch.Tensor:
    """Resample network-size maps back onto the scan's pixels (bilinear).

    maps: (B, C, h, w) on the grid of `net_scan` (from `network_view`); size: the scan's (width, height).
    Returns (B, C, H, W) maps, zero at pixels outside the network window (a crop).
    """
    W, H = size
    cover_w, cover_h = net_scan.output_size
    left, top, w, h = net_scan.crop or (0, 0, cover_w, cover_h)
    # pixel centre u of the scan -> continuous coordinate in the network window (0 .. w at its edges)
    x = (torch.arange(W, dtype=torch.float32, device=maps.device) + 0.5) * (cover_w / W) - left
    y = (torch.arange(H, dtype=torch.float32, device=maps.device) + 0.5) * (cover_h / H) - top
    inside = ((y >= 0) & (y <= h))[:, None] & ((x >= 0) & (x <= w))[None, :]
    grid = torch.stack(torch.meshgrid(x / w * 2 - 1, y / h * 2 - 1, indexing="xy"), -1)
    out = F.grid_sample(maps.float(), grid[None].expand(maps.shape[0], -1, -1, -1), mode="bilinear",
                        padding_mode="border", align_corners=False)
    return out * inside


def _check_scan(scan: Scan) -> None:
    scan.validate()  # poses: shape, finite, rigid
    if len(scan) < 3:
        raise ReconError(f"{scan.root or 'scan'}: depth needs at least 3 frames (a reference and two sources), "
                         f"got {len(scan)}")


def _image_tensor(scan: Scan, i: int) -> torch.Tensor:
    img = scan.image(i)
    if img.size == 0 or img.ndim != 3 or img.shape[2] != 3:
        raise ReconError(f"frame {scan.frames[i].name}: empty or non-RGB image of shape {img.shape}")
    return torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).float().div_(255.0)


def _sources(scan: Scan, opts: DepthOptions) -> dict[int, list[int]]:
    """Sources of every frame to estimate, by frame index.

    An online window cannot serve the first frames of a video (no past yet): they are
    skipped until the first frame with enough past sources. Any other frame without
    `num_sources` usable sources is an error naming it.
    """
    ranked = select_sources(scan.camera_to_world, opts.num_sources, opts.window, opts.source_baseline,
                            opts.min_baseline, opts.source_window)
    chosen: dict[int, list[int]] = {}
    for i in range(len(scan)):
        if len(ranked[i]) >= opts.num_sources:
            chosen[i] = ranked[i]
        elif opts.window == "online" and not chosen and i < len(scan) - 1:
            log.info("online window: frame %s has too little past, skipped", scan.frames[i].name)
        else:
            raise ReconError(
                f"{scan.root or 'scan'} frame {scan.frames[i].name}: only {len(ranked[i])} usable source frame(s) "
                f"(pose distance >= {opts.min_baseline} within {opts.source_window} frames, {opts.window} window); "
                "the camera barely moves here - use frames with more motion (--stride, --keyframe-distance)")
    return chosen


class _FrameStore:
    """Network-size images and matching features of recently used frames (small LRU)."""

    def __init__(self, model: ESTNet, features: Callable, scan: Scan, device: torch.device, capacity: int = 12):
        self.model, self.features, self.scan, self.device, self.capacity = model, features, scan, device, capacity
        self._cache: collections.OrderedDict[int, tuple[torch.Tensor, torch.Tensor]] = collections.OrderedDict()

    def get(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(normalised image (1, 3, H, W), features (1, F, H/4, W/4)) of frame i."""
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        image = self.model.normalise(_image_tensor(self.scan, i)[None].to(self.device))
        item = (image, self.features(image))
        self._cache[i] = item
        if len(self._cache) > self.capacity:
            self._cache.popitem(last=False)
        return item


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
        three per frame, and the memory's growth from 0 to N entries costs N + 1 compiles.
        """
        m = self.model
        if not compile:
            return m.frame_features, m.prepare, m.finish
        if self._compiled is None:
            self._compiled = tuple(torch.compile(f, dynamic=False) for f in (m.frame_features, m.prepare, m.finish))
        return self._compiled

    @classmethod
    def from_weights(cls, weights: str | os.PathLike, device: str = "auto", config: str | None = None,
                     ) -> "DepthEstimator":
        """Load shipped weights by name (`compact`) or a checkpoint path; `config` names the expected config."""
        ckpt = load_checkpoint(weights, expected=get_config(config) if config else None)
        rng = (ckpt.metadata.get("data") or {}).get("depth_range")
        return cls(build_model(ckpt), resolve_device(device), tuple(float(x) for x in rng) if rng else None)

    def _pose(self, scan: Scan, idx) -> torch.Tensor:
        return torch.from_numpy(scan.camera_to_world[idx]).float().to(self.device)

    @torch.no_grad()
    def run(self, scan: Scan, opts: DepthOptions = DepthOptions(), memory: TemporalMemory | None = None,
            skip: frozenset[int] = frozenset()) -> Iterator[FrameDepth]:
        """Yield every frame's depth in order. `memory` (ESTM) can be passed in to inspect it;
        `skip` lists frame indices not to compute: any frames in independent mode; in estm mode the
        first frames in order, with `memory` holding the entries of the last N of them (a resume)."""
        if opts.mode not in ("estm", "joint", "independent"):
            raise ReconError(f"mode {opts.mode!r} is not a network mode (estm, joint, independent)")
        if opts.precision not in PRECISIONS:
            raise ReconError(f"unknown precision {opts.precision!r} (expected one of {', '.join(PRECISIONS)})")
        _check_scan(scan)
        lo, hi = scan_depth_range(scan, opts.depth_range)
        sources = _sources(scan, opts)
        cfg = self.config
        net_scan = network_view(scan, cfg.image_width, cfg.image_height, opts.fit)
        K = torch.from_numpy(net_scan.intrinsics.K).float()[None].to(self.device)
        depth_range = torch.tensor([[lo, hi]], device=self.device)
        view = (net_scan, scan.intrinsics.size)
        features, prepare, finish = self.network_calls(opts.compile)
        store = _FrameStore(self.model, features, net_scan, self.device)
        # Autocast is entered per network call, never across a `yield` (it would leak into the caller).
        def precision():
            return torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=opts.precision == "bf16")

        if opts.mode == "joint":
            yield from self._run_joint(scan, store, sources, K, depth_range, view, opts, precision, prepare, finish)
            return
        if memory is None:
            memory = TemporalMemory(cfg.memory_size if opts.memory_size is None else opts.memory_size)
        for i in sources:
            if opts.mode in ("independent", "estm") and i in skip:
                continue
            with precision():
                image, feats = store.get(i)
                src_feats = torch.stack([store.get(j)[1] for j in sources[i]], 1)
                state = prepare(image, feats, src_feats, K, self._pose(scan, [i]),
                                self._pose(scan, sources[i])[None], depth_range)
                out = finish(state, memory.entries if opts.mode == "estm" else [])
            if opts.mode == "estm":
                out.memory.name = scan.frames[i].name
                memory.add(out.memory)
            yield self._result(scan, i, sources[i], out.depths[3], out.confidence, view)

    def _run_joint(self, scan, store, sources, K, depth_range, view, opts, precision, prepare, finish
                   ) -> Iterator[FrameDepth]:
        order = list(sources)
        for start in range(0, len(order), opts.joint_group):
            group = order[start:start + opts.joint_group]
            states = []
            with precision():
                for i in group:
                    image, feats = store.get(i)
                    src_feats = torch.stack([store.get(j)[1] for j in sources[i]], 1)
                    states.append(prepare(image, feats, src_feats, K, self._pose(scan, [i]),
                                          self._pose(scan, sources[i])[None], depth_range))
            entries = [MemoryEntry(s.key, s.value, s.camera_to_world) for s in states]
            for k, (i, state) in enumerate(zip(group, states)):
                with precision():
                    out = finish(state, [e for j, e in enumerate(entries) if j != k])
                entries[k] = out.memory
                yield self._result(scan, i, sources[i], out.depths[3], out.confidence, view)

    @staticmethod
    def _result(scan, i, srcs, depth, confidence, view) -> FrameDepth:
        d = to_scan_pixels(depth, *view)[0, 0].cpu().numpy()
        conf = to_scan_pixels(confidence, *view)[0, 0].cpu().numpy()
        if not np.all(np.isfinite(d)):
            raise ReconError(f"frame {scan.frames[i].name}: the network produced non-finite depth")
        return FrameDepth(i, scan.frames[i].name, d.astype(np.float32), conf.astype(np.float32), list(srcs))


def run_planesweep(scan: Scan, opts: DepthOptions = DepthOptions(),
                   skip: frozenset[int] = frozenset()) -> Iterator[FrameDepth]:
    """The classical baseline over every frame but `skip` (working width `opts.planesweep.width`)."""
    _check_scan(scan)
    lo, hi = scan_depth_range(scan, opts.depth_range)
    sources = _sources(scan, opts)
    intr = scan.intrinsics
    width = min(opts.planesweep.width, intr.width)
    height = max(8, int(round(intr.height * width / intr.width)))
    work = scan.resized(width, height)
    device = resolve_device(opts.device)
    K = torch.from_numpy(work.intrinsics.K).float().to(device)
    poses = torch.from_numpy(scan.camera_to_world).float().to(device)
    cache: collections.OrderedDict[int, torch.Tensor] = collections.OrderedDict()

    def gray(i: int) -> torch.Tensor:
        if i not in cache:
            cache[i] = to_gray(_image_tensor(work, i).to(device))
            if len(cache) > 12:
                cache.popitem(last=False)
        return cache[i]

    for i, srcs in sources.items():
        if i in skip:
            continue
        depth, conf = plane_sweep_depth(gray(i), torch.stack([gray(j) for j in srcs]), K, poses[i], poses[srcs],
                                        (lo, hi), opts.planesweep)
        size = (intr.height, intr.width)
        depth = F.interpolate(depth[None, None], size, mode="nearest")[0, 0]
        conf = F.interpolate(conf[None, None], size, mode="nearest")[0, 0]
        yield FrameDepth(i, scan.frames[i].name, depth.cpu().numpy(), conf.cpu().numpy(), list(srcs))


def _settings(scan: Scan, opts: DepthOptions, weights, config_name: str | None) -> dict:
    """What determines the output maps; a resumed run reuses files only when these match."""
    return {"mode": opts.mode, "window": opts.window, "depth_range": list(scan_depth_range(scan, opts.depth_range)),
            "memory_size": opts.memory_size, "num_sources": opts.num_sources,
            "source_baseline": opts.source_baseline, "min_baseline": opts.min_baseline,
            "source_window": opts.source_window,
            "joint_group": opts.joint_group, "precision": opts.precision,
            "fit": opts.fit if opts.mode != "planesweep" else None, "config": config_name,
            "weights": str(weights) if weights else None,
            "weights_digest": weights_digest(weights) if weights else None,
            "planesweep": asdict(opts.planesweep) if opts.mode == "planesweep" else None,
            "names": scan.names}


MEMORY_DIR = ".estm-memory"  # the last N memory entries of an unfinished ESTM run, so it can resume exactly


def _save_memory_entry(out_dir: Path, entry: MemoryEntry) -> None:
    path = out_dir / MEMORY_DIR / f"{entry.name}.pt"
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save({"key": entry.key.cpu(), "value": entry.value.cpu(),
                    "camera_to_world": entry.camera_to_world.cpu(), "name": entry.name}, tmp)


def _prune_memory_entries(out_dir: Path, keep: set[str]) -> None:
    for path in (out_dir / MEMORY_DIR).glob("*.pt"):
        if path.stem not in keep:
            path.unlink(missing_ok=True)


def _resumable_estm_prefix(scan: Scan, opts: DepthOptions, out_dir: Path, device: torch.device
                           ) -> tuple[frozenset[int], TemporalMemory]:
    """Frames an interrupted ESTM run finished (a prefix in processing order) and its memory at that point.

    Falls back to a full restart (empty skip) when an entry the memory needs is missing.
    """
    memory = TemporalMemory(opts.memory_size)
    done = []
    for i in _sources(scan, opts):
        if not (out_dir / f"{scan.names[i]}.conf.npy").is_file():
            break
        done.append(i)
    needed = done[len(done) - opts.memory_size:] if opts.memory_size else []
    for i in needed:
        path = out_dir / MEMORY_DIR / f"{scan.names[i]}.pt"
        try:
            doc = torch.load(path, map_location=device, weights_only=True)
        except (OSError, RuntimeError, EOFError):
            log.info("depth: memory entry %s missing, ESTM restarts from the first frame", path.name)
            return frozenset(), TemporalMemory(opts.memory_size)
        memory.add(MemoryEntry(doc["key"], doc["value"], doc["camera_to_world"], doc["name"]))
    log.info("depth: resuming ESTM after %d finished frames", len(done))
    return frozenset(done), memory


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def estimate_depth(scan: Scan, out_dir: str | os.PathLike, opts: DepthOptions = DepthOptions(),
                   weights: str | os.PathLike | None = None, estimator: DepthEstimator | None = None,
                   progress: Callable[[int, int], None] | None = None, resume: bool = False) -> dict:
    """Run the depth stage over `scan`, writing `<name>.npy/.png/.conf.npy` and `depth.json` to `out_dir`.

    Learned modes need `weights` (a shipped name or checkpoint path) or a ready `estimator`.
    With `resume`, a finished run with the same settings is returned as is, and an interrupted
    `planesweep` / `independent` run keeps the frames it finished (ESTM and joint restart:
    their frames depend on the ones before). Returns the summary written to depth.json.
    """
    if opts.mode not in MODES:
        raise ReconError(f"unknown depth mode {opts.mode!r} (expected one of {', '.join(MODES)})")
    out_dir = Path(out_dir)
    if opts.mode != "planesweep":
        if estimator is None:
            if weights is None:
                raise ReconError(f"--mode {opts.mode} needs network weights: pass --weights NAME|PATH "
                                 "(e.g. a checkpoint from `recon train`), or use --mode planesweep")
            estimator = DepthEstimator.from_weights(weights, opts.device, opts.config)
        if opts.memory_size is None:
            opts = replace(opts, memory_size=estimator.config.memory_size)
        if opts.depth_range is None and estimator.trained_depth_range is not None:
            opts = replace(opts, depth_range=estimator.trained_depth_range)
    settings = _settings(scan, opts, weights if estimator else None, estimator.config.name if estimator else None)
    summary_path, partial_path = out_dir / "depth.json", out_dir / "depth.partial.json"
    skip: frozenset[int] = frozenset()
    memory = TemporalMemory(opts.memory_size) if opts.mode == "estm" else None
    if resume:
        previous = _read_json(summary_path)
        if previous and previous.get("settings") == settings and all(
                (out_dir / f"{f['name']}.npy").is_file() for f in previous["frames"]):
            log.info("depth: %s is complete, reusing it", out_dir)
            return previous
        partial = _read_json(partial_path)
        if partial and partial.get("settings") == settings and opts.mode in ("planesweep", "independent"):
            skip = frozenset(i for i, n in enumerate(scan.names) if (out_dir / f"{n}.conf.npy").is_file())
        elif partial and partial.get("settings") == settings and opts.mode == "estm":
            skip, memory = _resumable_estm_prefix(scan, opts, out_dir, estimator.device)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(partial_path, {"settings": settings})
    started = time.perf_counter()
    if estimator is None:
        results = run_planesweep(scan, opts, skip)
    else:
        results = estimator.run(scan, opts, memory=memory, skip=skip)
    frames = {}
    for r in results:
        if memory is not None:  # the entry first: a frame whose maps exist always has its entry on disk
            _save_memory_entry(out_dir, memory.entries[-1])
        save_depth_map(out_dir, r.name, r.depth, r.confidence)
        if memory is not None:
            _prune_memory_entries(out_dir, keep=set(memory.names))
        frames[r.index] = {"name": r.name, "sources": [scan.frames[j].name for j in r.sources],
                           "valid_fraction": float((r.depth > 0).mean())}
        if progress:
            progress(r.index + 1, len(scan))
    if skip:
        sources = _sources(scan, opts)
        for i in skip:
            depth = load_depth_map(out_dir, scan.names[i])
            frames[i] = {"name": scan.names[i], "sources": [scan.frames[j].name for j in sources[i]],
                         "valid_fraction": float((depth > 0).mean()), "reused": True}
    frames = [frames[i] for i in sorted(frames)]
    seconds = time.perf_counter() - started
    computed = max(len(frames) - len(skip), 1)
    summary = {**{k: v for k, v in settings.items() if k != "names"}, "settings": settings, "frames": frames,
               "skipped": [n for n in scan.names if n not in {f["name"] for f in frames}], "seconds": seconds,
               "seconds_per_frame": seconds / computed}
    write_json_atomic(summary_path, summary)
    partial_path.unlink(missing_ok=True)
    shutil.rmtree(out_dir / MEMORY_DIR, ignore_errors=True)
    log.info("depth: %d frames in %.1f s (%s)", len(frames), seconds, opts.mode)
    return summary
