"""Frames as the network sees them and back: the network size turned to the frames' orientation,
fitting to it (stretch / crop, said out loud), images as tensors."""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from recon.errors import ReconError
from recon.scan import Scan

from .options import FITS


def network_size(frame_size: tuple[int, int], width: int, height: int) -> tuple[int, int]:
    """The network input size (w, h) for frames of `frame_size`: width x height turned to the frames'
    orientation, so a portrait clip runs at 256x320 rather than squashed into 320x256. The network
    is size-agnostic (sizes in multiples of 32) and is trained on portrait clips the same way."""
    W, H = frame_size
    return (height, width) if (H > W) != (height > width) and H != W else (width, height)


def describe_view(frame_size: tuple[int, int], width: int, height: int, fit: str) -> dict:
    """What fitting frames to the network does to them, for logs and depth.json: sizes, whether the
    network size was turned, and how much "stretch" changes the aspect ratio (1 = not at all)."""
    w, h = network_size(frame_size, width, height)
    W, H = frame_size
    change = (w / h) / (W / H) if fit == "stretch" else 1.0
    return {"frame_size": [int(W), int(H)], "network_size": [w, h], "turned": (w, h) != (width, height),
            "fit": fit, "aspect_change": round(change, 4)}


def view_message(view: dict) -> str:
    W, H = view["frame_size"]
    w, h = view["network_size"]
    turned = " (network size turned to the frames' portrait orientation)" if view["turned"] else ""
    if view["fit"] == "crop":
        how = "scaled to cover it and centre-cropped, aspect ratio kept"
    elif abs(view["aspect_change"] - 1) < 0.01:
        how = "aspect ratio kept"
    else:
        how = (f"stretched: aspect ratio {W / H:.3f} -> {w / h:.3f}, pixels {view['aspect_change']:.2f}x as wide as "
               "tall (what the network was trained on; --fit crop keeps the aspect ratio)")
    return f"depth: {W}x{H} frames run at {w}x{h}{turned}, {how}"


def network_view(scan: Scan, width: int, height: int, fit: str = "stretch") -> Scan:
    """`scan` as the network sees it: images of the network size (`network_size`: width x height, turned
    for portrait frames), intrinsics following.

    "stretch" resizes the whole frame (pixels turn non-square when the aspect ratios differ);
    "crop" scales the frame to cover the network size and keeps the centre window.
    """
    if fit not in FITS:
        raise ReconError(f"unknown fit {fit!r} (expected one of {', '.join(FITS)})")
    W, H = scan.intrinsics.size
    width, height = network_size((W, H), width, height)
    if fit == "stretch":
        return scan.resized(width, height)
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
