"""Argument helpers shared by the commands: frame selection, scan opening, JSON output."""
from __future__ import annotations

import argparse
import json
import sys

from recon.scan import Scan


def add_selection_args(parser: argparse.ArgumentParser) -> None:
    """--start/--stride/--max-frames: every command that takes a scan accepts them."""
    g = parser.add_argument_group("frame selection")
    g.add_argument("--start", type=int, default=0, metavar="N", help="first frame to use (default 0)")
    g.add_argument("--stride", type=int, default=1, metavar="N", help="use every N-th frame (default 1)")
    g.add_argument("--max-frames", type=int, default=None, metavar="N", help="use at most N frames")


def add_scan_args(parser: argparse.ArgumentParser, name: str = "scan", help: str = "scan folder or file") -> None:
    parser.add_argument(name, help=f"{help} (any supported format, see `recon info --formats`)")
    parser.add_argument("--format", default="auto", help="input format (default: auto-detect)")
    add_selection_args(parser)


def open_selected_scan(path: str, args: argparse.Namespace) -> Scan:
    """Open a scan with the reader named by --format and apply the frame selection."""
    from poses.readers import open_scan

    scan = open_scan(path, getattr(args, "format", "auto"))
    return scan.select(args.start, args.stride, args.max_frames)


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")
