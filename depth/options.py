"""How the depth stage runs (`DepthOptions`), what it yields per frame, and which frames and sources.

The options are the depth stage's config: `recon run` composes them into its run config and
`recon depth` builds them from the same command-line options.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from recon.errors import ReconError, naming
from recon.io import working_size
from recon.keyframes import SourceConfig, select_sources
from recon.scan import Scan


log = logging.getLogger(__name__)

MODES = ("estm", "joint", "independent", "planesweep", "hybrid")
NETWORK_MODES = MODES[:3]
PRECISIONS = ("auto", "fp32", "bf16")
FITS = ("stretch", "crop")


@dataclass(frozen=True)
class PlaneSweepOptions:
    """The classical plane sweep (`depth.planesweep`)."""

    num_planes: int = 64
    spacing: str = "inverse"
    ncc_window: int = 7
    aggregation_window: int = 5
    min_score: float = 0.5  # NCC of the chosen plane
    min_texture: float = 4e-4  # variance of the reference window, intensities in [0, 1]
    min_agreeing_sources: int = 2
    agreement_planes: float = 2.0
    width: int = 320  # working width (height follows the aspect ratio)
    refine_band: float = 0.5  # `hybrid`: the sweep around the network's depth spans depth x (1 +- band)
    refine_steps: int = 33  # `hybrid`: depths tried per pixel in that band
    refine_min_score: float = 0.3  # `hybrid`: NCC a refined pixel's match needs (the band already rules out far matches)
    refine_agreement: bool = False  # `hybrid`: also ask the sources to agree (min_agreeing_sources, agreement_planes steps)


@dataclass(frozen=True)
class AdaptOptions:
    """Test-time adaptation of the network to the scan (`depth.adapt`); the settings were chosen on the
    held-out synthetic scans and ICL-NUIM, never on 7-Scenes."""

    steps: int = 0  # optimiser steps; 0 = no adaptation
    lr: float = 1e-5  # Adam; 2e-5 already lost on a held-out room
    clip_length: int = 5  # as training: the middle clip_length - 2 frames are the targets
    smoothness: float = 1e-3  # weight of the edge-aware smoothness
    anchor: float = 0.0  # weight of the mean |log depth - log unadapted depth| (0: no pull back)
    seed: int = 0  # order of the clips

    def validate(self) -> "AdaptOptions":
        if self.steps < 0:
            raise ReconError(f"--adapt-steps must be >= 0, got {self.steps}")
        if not 0 < self.lr < 1:
            raise ReconError(f"--adapt-lr must be in (0, 1), got {self.lr}")
        if self.anchor < 0 or self.smoothness < 0:
            raise ReconError(f"adaptation weights must be >= 0, got anchor {self.anchor}, smoothness {self.smoothness}")
        if self.clip_length < 3:
            raise ReconError(f"adaptation clips need at least 3 frames, got {self.clip_length}")
        return self


@dataclass
class FrameDepth:
    """One frame's result on its stored grid (`stored_size`: the scan's aspect, the working resolution)."""

    index: int
    name: str
    depth: np.ndarray  # (h, w) float32 metres, 0 = invalid
    confidence: np.ndarray  # (h, w) float32 in [0, 1]
    sources: list[int]


@dataclass(frozen=True)
class DepthOptions:
    """`depth_range` overrides the scan's metadata range (and the weights' trained range)."""

    mode: str = "estm"
    weights: str | None = None  # shipped name or checkpoint path; None: the shipped default (learned modes)
    memory_size: int | None = None  # ESTM memory length N; None = the network config's (2)
    depth_range: tuple[float, float] | None = None
    sources: SourceConfig = field(default_factory=SourceConfig)
    joint_group: int = 3
    device: str = "auto"
    config: str | None = None  # expected network config name; None accepts the checkpoint's
    # network arithmetic: "bf16" autocast, "fp32", or "auto": bf16 where the device computes it in hardware (a
    # CUDA GPU, a CPU with AMX or AVX512-BF16: 1.5x faster ESTM, the same depth, docs/depth.md), else fp32
    precision: str = "auto"
    fit: str = "stretch"  # "stretch" the frame to the network size, or "crop" it (aspect kept, borders lost)
    compile: bool = False  # torch.compile the network (a one-off compile of about a minute, then faster frames)
    mirror_pass: bool = False  # also run the left-right mirrored video; each pixel keeps the more confident depth (2x time)
    full_resolution: bool = False  # store maps at the scan's resolution instead of the working one (`stored_size`)
    planesweep: PlaneSweepOptions = field(default_factory=PlaneSweepOptions)
    adapt: AdaptOptions = field(default_factory=AdaptOptions)  # test-time adaptation of the network (off by default)

    def validate(self) -> "DepthOptions":
        """Refuse bad values before any work (one line naming the option)."""
        for name, value, allowed in (("mode", self.mode, MODES), ("precision", self.precision, PRECISIONS),
                                     ("fit", self.fit, FITS)):
            if value not in allowed:
                raise ReconError(f"unknown depth {name} {value!r} (expected one of {', '.join(allowed)})")
        if self.memory_size is not None and self.memory_size < 0:
            raise ReconError(f"--memory must be >= 0, got {self.memory_size}")
        if self.depth_range is not None:
            with naming("--depth-range"):
                check_depth_range(self.depth_range)
        if not (0 < self.planesweep.refine_band < 10 and self.planesweep.refine_steps >= 3):
            raise ReconError("hybrid refinement: refine_band must be in (0, 10) and refine_steps >= 3, got "
                             f"{self.planesweep.refine_band}, {self.planesweep.refine_steps}")
        if self.mirror_pass and self.mode not in ("estm", "independent", "hybrid"):
            raise ReconError(f"--mirror-pass needs a network mode that runs frame by frame (estm, independent, "
                             f"hybrid), not {self.mode}")
        if self.adapt.validate().steps and self.mode not in NETWORK_MODES + ("hybrid",):
            raise ReconError(f"--adapt-steps adapts a network: mode {self.mode} runs none")
        self.sources.validate()
        return self


def stored_size(scan_size: tuple[int, int], work_size: tuple[int, int], full_resolution: bool = False
                ) -> tuple[int, int]:
    """(w, h) of the grid a frame's depth is stored on: the scan's own with `full_resolution`, else the scan's
    aspect ratio with the long side of the working size (the network's or the sweep's). Upsampling adds no
    information, and a full-resolution float map per frame outweighs the input many times over."""
    width, height = scan_size
    return (width, height) if full_resolution else working_size(width, height, max(work_size))


def check_depth_range(rng) -> tuple[float, float]:
    lo, hi = float(rng[0]), float(rng[1])
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ReconError(f"invalid depth range {tuple(rng)!r}: need 0 < min < max")
    return lo, hi


def scan_depth_range(scan: Scan, override: tuple[float, float] | None = None) -> tuple[float, float]:
    """The depth range to sweep: the override, else the scan's metadata; validated."""
    rng = override or scan.metadata.depth_range
    if rng is None:
        raise ReconError(f"{scan.root or 'scan'}: no depth range in the scan metadata; pass one "
                         "(--depth-range MIN MAX, in scan units)")
    return check_depth_range(rng)


