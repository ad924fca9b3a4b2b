"""User-facing errors: the CLI turns them into one line on stderr and exit code 2."""

import contextlib
from typing import Iterator


class ReconError(Exception):
    """Bad input or an impossible request; the message names the file and what is wrong."""


class ScanFormatError(ReconError):
    """A scan folder or file that does not follow its format."""


@contextlib.contextmanager
def naming(source) -> Iterator[None]:
    """Name `source` (the file some values came from) in a ReconError raised inside the block that does not
    name it already: checks such as the intrinsics' know the numbers, not the file they were read from."""
    try:
        yield
    except ReconError as exc:
        if str(source) in str(exc):
            raise
        raise type(exc)(f"{source}: {exc}") from None
