"""ContextNet: a ResNet encoder-decoder on the reference image -> D-channel context map at 1/4 res.

Module names follow the usual ResNet layout (conv1, bn1, layer1..4, downsample), so an
ImageNet backbone state dict can be loaded with `ContextNet.load_backbone`.
"""
from __future__ import annotations

import os

import torch
import torch.nn.functional as F
from torch import nn

from recon.errors import ReconError

from ..config import ESTConfig
from .layers import conv2d_bn


class BasicBlock(nn.Module):
    expansion = 1

    def __init__(self, cin: int, width: int, stride: int):
        super().__init__()
        cout = width * self.expansion
        self.conv1 = nn.Conv2d(cin, width, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.conv2 = nn.Conv2d(width, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.downsample = (nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
                           if stride != 1 or cin != cout else None)

    def forward(self, x):
        out = F.relu(self.bn1(self.conv1(x)), inplace=True)
        out = self.bn2(self.conv2(out))
        return F.relu(out + (x if self.downsample is None else self.downsample(x)), inplace=True)


class Bottleneck(nn.Module):
    expansion = 4

    def __init__(self, cin: int, width: int, stride: int):
        super().__init__()
        cout = width * self.expansion
        self.conv1 = nn.Conv2d(cin, width, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.conv2 = nn.Conv2d(width, width, 3, stride, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(width)
        self.conv3 = nn.Conv2d(width, cout, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(cout)
        self.downsample = (nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
                           if stride != 1 or cin != cout else None)

    def forward(self, x):
        out = F.relu(self.bn1(self.conv1(x)), inplace=True)
        out = F.relu(self.bn2(self.conv2(out)), inplace=True)
        out = self.bn3(self.conv3(out))
        return F.relu(out + (x if self.downsample is None else self.downsample(x)), inplace=True)


class ResNetEncoder(nn.Module):
    """Image (B, 3, H, W) -> features at 1/2, 1/4, 1/8, 1/16, 1/32 resolution."""

    def __init__(self, cfg: ESTConfig):
        super().__init__()
        block = Bottleneck if cfg.context_block == "bottleneck" else BasicBlock
        s = cfg.context_stem_channels
        self.conv1 = nn.Conv2d(3, s, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(s)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        cin, self.channels = s, [s]
        for i, (n, width) in enumerate(zip(cfg.context_block_counts, cfg.context_block_widths)):
            blocks = []
            for k in range(n):
                blocks.append(block(cin, width, 2 if (k == 0 and i > 0) else 1))
                cin = width * block.expansion
            setattr(self, f"layer{i + 1}", nn.Sequential(*blocks))
            self.channels.append(cin)

    def forward(self, image: torch.Tensor) -> list[torch.Tensor]:
        half = F.relu(self.bn1(self.conv1(image)), inplace=True)
        x = self.layer1(self.maxpool(half))
        feats = [half, x]
        for layer in (self.layer2, self.layer3, self.layer4):
            x = layer(x)
            feats.append(x)
        return feats


class ContextDecoder(nn.Module):
    """Encoder features at 1/2..1/32 -> context map (B, D, H/4, W/4) and the 1/2-res feature.

    The decoder climbs from 1/32 to 1/4 with skip connections (conv, 2x upsample, concat
    skip, conv), ending in D channels: one per depth plane, the 1 x D x H x W context volume.
    `encoder_channels` lists the channels at [1/2, 1/4, 1/8, 1/16, 1/32].
    """

    def __init__(self, encoder_channels: list[int], decoder_channels: tuple[int, ...], num_planes: int):
        super().__init__()
        enc = encoder_channels
        dec = list(decoder_channels) + [num_planes]
        self.up_convs = nn.ModuleList()
        self.skip_convs = nn.ModuleList()
        cin = enc[4]
        for level, cout in zip((3, 2, 1), dec):
            self.up_convs.append(conv2d_bn(cin, cout))
            self.skip_convs.append(conv2d_bn(cout + enc[level], cout))
            cin = cout

    def decode(self, feats: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        x = feats[4]
        for up, skip, level in zip(self.up_convs, self.skip_convs, (3, 2, 1)):
            x = F.interpolate(up(x), size=feats[level].shape[-2:], mode="nearest")
            x = skip(torch.cat([x, feats[level]], 1))
        return x, feats[0]

    forward = decode


class ContextNet(ContextDecoder):
    """The paper's ContextNet: a ResNet encoder on the reference image (B, 3, H, W) + `ContextDecoder`."""

    def __init__(self, cfg: ESTConfig):
        encoder = ResNetEncoder(cfg)
        super().__init__(encoder.channels, cfg.context_decoder_channels, cfg.num_planes)
        self.encoder = encoder

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.decode(self.encoder(image))

    def load_backbone(self, path: str | os.PathLike) -> list[str]:
        """Load ResNet encoder weights (a torchvision-layout state dict file); returns the missing keys.

        Keys may carry a `module.` or `encoder.` prefix; the classifier (`fc.*`) is ignored.
        """
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:
            raise ReconError(f"{path}: unreadable backbone weights ({exc})") from None
        state = state.get("state_dict", state) if isinstance(state, dict) else state
        if not isinstance(state, dict):
            raise ReconError(f"{path}: backbone file holds no state dict")
        cleaned = {}
        for k, v in state.items():
            for prefix in ("module.", "encoder."):
                k = k[len(prefix):] if k.startswith(prefix) else k
            if not k.startswith("fc."):
                cleaned[k] = v
        own = self.encoder.state_dict()
        bad = [k for k, v in cleaned.items() if k not in own or own[k].shape != v.shape]
        if bad:
            raise ReconError(f"{path}: backbone does not match the {len(own)}-tensor encoder "
                             f"(e.g. {bad[0]}); is it the right ResNet depth?")
        result = self.encoder.load_state_dict(cleaned, strict=False)
        return list(result.missing_keys)
