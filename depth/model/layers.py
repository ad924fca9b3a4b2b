"""Small convolution blocks shared by the network parts."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

# oneDNN has no fast 3D kernel for fewer input channels than this; PyTorch then falls back to a
# slow im2col path (about 4x slower for 8 channels on the CPU).
FAST_CONV3D_CHANNELS = 16


def conv2d_bn(cin: int, cout: int, kernel: int = 3, stride: int = 1, dilation: int = 1,
              relu: bool = True) -> nn.Sequential:
    """Conv2d (no bias) + BatchNorm [+ ReLU], 'same' padding for odd kernels."""
    layers = [nn.Conv2d(cin, cout, kernel, stride, dilation * (kernel // 2), dilation, bias=False),
              nn.BatchNorm2d(cout)]
    if relu:
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class Conv3d(nn.Conv3d):
    """nn.Conv3d on the fast CPU kernels, the same function and the same parameters: narrow inputs (and
    the weight) are zero-padded to FAST_CONV3D_CHANNELS channels, and the volume is convolved in
    channels-last layout (oneDNN's blocked kernels: 2-3x faster forward at 16-17 channels, 1.2-2.6x
    forward + backward). The output stays channels-last, so a chain of them converts once (turning it
    back after every conv costs more than it saves: `lite` ESTM 0.76 s/frame kept, 0.93 turned back,
    1.01 without, docs/depth.md)."""

    memory_format = torch.channels_last_3d  # experiments/conv3d_layout.py compares torch.contiguous_format

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        weight, extra = self.weight, FAST_CONV3D_CHANNELS - self.in_channels
        if extra > 0 and self.groups == 1 and self.kernel_size != (1, 1, 1):
            x, weight = F.pad(x, (0, 0, 0, 0, 0, 0, 0, extra)), F.pad(weight, (0, 0, 0, 0, 0, 0, 0, extra))
        layout = self.memory_format
        return self._conv_forward(x.contiguous(memory_format=layout), weight.contiguous(memory_format=layout),
                                  self.bias)


def conv3d_bn(cin: int, cout: int, kernel: int = 3, activation: str | None = "relu") -> nn.Sequential:
    """Conv3d (no bias) + BatchNorm3d [+ ReLU | Tanh] over (C, D, H, W) volumes."""
    layers = [Conv3d(cin, cout, kernel, 1, kernel // 2, bias=False), nn.BatchNorm3d(cout)]
    if activation == "relu":
        layers.append(nn.ReLU(inplace=True))
    elif activation == "tanh":
        layers.append(nn.Tanh())
    elif activation is not None:
        raise ValueError(f"unknown activation {activation!r}")
    return nn.Sequential(*layers)
