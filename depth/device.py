"""Which torch device a depth command runs on."""
from __future__ import annotations

import torch

from recon.errors import ReconError

DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name: str) -> torch.device:
    """`auto` picks CUDA when present; asking for CUDA without one is a clear error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ReconError("--device cuda requested but no CUDA device is available")
    if name not in DEVICES:
        raise ReconError(f"unknown device {name!r} ({', '.join(DEVICES)})")
    return torch.device(name)


def describe_device(device: torch.device) -> str:
    """A line for checkpoint metadata: the GPU's name, or the CPU thread count."""
    if device.type == "cuda":
        return f"CUDA {torch.cuda.get_device_name(device)}"
    return f"CPU, {torch.get_num_threads()} torch thread(s)"
