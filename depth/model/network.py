"""The EST network: matching features + MatchNet + ContextNet -> hybrid volume -> EST -> depth.

`ESTNet.forward` runs a clip jointly (training, `joint` inference); `prepare` and
`finish` split one target frame into the memory-independent part (features, hybrid
volume, D0) and the EST + refinement part, which ESTM inference drives frame by frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..config import ESTConfig
from ..geometry import depth_planes, scale_intrinsics
from .context import ContextDecoder, ContextNet
from .efficientnet import EfficientNetLite, load_pretrained
from .features import PyramidFeatures, SPPFeatures
from .refine import RefineNet
from .transformer import ESTransformer, MemoryEntry
from .volumes import DepthHead, HybridVolume, MatchNet, soft_argmax_depth

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass
class TargetState:
    """Everything computed for one target frame before the EST transformer (1/4 res: h x w)."""

    image: torch.Tensor  # (B, 3, H, W) normalised
    camera_to_world: torch.Tensor  # (B, 4, 4)
    depth_range: torch.Tensor  # (B, 2)
    planes: torch.Tensor  # (B, D)
    K_quarter: torch.Tensor  # (B, 3, 3)
    context: torch.Tensor  # (B, D, h, w)
    half: torch.Tensor  # (B, Ch, 2h, 2w)
    key: torch.Tensor  # (B, C/2, D, h, w)
    value: torch.Tensor  # (B, C/2, D, h, w)
    depth0: torch.Tensor  # (B, 1, h, w)


@dataclass
class TargetOutput:
    """Depth maps D0..D3 of one target (D0, D1 at 1/4, D2 at 1/2, D3 full res; each (B, 1, ., .)),
    the confidence of D1 (B, 1, h, w) and the memory entry this frame leaves for later frames."""

    depths: list[torch.Tensor]
    confidence: torch.Tensor
    memory: MemoryEntry


class ESTNet(nn.Module):
    """The whole network. With `cfg.encoder == "efficientnet-lite0"` one ImageNet-pretrained
    encoder (`self.encoder`, loaded from its package unless `pretrained=False`) feeds both the
    matching features and the ContextNet decoder; its stem, first `encoder_frozen_blocks` blocks
    and every BatchNorm stay frozen (eval mode, no gradient)."""

    def __init__(self, cfg: ESTConfig, pretrained: bool = True):
        super().__init__()
        self.cfg = cfg
        self.statistics_held = False  # see hold_statistics
        if cfg.encoder == "resnet":
            self.encoder = None
            self.features = SPPFeatures(cfg)
            self.context = ContextNet(cfg)
            half_channels = self.context.encoder.channels[0]
        else:
            self.encoder = EfficientNetLite(classifier=False)
            if pretrained:
                load_pretrained(self.encoder)
            self._freeze_encoder()
            channels = self.encoder.channels
            self.features = PyramidFeatures(channels[1:4], cfg.feature_channels)
            self.context = ContextDecoder(channels, cfg.context_decoder_channels, cfg.num_planes)
            half_channels = channels[0]
        self.matchnet = MatchNet(cfg)
        self.hybrid = HybridVolume(cfg)
        half_c = cfg.volume_channels // 2
        self.head0 = DepthHead(half_c)
        self.transformer = ESTransformer(half_c, cfg.fusion, cfg.plane_spacing)
        self.head1 = DepthHead(half_c)
        self.refine = RefineNet(cfg, half_channels)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def normalise(self, images: torch.Tensor) -> torch.Tensor:
        """RGB in [0, 1], (..., 3, H, W) -> ImageNet-normalised."""
        return (images - self.mean) / self.std

    def _freeze_encoder(self) -> None:
        frozen = {"_conv_stem", "_bn0"} | {f"_blocks.{i}" for i in range(self.cfg.encoder_frozen_blocks)}
        for name, module in self.encoder.named_modules():
            if name in frozen or isinstance(module, nn.BatchNorm2d):
                module.requires_grad_(False)

    def train(self, mode: bool = True) -> "ESTNet":
        """As nn.Module.train, but the pretrained encoder's BatchNorm statistics never move, nor any other's
        once `hold_statistics` was called."""
        super().train(mode)
        held = self if self.statistics_held else self.encoder
        if held is not None:
            for module in held.modules():
                if isinstance(module, (nn.BatchNorm2d, nn.BatchNorm3d)):
                    module.eval()
        return self

    def hold_statistics(self) -> "ESTNet":
        """Every BatchNorm normalises with its running statistics from now on, in training too: a batch-1
        fine-tune then trains the network inference runs, instead of dragging the statistics towards its
        last clip (docs/depth.md, "BatchNorm statistics"). Affine parameters still train."""
        self.statistics_held = True
        return self.train(self.training)

    def pretrained_keys(self) -> set[str]:
        """State-dict keys that come from the encoder package, not from our checkpoints."""
        if self.encoder is None:
            return set()
        trained = {n for n, p in self.encoder.named_parameters() if p.requires_grad}
        return {f"encoder.{k}" for k in self.encoder.state_dict() if k not in trained}

    def stored_state_dict(self) -> dict[str, torch.Tensor]:
        """What a checkpoint holds: every tensor but the frozen pretrained ones."""
        skip = self.pretrained_keys()
        return {k: v for k, v in self.state_dict().items() if k not in skip}

    def frame_features(self, images: torch.Tensor) -> torch.Tensor:
        """Normalised images (N, 3, H, W) -> matching features (N, F, H/4, W/4)."""
        if self.encoder is None:
            return self.features(images)
        return self.features(self.encoder.pyramid(images, 4)[1:])

    def context_map(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Normalised reference image (B, 3, H, W) -> context map (B, D, h, w) and the 1/2-res feature."""
        if self.encoder is None:
            return self.context(image)
        return self.context(self.encoder.pyramid(image))

    def prepare(self, image: torch.Tensor, ref_features: torch.Tensor, src_features: torch.Tensor,
                K: torch.Tensor, camera_to_world: torch.Tensor, src_camera_to_world: torch.Tensor,
                depth_range: torch.Tensor) -> TargetState:
        """One target up to its hybrid volume and D0.

        image (B, 3, H, W) normalised; ref_features (B, F, h, w); src_features (B, S, F, h, w);
        K (B, 3, 3) at H x W; poses (B, 4, 4), (B, S, 4, 4); depth_range (B, 2).
        """
        h, w = ref_features.shape[-2:]
        K4 = scale_intrinsics(K, w / image.shape[-1], h / image.shape[-2])
        planes = depth_planes(depth_range[:, 0], depth_range[:, 1], self.cfg.num_planes, self.cfg.plane_spacing)
        matching = self.matchnet(ref_features, src_features, K4, camera_to_world, src_camera_to_world, planes)
        context, half = self.context_map(image)
        key, value = self.hybrid(matching, context)
        depth0, _ = soft_argmax_depth(self.head0(value), planes)
        return TargetState(image, camera_to_world, depth_range, planes, K4, context, half, key, value, depth0)

    def finish(self, state: TargetState, memories: list[MemoryEntry]) -> TargetOutput:
        """EST fusion with `memories`, depth head and refinement for a prepared target."""
        fused = self.transformer(state.key, state.value, memories, state.camera_to_world, state.K_quarter,
                                 state.planes)
        logits = self.head1(fused)
        depth1, confidence = soft_argmax_depth(logits, state.planes)
        depth2, depth3 = self.refine(depth1, state.context, logits, state.half, state.image, state.depth_range)
        entry = MemoryEntry(state.key, fused, state.camera_to_world)
        return TargetOutput([state.depth0, depth1, depth2, depth3], confidence, entry)

    def forward(self, images: torch.Tensor, K: torch.Tensor, camera_to_world: torch.Tensor,
                depth_range: torch.Tensor, targets: list[tuple[int, tuple[int, ...]]] | None = None,
                memory: list[MemoryEntry] = ()) -> list[TargetOutput]:
        """Joint prediction over a clip.

        images (B, V, 3, H, W) RGB in [0, 1]; K (B, 3, 3) at H x W; camera_to_world (B, V, 4, 4);
        depth_range (B, 2). `targets` lists (reference index, source indices); default: the
        V-2 middle frames, each with its two neighbours. Targets are fused in order: each
        attends to `memory` plus the other targets (earlier ones already fused), as in training.
        """
        b, v = images.shape[:2]
        if targets is None:
            targets = [(t, (t - 1, t + 1)) for t in range(1, v - 1)]
        norm = self.normalise(images.flatten(0, 1))
        feats = self.frame_features(norm).unflatten(0, (b, v))
        norm = norm.unflatten(0, (b, v))
        states = [self.prepare(norm[:, t], feats[:, t], feats[:, list(srcs)], K, camera_to_world[:, t],
                               camera_to_world[:, list(srcs)], depth_range) for t, srcs in targets]
        entries = [MemoryEntry(s.key, s.value, s.camera_to_world) for s in states]
        outputs = []
        for i, state in enumerate(states):
            out = self.finish(state, list(memory) + [e for j, e in enumerate(entries) if j != i])
            entries[i] = out.memory
            outputs.append(out)
        return outputs
