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


def resolve_precision(precision: str, device: torch.device) -> str:
    """`auto` -> bf16 where `device` computes it in hardware, else fp32; other names as they are."""
    if precision != "auto":
        return precision
    return "bf16" if computes_bf16(device) else "fp32"


def computes_bf16(device: torch.device) -> bool:
    """Whether `device` has bfloat16 arithmetic in hardware: a CUDA GPU that supports it, or a CPU with AMX
    tiles or AVX512-BF16 (where a `compact` training step takes 0.67x the fp32 one, docs/depth.md); a CPU
    without them emulates bf16 and runs a training step 8x slower than fp32."""
    if device.type == "cuda":
        return torch.cuda.is_bf16_supported()
    checks = (getattr(torch.cpu, name, None) for name in ("_is_amx_tile_supported", "_is_avx512_bf16_supported"))
    return any(check() for check in checks if check is not None)
