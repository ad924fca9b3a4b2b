"""`recon`: the command-line front end. Thin: every command calls the Python API.

Each command lives in `apps/commands/<name>.py` with a `register(subparsers)`
function that adds its parser and sets `func(args) -> int`.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from recon.errors import ReconError

# Modules under apps.commands that add subcommands, in help order.
COMMAND_MODULES = ["run", "demo", "batch", "info", "convert", "poses", "depth", "train", "fuse", "evaluate", "bench", "synth"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="recon",
        description="Video of a room to a colored mesh: poses, EST depth, TSDF fusion, evaluation.")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    parser.add_argument("--quiet", "-q", action="store_true", help="only errors and final results")
    parser.add_argument("--verbose", "-v", action="store_true", help="more log lines")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"apps.commands.{name}").register(subparsers)
    for sub in subparsers.choices.values():
        _add_output_flags(sub)
    return parser


def _add_output_flags(parser: argparse.ArgumentParser) -> None:
    """Let --debug/--quiet/--verbose also follow the command (`recon run X --quiet`), at any depth."""
    group = parser.add_argument_group("output")
    group.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show full tracebacks")
    group.add_argument("--quiet", "-q", action="store_true", default=argparse.SUPPRESS, help="only errors and results")
    group.add_argument("--verbose", "-v", action="store_true", default=argparse.SUPPRESS, help="more log lines")
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _add_output_flags(sub)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.quiet else logging.DEBUG if args.verbose else logging.INFO
    logging.basicConfig(level=level, format="%(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ReconError as exc:
        if args.debug:
            raise
        print(f"recon: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("recon: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
