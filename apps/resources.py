"""Wall time and peak resident memory of a block of work (sampled, so a stage's own peak shows)."""
from __future__ import annotations

import contextlib
import resource
import threading
import time
from dataclasses import dataclass
from typing import Iterator

_PAGE = resource.getpagesize()


def current_rss_mb() -> float:
    """Resident memory of this process now, from /proc (Linux); falls back to the peak so far."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * _PAGE / 2**20
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@dataclass
class Usage:
    seconds: float = 0.0
    peak_rss_mb: float = 0.0


@contextlib.contextmanager
def measure(interval: float = 0.05) -> Iterator[Usage]:
    """Yields a Usage filled in when the block ends: its wall time and the highest RSS seen during it."""
    usage = Usage(peak_rss_mb=current_rss_mb())
    stop = threading.Event()

    def sample():
        while not stop.wait(interval):
            usage.peak_rss_mb = max(usage.peak_rss_mb, current_rss_mb())

    thread = threading.Thread(target=sample, daemon=True)
    start = time.perf_counter()
    thread.start()
    try:
        yield usage
    finally:
        stop.set()
        thread.join()
        usage.seconds = time.perf_counter() - start
        usage.peak_rss_mb = max(usage.peak_rss_mb, current_rss_mb())
