"""Terminal output: log lines and progress bars on one rich console, plain lines when not a terminal.

On a terminal, log records go through rich's handler to the same console the live bars draw on,
so a log line prints above the bars instead of into them. Elsewhere (a pipe, a file, a batch
worker) both are plain lines: a log line per record and one every ~10 % of a bar.
"""
from __future__ import annotations

import contextlib
import functools
import logging
import sys
import time
from typing import Callable, Iterator

log = logging.getLogger("recon")


@functools.lru_cache(maxsize=1)
def console():
    """The one rich console on stderr, shared by the log handler and the bars."""
    from rich.console import Console

    return Console(stderr=True)


def setup_logging(level: int) -> None:
    """Route every log record to stderr: through rich on a terminal, as plain message lines otherwise."""
    if sys.stderr.isatty():
        from rich.highlighter import NullHighlighter
        from rich.logging import RichHandler

        handler: logging.Handler = RichHandler(console=console(), show_time=False, show_level=False, show_path=False,
                                               markup=False, rich_tracebacks=False, highlighter=NullHighlighter())
    else:
        handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    root = logging.getLogger()
    for old in [h for h in root.handlers if getattr(h, "recon_cli", False)]:
        root.removeHandler(old)  # a second `main()` in one process (tests, notebooks) replaces ours only
    handler.recon_cli = True
    root.addHandler(handler)
    root.setLevel(level)


@contextlib.contextmanager
def progress_bar(label: str, total: int, quiet: bool = False) -> Iterator[Callable[[int], None]]:
    """Yields `advance(n=1)`. A rich bar when stderr is a terminal; else a log line every ~10 %."""
    if quiet or total <= 0:
        yield lambda n=1: None
        return
    if sys.stderr.isatty():
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, \
            TimeRemainingColumn

        with Progress(TextColumn("{task.description:>10}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      TextColumn("eta"), TimeRemainingColumn(), console=console(), transient=False) as bar:
            task = bar.add_task(label, total=total)
            yield lambda n=1: bar.advance(task, n)
        return
    state = {"done": 0, "next": max(1, total // 10)}
    start = time.perf_counter()

    def advance(n: int = 1) -> None:
        state["done"] += n
        if state["done"] >= state["next"] or state["done"] == total:
            elapsed = time.perf_counter() - start
            eta = elapsed / state["done"] * (total - state["done"])
            log.info("%s: %d/%d (%.0f s, eta %.0f s)", label, state["done"], total, elapsed, eta)
            state["next"] = state["done"] + max(1, total // 10)

    yield advance
