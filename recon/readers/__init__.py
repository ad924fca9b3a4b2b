"""Readers for recorded scans: one small module per input format, each returning a canonical `Scan`.

Every reader module exposes `NAME`, `detect(path) -> bool` and `read(path) -> Scan`,
converting poses to camera-to-world with OpenCV axes and depth to metres on the way in.
`open_scan(path, "auto")` picks the first reader whose `detect` accepts the path.
"""
from __future__ import annotations

import os
from pathlib import Path

from recon.errors import ReconError
from recon.scan import Scan

from . import canonical, colmap, nerfstudio, open3d_log, scannet, sevenscenes, simplerecon, stray, tum

# Order matters for detection: the most specific layouts first.
READERS = [canonical, sevenscenes, scannet, tum, open3d_log, simplerecon, stray, colmap, nerfstudio]
FORMATS = [r.NAME for r in READERS]


def detect_format(path: str | os.PathLike) -> str:
    path = Path(path)
    if not path.exists():
        raise ReconError(f"{path}: no such file or folder")
    for reader in READERS:
        if reader.detect(path):
            return reader.NAME
    raise ReconError(f"{path}: unknown scan format (known: {', '.join(FORMATS)})")


def open_scan(path: str | os.PathLike, fmt: str = "auto") -> Scan:
    """Read any supported scan as a validated canonical `Scan` (lazy: pixels load on demand)."""
    path = Path(path)
    if not path.exists():
        raise ReconError(f"{path}: no such file or folder")
    path = path.resolve()  # readers store absolute file paths, so the scan works from any directory
    name = detect_format(path) if fmt == "auto" else fmt
    for reader in READERS:
        if reader.NAME == name:
            scan = reader.read(path)
            scan.metadata.source_format = scan.metadata.source_format or name
            scan.metadata.source = scan.metadata.source or str(path)
            return scan.validate()
    raise ReconError(f"unknown format {fmt!r} (known: auto, {', '.join(FORMATS)})")
