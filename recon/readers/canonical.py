"""The project's own scan folder (scan.json + images/ + depth/)."""
from pathlib import Path

from recon.scan import SCAN_FILE, load_scan

NAME = "canonical"


def detect(path: Path) -> bool:
    return (path / SCAN_FILE).is_file() or (path.name == SCAN_FILE and path.is_file())


def read(path: Path):
    return load_scan(path)
