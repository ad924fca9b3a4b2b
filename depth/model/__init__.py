"""The EST depth network (see depth.model.network.ESTNet)."""
from .network import ESTNet, TargetOutput, TargetState
from .transformer import MemoryEntry

__all__ = ["ESTNet", "MemoryEntry", "TargetOutput", "TargetState"]
