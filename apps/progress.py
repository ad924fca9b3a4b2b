"""Progress reporting: a rich bar with ETA on a terminal, plain log lines otherwise."""
from __future__ import annotations

import contextlib
import logging
import sys
import time
from typing import Callable, Iterator

log = logging.getLogger("recon")


@contextlib.contextmanager
def progress_bar(label: str, total: int, quiet: bool = False) -> Iterator[Callable[[int], None]]:
    """Yields `advance(n=1)`. Rich bar when stderr is a terminal; else a log line every ~10 %."""
    if quiet or total <= 0:
        yield lambda n=1: None
        return
    if sys.stderr.isatty():
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, \
            TimeRemainingColumn

        with Progress(TextColumn("{task.description:>10}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      TextColumn("eta"), TimeRemainingColumn(), transient=False) as bar:
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
