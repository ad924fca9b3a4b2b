"""Helpers shared by the commands: scan opening, sizes, JSON output (the options themselves: apps.options)."""
from __future__ import annotations

import argparse
import json
import re
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the commands import this module to build their parsers: no numpy or OpenCV here
    from recon.scan import Scan


def open_selected_scan(path: str, args: argparse.Namespace) -> "Scan":
    """Open a scan with the reader named by --format and apply the frame selection."""
    from recon.readers import open_scan

    scan = open_scan(path, getattr(args, "format", "auto"))
    return scan.select(args.start, args.stride, args.max_frames)


MAX_IMAGE_SIDE = 4096  # larger sizes are typos (and would exhaust memory)


def parse_size(text: str, option: str = "--size", multiple: int = 1) -> tuple[int, int]:
    """'WxH' -> (W, H), each in [1, MAX_IMAGE_SIDE] and a multiple of `multiple`; else a one-line ReconError."""
    from recon.errors import ReconError

    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise ReconError(f"{option}: expected WIDTHxHEIGHT such as 320x256, got {text!r}")
    w, h = int(m.group(1)), int(m.group(2))
    if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE) or w % multiple or h % multiple:
        rule = f" and multiples of {multiple}" if multiple > 1 else ""
        raise ReconError(f"{option} {text}: width and height must be in 1..{MAX_IMAGE_SIDE}{rule}")
    return w, h


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")
