"""`recon`: the command-line front end. Thin: every command calls the Python API.

Each command lives in `apps/commands/<name>.py` with a `register(subparsers)`
function that adds its parser and sets `func(args) -> int`.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from apps.commands import CommandParser, DefaultsHelpFormatter
from apps.progress import setup_logging
from recon.errors import ReconError

# Modules under apps.commands that add subcommands, in help order.
COMMAND_MODULES = ["run", "demo", "batch", "export", "info", "convert", "poses", "depth", "train", "fuse", "evaluate",
                   "bench", "synth"]


def version() -> str:
    from importlib.metadata import PackageNotFoundError, version as package_version

    try:
        return package_version("recon-est")
    except PackageNotFoundError:  # a checkout used without `pip install -e .`
        return "unknown (not installed)"


class VersionAction(argparse.Action):
    """--version, looked up only when asked (importlib.metadata costs a tenth of `recon --help`)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"recon {version()}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    """The whole command line; each command's own arguments are added only when it is used."""
    parser = argparse.ArgumentParser(
        prog="recon", formatter_class=DefaultsHelpFormatter,
        description="Video of a room to a colored mesh: poses, EST depth, TSDF fusion, evaluation.",
        epilog="`recon COMMAND --help` lists a command's options; `recon formats` the scan formats it reads.")
    parser.add_argument("--version", action=VersionAction, help="print the version of recon-est and exit")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    parser.add_argument("--quiet", "-q", action="store_true", help="only errors and final results")
    parser.add_argument("--verbose", "-v", action="store_true", help="more log lines")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=CommandParser)
    for name in COMMAND_MODULES:
        importlib.import_module(f"apps.commands.{name}").register(subparsers)
    return parser


def error_line(exc: Exception) -> str:
    """One line for the user: a ReconError's own message; an OSError as `FILE: what the system said`."""
    if isinstance(exc, OSError) and exc.strerror:
        files = " -> ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
        return f"{files}: {exc.strerror.lower()}" if files else exc.strerror.lower()
    return " ".join(str(exc).splitlines())  # a message must never spill onto a second line


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.quiet else logging.DEBUG if args.verbose else logging.INFO
    setup_logging(level)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ReconError, OSError) as exc:  # bad input, or the file system refusing (permissions, a full disk)
        if args.debug:
            raise
        print(f"recon: error: {error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("recon: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
