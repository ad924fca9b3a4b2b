"""The depth folder of a run, and how an interrupted depth stage resumes.

    <name>.png / .conf.png          one frame's depth (mm) and confidence, written atomically, confidence last
    depth.json                      the summary, written last: the stage is complete
    depth.partial.json              the settings of an unfinished run
    .estm-memory/<name>.pt          the last N ESTM memory entries of an unfinished run

A re-run with the same settings reuses a complete folder as is, and an unfinished one keeps
its frames: any of them for planesweep and independent (frames do not depend on each
other), the finished prefix for ESTM (whose memory entries are restored exactly). This is
the one resume mechanism of the depth stage; the pipeline's stage cache calls it.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import torch

from recon.io import CONFIDENCE_SUFFIX, DEPTH_SUFFIX, atomic_path, remove_path, save_depth_map, write_json_atomic

from .estimator import TemporalMemory
from .model import MemoryEntry
from .options import FrameDepth

log = logging.getLogger(__name__)
SUMMARY, PARTIAL, MEMORY_DIR = "depth.json", "depth.partial.json", ".estm-memory"


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


class DepthStore:
    """One depth folder for one set of settings (what determines the maps)."""

    def __init__(self, folder: str | Path, settings: dict):
        self.folder, self.settings = Path(folder), settings

    def complete(self) -> dict | None:
        """The summary of a finished run with these settings whose maps all exist, else None."""
        previous = _read_json(self.folder / SUMMARY)
        if previous and previous.get("settings") == self.settings and all(
                (self.folder / f"{f['name']}{DEPTH_SUFFIX}").is_file() for f in previous["frames"]):
            return previous
        return None

    def _unfinished(self) -> bool:
        partial = _read_json(self.folder / PARTIAL)
        return bool(partial and partial.get("settings") == self.settings)

    def finished_frames(self, names: list[str]) -> frozenset[int]:
        """Indices of frames an unfinished run with these settings wrote (none otherwise)."""
        if not self._unfinished():
            return frozenset()
        return frozenset(i for i, n in enumerate(names) if (self.folder / f"{n}{CONFIDENCE_SUFFIX}").is_file())

    def finished_prefix(self, names: list[str], order: list[int], memory_size: int, device: torch.device
                        ) -> tuple[frozenset[int], TemporalMemory]:
        """ESTM: the frames finished in processing order and the memory at that point. Falls back to a
        full restart (empty set) when an entry the memory needs is missing."""
        memory = TemporalMemory(memory_size)
        if not self._unfinished():
            return frozenset(), memory
        done = []
        for i in order:
            if not (self.folder / f"{names[i]}{CONFIDENCE_SUFFIX}").is_file():
                break
            done.append(i)
        for i in done[len(done) - memory_size:] if memory_size else []:
            path = self.folder / MEMORY_DIR / f"{names[i]}.pt"
            try:
                doc = torch.load(path, map_location=device, weights_only=True)
            except (OSError, RuntimeError, EOFError):
                log.info("depth: memory entry %s missing, ESTM restarts from the first frame", path.name)
                return frozenset(), TemporalMemory(memory_size)
            memory.add(MemoryEntry(doc["key"], doc["value"], doc["camera_to_world"], doc["name"]))
        log.info("depth: resuming ESTM after %d finished frames", len(done))
        return frozenset(done), memory

    def begin(self) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        if (self.folder / MEMORY_DIR).is_symlink():
            remove_path(self.folder / MEMORY_DIR)  # never write (or delete) through a planted link
        write_json_atomic(self.folder / PARTIAL, {"settings": self.settings})

    def save(self, result: FrameDepth, memory: TemporalMemory | None) -> None:
        """A frame's maps; with ESTM its memory entry first (a frame whose maps exist has its entry)."""
        if memory is not None:
            self._save_entry(memory.entries[-1])
        save_depth_map(self.folder, result.name, result.depth, result.confidence)
        if memory is not None:
            keep = set(memory.names)
            for path in (self.folder / MEMORY_DIR).glob("*.pt"):
                if path.stem not in keep:
                    remove_path(path)

    def _save_entry(self, entry: MemoryEntry) -> None:
        path = self.folder / MEMORY_DIR / f"{entry.name}.pt"
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            torch.save({"key": entry.key.cpu(), "value": entry.value.cpu(),
                        "camera_to_world": entry.camera_to_world.cpu(), "name": entry.name}, tmp)

    def finish(self, summary: dict) -> None:
        write_json_atomic(self.folder / SUMMARY, summary)
        remove_path(self.folder / PARTIAL)
        remove_path(self.folder / MEMORY_DIR)
