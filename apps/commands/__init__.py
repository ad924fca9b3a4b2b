"""The `recon` commands, one module each, and the parser they share.

Every command module has `register(subparsers)`, which adds its parser with
`subparsers.add_parser(NAME, help=..., description=..., arguments=add_arguments)`.
`add_arguments(parser)` runs only when that command is used (parsed or its help shown):
the options read their defaults from the stage configs, which import torch, Open3D or
trimesh, so `recon --help` builds none of them and stays fast.
"""
from __future__ import annotations

import argparse
from typing import Callable, Iterator


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Says each option's default, unless its help already does or there is none worth saying."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (not action.option_strings or "default" in text or default in (None, False, argparse.SUPPRESS)
                or isinstance(default, (list, tuple)) and not default):
            return text
        return f"{text} (default %(default)s)"


class CommandParser(argparse.ArgumentParser):
    """A command's parser: its arguments are added on first use; every default shows in its help."""

    def __init__(self, *args, arguments: Callable[[argparse.ArgumentParser], None] | None = None, **kwargs):
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)
        self._arguments = arguments
        self._complete = False

    def complete(self) -> "CommandParser":
        """Add the command's arguments (once), then the output flags every command takes."""
        if not self._complete:
            self._complete = True
            if self._arguments is not None:
                self._arguments(self)
            group = self.add_argument_group("output")
            group.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                               help="show full tracebacks on errors")
            group.add_argument("--quiet", "-q", action="store_true", default=argparse.SUPPRESS,
                               help="only errors and final results")
            group.add_argument("--verbose", "-v", action="store_true", default=argparse.SUPPRESS, help="more log lines")
        return self

    def parse_known_args(self, args=None, namespace=None):
        self.complete()
        return super().parse_known_args(args, namespace)

    def format_help(self) -> str:
        self.complete()
        return super().format_help()

    def format_usage(self) -> str:
        self.complete()
        return super().format_usage()


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The parsers of `parser`'s sub-commands by name (empty for a leaf command)."""
    return {name: sub for action in parser._actions if isinstance(action, argparse._SubParsersAction)
            for name, sub in action.choices.items()}


def iter_commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
                  ) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every leaf command as (name path, completed parser), e.g. (("eval", "depth"), parser)."""
    for name, sub in subcommands(parser).items():
        if isinstance(sub, CommandParser):
            sub.complete()
        children = subcommands(sub)
        if children:
            yield from iter_commands(sub, (*path, name))
        else:
            yield (*path, name), sub