def check_scan(scan: Scan) -> None:
    scan.validate()  # poses: shape, finite, rigid
    if len(scan) < 3:
        raise ReconError(f"{scan.root or 'scan'}: depth needs at least 3 frames (a reference and two sources), "
                         f"got {len(scan)}")


def frame_sources(scan: Scan, sources: SourceConfig) -> dict[int, list[int]]:
    """Sources of every frame to estimate, by frame index.

    An online window cannot serve the first frames of a video (no past yet): they are
    skipped until the first frame with enough past sources. Any other frame without
    `num_sources` usable sources is an error naming it.
    """
    ranked = select_sources(scan.camera_to_world, sources)
    chosen: dict[int, list[int]] = {}
    for i in range(len(scan)):
        if len(ranked[i]) >= sources.num_sources:
            chosen[i] = ranked[i]
        elif sources.window == "online" and not chosen and i < len(scan) - 1:
            log.info("online window: frame %s has too little past, skipped", scan.frames[i].name)
        else:
            raise ReconError(
                f"{scan.root or 'scan'} frame {scan.frames[i].name}: only {len(ranked[i])} usable source frame(s) "
                f"(pose distance >= {sources.min_baseline} within {sources.source_window} frames, {sources.window} "
                "window); the camera barely moves here - use frames with more motion (--stride, --keyframe-distance)")
    return chosen
