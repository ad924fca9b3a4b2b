"""Frames as the network sees them and back: fitting to the network size, images as tensors."""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from recon.errors import ReconError
from recon.scan import Scan

from .options import FITS


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


def image_tensor(scan: Scan, i: int) -> torch.Tensor:
    """Frame i as a (3, H, W) float tensor in [0, 1]."""
    img = scan.image(i)
    if img.size == 0 or img.ndim != 3 or img.shape[2] != 3:
        raise ReconError(f"frame {scan.frames[i].name}: empty or non-RGB image of shape {img.shape}")
    return torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).float().div_(255.0)
