"""Configuration of the EST depth network: one dataclass, two named configurations.

`paper` reproduces the seed paper's sizes (ResNet-50 ContextNet, PSMNet-sized SPP
features, C = 32, D = 64); `compact` keeps every stage but shrinks channels, block
counts and planes so ESTM inference runs on a laptop CPU. See docs/depth.md.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from recon.errors import ReconError

from .geometry import SPACINGS

FUSIONS = ("adaptive", "concat")
CONTEXT_BLOCKS = ("bottleneck", "basic")
ENCODERS = ("resnet", "efficientnet-lite0")


@dataclass(frozen=True)
class ESTConfig:
    """Every size of the network. Image size is the network input (width x height)."""

    name: str = "custom"
    image_width: int = 320
    image_height: int = 256
    num_planes: int = 64
    plane_spacing: str = "linear"  # "linear" (paper), "inverse" or "log" (same relative step everywhere)
    # Image encoder: "resnet" (the paper: SPP matching features + a ResNet ContextNet, both from scratch
    # or external weights) or "efficientnet-lite0" (one ImageNet-pretrained encoder feeds an FPN for
    # the matching features and the ContextNet decoder; its first blocks and every BatchNorm are frozen)
    encoder: str = "resnet"
    encoder_frozen_blocks: int = 8  # efficientnet-lite0: stem + this many MBConv blocks never train
    # Matching-volume metadata (SimpleRecon-style): per source and plane, the feature dot product
    # and the source-visibility mask join the raw volume
    match_metadata: bool = False
    # SPP matching features (PSMNet style) at 1/4 resolution
    feature_channels: int = 32
    feature_stem_channels: int = 32
    feature_block_counts: tuple[int, ...] = (3, 16, 3, 3)
    feature_block_channels: tuple[int, ...] = (32, 64, 128, 128)
    feature_block_dilations: tuple[int, ...] = (1, 1, 1, 2)
    spp_pool_sizes: tuple[int, ...] = (64, 32, 16, 8)  # in 1/4-resolution pixels
    spp_branch_channels: int = 32
    # MatchNet and the hybrid volume
    volume_channels: int = 32  # C; key and value volumes have C/2
    match_regularisation_layers: int = 4
    # ContextNet: ResNet encoder + decoder to a D-channel map at 1/4 resolution
    context_block: str = "bottleneck"
    context_stem_channels: int = 64
    context_block_counts: tuple[int, ...] = (3, 4, 6, 3)
    context_block_widths: tuple[int, ...] = (64, 128, 256, 512)
    context_decoder_channels: tuple[int, ...] = (256, 128)  # at 1/16 and 1/8
    # EST transformer
    fusion: str = "adaptive"  # "adaptive" (GRU-like gates) or "concat"
    memory_size: int = 2
    # RefineNet (1/2 and full resolution)
    refine_channels: tuple[int, int] = (32, 16)
    # Rescale each refined map to the median of the EST stage's depth, so the image-guided stages shape
    # the depth but cannot move its scale (in `lite` they pulled it toward the training rooms' size)
    refine_keeps_scale: bool = False

    def __post_init__(self):
        if self.fusion not in FUSIONS:
            raise ReconError(f"depth config: fusion must be one of {FUSIONS}, got {self.fusion!r}")
        if self.context_block not in CONTEXT_BLOCKS:
            raise ReconError(f"depth config: context_block must be one of {CONTEXT_BLOCKS}")
        if self.plane_spacing not in SPACINGS:
            raise ReconError(f"depth config: plane_spacing must be one of {SPACINGS}, got {self.plane_spacing!r}")
        if self.encoder not in ENCODERS:
            raise ReconError(f"depth config: encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if self.image_width % 32 or self.image_height % 32:
            raise ReconError(f"depth config: image size {self.image_width}x{self.image_height} "
                             "must be a multiple of 32 (ResNet strides)")
        if self.volume_channels % 2 or self.num_planes < 2 or self.memory_size < 0:
            raise ReconError("depth config: volume_channels must be even, num_planes >= 2, memory_size >= 0")
        if not (len(self.feature_block_counts) == len(self.feature_block_channels)
                == len(self.feature_block_dilations) == 4):
            raise ReconError("depth config: the SPP feature extractor has exactly four block groups")
        if len(self.context_block_counts) != 4 or len(self.context_block_widths) != 4:
            raise ReconError("depth config: the ResNet encoder has exactly four stages")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "ESTConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ReconError(f"depth config: unknown fields {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    def replace(self, **changes) -> "ESTConfig":
        return dataclasses.replace(self, **changes)


PAPER = ESTConfig(name="paper")

COMPACT = ESTConfig(
    name="compact",
    num_planes=48,
    feature_channels=16,
    feature_stem_channels=16,
    feature_block_counts=(1, 2, 1, 1),
    feature_block_channels=(16, 24, 32, 32),
    spp_branch_channels=8,
    volume_channels=16,
    match_regularisation_layers=1,
    context_block="basic",
    context_stem_channels=32,
    context_block_counts=(1, 1, 1, 1),
    context_block_widths=(32, 48, 64, 96),
    context_decoder_channels=(64, 48),
    refine_channels=(16, 8),
    refine_keeps_scale=True,  # the shipped weights since 2026-12-04 (docs/depth.md, "`compact` trained with the rescale")
)

# The v2 configuration (docs/depth.md, "`lite`"): an ImageNet-pretrained EfficientNet-Lite0 encoder, 32 log-spaced
# planes (64 until 2026-12-08: half the time, for the 0.5 s/frame target), match metadata, a scale-keeping
# RefineNet; EST parts as in compact.
LITE = COMPACT.replace(
    name="lite", num_planes=32, plane_spacing="log", encoder="efficientnet-lite0", encoder_frozen_blocks=8,
    match_metadata=True, feature_channels=32, context_decoder_channels=(96, 64), refine_channels=(32, 16))

# Smallest network with every part, for tests and smoke runs (not a shipped configuration).
TINY = COMPACT.replace(
    name="tiny", image_width=96, image_height=64, num_planes=16, volume_channels=8, feature_channels=8,
    feature_stem_channels=8, feature_block_channels=(8, 12, 16, 16), spp_branch_channels=4, context_stem_channels=8,
    context_block_widths=(8, 12, 16, 24), context_decoder_channels=(16, 16), refine_channels=(8, 8))

CONFIGS = {"paper": PAPER, "compact": COMPACT, "lite": LITE}


def get_config(name: str) -> ESTConfig:
    try:
        return CONFIGS[name]
    except KeyError:
        raise ReconError(f"unknown depth network config {name!r} (known: {', '.join(CONFIGS)})") from None
