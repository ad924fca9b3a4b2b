"""User-facing errors: the CLI turns them into one line on stderr and exit code 2."""


class ReconError(Exception):
    """Bad input or an impossible request; the message names the file and what is wrong."""


class ScanFormatError(ReconError):
    """A scan folder or file that does not follow its format."""
