"""Contact sheets: rendered frames beside their depth maps, to check by eye that scenes read as rooms."""
from __future__ import annotations

import cv2
import numpy as np

from recon.scan import Scan


def colorize_depth(depth_m: np.ndarray, max_depth_m: float = 7.0) -> np.ndarray:
    """uint8 RGB picture of a depth map (turbo colors, near = blue; invalid = black)."""
    scaled = np.clip(depth_m / max_depth_m * 255, 0, 255).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[depth_m <= 0] = 0
    return rgb


def contact_sheet(scans: list[Scan], frames_per_scan: int = 3, tile_width: int = 240) -> np.ndarray:
    """One row per scan: `frames_per_scan` evenly spaced frames, each followed by its depth map."""
    rows = []
    for scan in scans:
        picks = np.linspace(0, len(scan) - 1, frames_per_scan).round().astype(int)
        tiles = []
        for i in picks:
            image, depth = scan.image(int(i)), scan.depth(int(i))
            tile_height = int(round(tile_width * image.shape[0] / image.shape[1]))
            tiles.append(cv2.resize(image, (tile_width, tile_height), interpolation=cv2.INTER_AREA))
            depth_tile = colorize_depth(depth) if depth is not None else np.zeros_like(image)
            tiles.append(cv2.resize(depth_tile, (tile_width, tile_height), interpolation=cv2.INTER_NEAREST))
        rows.append(np.concatenate(tiles, axis=1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(rows, axis=0)[:-4]
