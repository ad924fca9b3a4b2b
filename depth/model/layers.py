"""Small convolution blocks shared by the network parts."""
from __future__ import annotations

from torch import nn


def conv2d_bn(cin: int, cout: int, kernel: int = 3, stride: int = 1, dilation: int = 1,
              relu: bool = True) -> nn.Sequential:
    """Conv2d (no bias) + BatchNorm [+ ReLU], 'same' padding for odd kernels."""
    layers = [nn.Conv2d(cin, cout, kernel, stride, dilation * (kernel // 2), dilation, bias=False),
              nn.BatchNorm2d(cout)]
    if relu:
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


def conv3d_bn(cin: int, cout: int, kernel: int = 3, activation: str | None = "relu") -> nn.Sequential:
    """Conv3d (no bias) + BatchNorm3d [+ ReLU | Tanh] over (C, D, H, W) volumes."""
    layers = [nn.Conv3d(cin, cout, kernel, 1, kernel // 2, bias=False), nn.BatchNorm3d(cout)]
    if activation == "relu":
        layers.append(nn.ReLU(inplace=True))
    elif activation == "tanh":
        layers.append(nn.Tanh())
    elif activation is not None:
        raise ValueError(f"unknown activation {activation!r}")
    return nn.Sequential(*layers)
