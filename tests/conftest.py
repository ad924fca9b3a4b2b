"""Shared fixtures: the real RGB-D sequences in ../shared/data (skipped cleanly when absent)."""
import os
from pathlib import Path

import pytest

SHARED_DATA = Path(os.environ.get("RECON_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA


def _sequence(shared_data: Path, name: str) -> Path:
    """One shared sequence's folder; the test is skipped when this machine lacks it."""
    path = shared_data / name
    if not path.is_dir():
        pytest.skip(f"{path} not found")
    return path


@pytest.fixture(scope="session")
def sevenscenes(shared_data) -> Path:
    return _sequence(shared_data, "7scenes-redkitchen")


@pytest.fixture(scope="session")
def iclnuim(shared_data) -> Path:
    return _sequence(shared_data, "iclnuim-livingroom1")


@pytest.fixture
def single_torch_thread():
    """Small tensors: one thread avoids OpenMP hand-offs on a shared 2-core machine."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def small_run(tmp_path_factory) -> Path:
    """A finished `recon run` folder (plane sweep, every stage) of a small synthetic room with exact ground
    truth, shared by the report and export tests: read it, never change it."""
    from apps.pipeline import InputConfig, Pipeline, RunConfig
    from depth.options import DepthOptions
    from recon.synthetic import SynthConfig, write_synthetic_scan

    room = write_synthetic_scan(SynthConfig(seed=5, frames=30, width=128, height=96),
                                tmp_path_factory.mktemp("small_room") / "scan")
    out = tmp_path_factory.mktemp("small_run") / "out"
    Pipeline(RunConfig(InputConfig(str(room)), str(out), depth=DepthOptions(mode="planesweep"))).run()
    return out
