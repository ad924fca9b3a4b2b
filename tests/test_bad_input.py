"""The bad-input table (docs/reliability.md): a hostile or careless user's inputs, each checked the same way.

For every class: exit status 2, exactly one stderr line, that it names the file or option at fault, no
traceback, nothing written outside --out, and no earlier result lost (the run-command classes run into a
copy of a finished run and must leave its results byte for byte). The workspace path has a space and
non-ASCII letters, so every class also runs through such a path. The commands run in one worker process
(tests/fixtures/cli_worker.py) exactly as `python -m apps.cli` would run them, to keep the table fast.
After the table, the guarantees behind it: changed inputs noticed, no delete through a link, stale temporaries
removed, native decoders' messages folded into one error.
"""
from __future__ import annotations

import itertools
import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest
import torch

from fixtures.box_room import box_room_scan
from fixtures.format_writers import WRITERS

ROOT = Path(__file__).resolve().parents[1]
# The baseline run's options: every frame a keyframe, and no depth filter (at 32x24 it would keep nothing).
RUN = ["--mode", "planesweep", "--keyframe-distance", "0", "--filter", "none", "--quiet"]
# Files of a run that may change when a later command fails: the state file and the lock (its holder's pid).
BOOKKEEPING = {"run.json", ".lock"}


class Worker:
    """One `recon` interpreter that runs command lines sent to it (see tests/fixtures/cli_worker.py)."""

    def __init__(self):
        self.proc = subprocess.Popen([sys.executable, str(ROOT / "tests" / "fixtures" / "cli_worker.py")], cwd=ROOT,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     env={**os.environ, "PYTHONPATH": str(ROOT)})

    def __call__(self, *argv: str) -> dict:
        self.proc.stdin.write(json.dumps([str(a) for a in argv]) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        assert line, "the CLI worker died"
        return json.loads(line)

    def close(self):
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


@pytest.fixture(scope="module")
def recon():
    worker = Worker()
    yield worker
    worker.close()


@pytest.fixture(scope="module")
def ws(tmp_path_factory, recon) -> Path:
    """The workspace: a tiny synthetic scan (6 frames of 32x24) with ground truth (room_gt), the same without
    (room: its run skips the mesh scoring, which would cost most of the table's time), a finished run of room."""
    from recon.synthetic import SynthConfig, write_synthetic_scan

    root = tmp_path_factory.mktemp("bad") / "wörk space"
    write_synthetic_scan(SynthConfig(seed=3, frames=6, width=32, height=24), root / "room_gt")
    shutil.copytree(root / "room_gt", root / "room", ignore=shutil.ignore_patterns("depth", "gt_mesh.ply"))
    doc = json.loads((root / "room" / "scan.json").read_text())
    doc["metadata"]["gt_mesh"] = None
    for frame in doc["frames"]:
        frame.pop("depth", None)
    (root / "room" / "scan.json").write_text(json.dumps(doc))
    done = recon("run", root / "room", "--out", root / "finished", *RUN)
    assert done["rc"] == 0, done["stderr"]
    return root


def snapshot(root: Path, skip: Path | None = None) -> dict[str, tuple[int, int]]:
    """Every file (and folder link) under root, except those under `skip`, with its size and modification time."""
    skip = skip.resolve() if skip is not None else None
    out = {}
    for dirpath, dirs, files in os.walk(root):
        for name in files + [d for d in dirs if os.path.islink(os.path.join(dirpath, d))]:
            path = Path(dirpath, name)
            if skip is not None and (path.resolve() == skip or skip in path.resolve().parents):
                continue
            st = path.lstat()
            out[str(path.relative_to(root))] = (st.st_size, st.st_mtime_ns)
    return out


def contents(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*")
            if p.is_file() and not p.is_symlink() and p.name not in BOOKKEEPING}


# -- the inputs ------------------------------------------------------------------------------------------------

def copy_scan(ws: Path, case: Path, edit: Callable[[dict], None], source: str = "room") -> Path:
    """A copy of one of the workspace's scans with its scan.json edited."""
    scan = case / "scan"
    shutil.copytree(ws / source, scan)
    doc = json.loads((scan / "scan.json").read_text())
    edit(doc)
    (scan / "scan.json").write_text(json.dumps(doc))
    return scan


def write_format(fmt: str, case: Path, frames: int = 4) -> Path:
    folder = case / fmt
    WRITERS[fmt](box_room_scan(frames, 32, 24), folder)
    return folder


def write_video(path: Path, frames: int, moving: bool = True) -> Path:
    """A clip panning over a picture of random shapes (SIFT finds them), or standing still on it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    picture = np.full((240, 400, 3), 128, np.uint8)
    for _ in range(80):
        x, y, r = int(rng.integers(0, 400)), int(rng.integers(0, 240)), int(rng.integers(4, 20))
        cv2.circle(picture, (x, y), r, tuple(int(c) for c in rng.integers(0, 255, 3)), -1)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, (320, 240))
    for i in range(frames):
        shift = 4 * i if moving else 0
        writer.write(np.ascontiguousarray(picture[:, shift:shift + 320]))
    writer.release()
    return path


def truncated(src: Path, dst: Path) -> Path:
    dst.parent.mkdir(parents=True, exist_ok=True)
    data = src.read_bytes()
    dst.write_bytes(data[: len(data) // 2])
    return dst


def set_pose(doc: dict, index: int, value) -> None:
    doc["frames"][index]["camera_to_world"] = value


def lite_checkpoint(path: Path) -> Path:
    """A checkpoint of ours: the smallest network config, untrained."""
    from depth.checkpoint import save_checkpoint
    from depth.config import get_config
    from depth.model import ESTNet

    config = get_config("lite")
    return save_checkpoint(path, ESTNet(config), config)


def mismatched_checkpoint(case: Path) -> tuple[Path, str]:
    """A checkpoint of ours whose first matrix has one row too many; returns it and that tensor's name."""
    path = lite_checkpoint(case / "odd.pt")
    doc = torch.load(path, weights_only=True)
    name = next(k for k, v in doc["state_dict"].items() if v.ndim >= 2)
    doc["state_dict"][name] = torch.cat([doc["state_dict"][name], doc["state_dict"][name][:1]])
    torch.save(doc, path)
    return path, name


def linked(ws: Path, case: Path, slot: str, extra: list[str]) -> tuple[list[str], list[str]]:
    """A copy of the finished run whose stage folder `slot` is a link to a user's folder of photos."""
    photos = case / "my photos"
    photos.mkdir(parents=True)
    for i in range(3):
        cv2.imwrite(str(photos / f"holiday{i}.jpg"), np.full((8, 8, 3), 40 * i, np.uint8))
    out = case / "out"
    link = out / slot
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(photos, target_is_directory=True)
    return ["run", ws / "room", "--out", out, *RUN, *extra], [slot.split("/")[-1], "link"]


@dataclass
class Case:
    name: str
    make: Callable[[Path, Path], tuple[list, list[str]]]  # (workspace, case folder) -> (argv, fragments)
    into_finished_run: bool = True  # --out is case/out, a copy of the finished run whose results must survive


def run_with(*extra):
    """A run of the workspace's own scan with extra options."""
    return lambda ws, case: (["run", ws / "room", "--out", case / "out", *RUN, *extra[:-1]], [extra[-1]])


def run_input(build: Callable[[Path, Path], Path], *fragments: str, extra: tuple = ()):
    """A run of a bad input; the error must name `fragments` (a callable gets the input's path)."""
    def make(ws, case):
        src = build(ws, case)
        names = [f(src) if callable(f) else f for f in fragments] or [str(src)]
        return ["run", src, "--out", case / "out", *RUN, *extra], names
    return make


def _sevenscenes_without(kind: str):
    def build(ws, case):
        folder = write_format("7scenes", case)
        (folder / f"frame-000002.{kind}").unlink()
        return folder
    return build


def nth_file(folder: Path, index: int) -> Path:
    return sorted(folder.iterdir())[index]


def _corrupt(relative: str, index: int | None = None, data: bytes | None = None, truncate: bool = False):
    """A copy of the scan with one file (`relative`, or the index-th file in that folder) broken."""
    def build(ws, case):
        scan = copy_scan(ws, case, lambda doc: None, source="room_gt")
        target = scan / relative if index is None else nth_file(scan / relative, index)
        if truncate:
            data_ = target.read_bytes()
            target.write_bytes(data_[: len(data_) // 2])
        else:
            target.write_bytes(data)
        return scan
    return build


def _simplerecon(edit: Callable[[Path], None]):
    def build(ws, case):
        folder = write_format("simplerecon", case)
        edit(folder)
        return folder
    return build


def _drop_last_pose(folder: Path) -> None:
    rows = (folder / "poses.txt").read_text().splitlines()
    (folder / "poses.txt").write_text("\n".join(rows[:-1]) + "\n")


def _zero_focal(folder: Path) -> None:
    np.savetxt(folder / "K.txt", np.array([[0.0, 0, 16], [0, 0.0, 12], [0, 0, 1]]))


def _resized_image(ws, case):
    scan = copy_scan(ws, case, lambda doc: None)
    image = nth_file(scan / "images", 0)
    cv2.imwrite(str(image), np.zeros((12, 16, 3), np.uint8))
    return scan


def _unicode_input(ws, case):
    scan = case / "scän dir ü" / "room"
    shutil.copytree(ws / "room", scan)
    nth_file(scan / "images", 1).write_bytes(b"\x00" * 10)
    return scan


def _weights(make_file: Callable[[Path], Path], *fragments: str):
    def make(ws, case):
        case.mkdir(parents=True, exist_ok=True)
        weights = make_file(case)
        return ["run", ws / "room", "--out", case / "out", *RUN[2:], "--mode", "estm", "--weights", weights], \
            [str(weights), *fragments]
    return make


def _garbage(name: str, data: bytes) -> Callable[[Path], Path]:
    def write(case):
        (case / name).write_bytes(data)
        return case / name
    return write


def _mismatch(ws, case):
    case.mkdir(parents=True, exist_ok=True)
    weights, tensor = mismatched_checkpoint(case)
    return ["run", ws / "room", "--out", case / "out", *RUN[2:], "--mode", "estm", "--weights", weights], \
        [str(weights), tensor]


def _out_is_file(ws, case):
    case.mkdir(parents=True, exist_ok=True)
    (case / "notes").write_text("my notes\n")  # outside case/out, so the snapshot sees that it survives
    return ["run", ws / "room", "--out", case / "notes", *RUN], [str(case / "notes")]


def _out_under_file(ws, case):
    case.mkdir(parents=True, exist_ok=True)
    (case / "notes.txt").write_text("my notes\n")
    return ["run", ws / "room", "--out", case / "notes.txt" / "run", *RUN], ["notes.txt"]


def _out_unwritable(ws, case):
    if os.geteuid() == 0:  # root writes anywhere it may; /sys refuses even root a new folder
        return ["run", ws / "room", "--out", "/sys/recon-bad-input/run", *RUN], ["/sys/recon-bad-input"]
    locked = case / "locked"
    locked.mkdir(parents=True)
    locked.chmod(0o500)
    return ["run", ws / "room", "--out", locked / "run", *RUN], [str(locked / "run")]


def _convert_huge(ws, case):
    out = case / "converted"
    shutil.copytree(ws / "room", out)  # an earlier conversion that must survive
    return ["convert", ws / "room", "--out", out, "--size", "50000x40000", "--quiet"], ["--size"]


def _batch_gt_mesh(ws, case):
    case.mkdir(parents=True, exist_ok=True)
    (case / "broken.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    data = case / "dataset"
    data.mkdir()
    (data / "room").symlink_to(ws / "room", target_is_directory=True)
    return ["batch", data, "--out", case / "batch", *RUN, "--gt-mesh", case / "broken.ply"], ["broken.ply"]


def _gt_mesh_broken(ws, case):
    case.mkdir(parents=True, exist_ok=True)
    (case / "gt.ply").write_bytes(b"not a mesh at all")
    return ["run", ws / "room", "--out", case / "out", *RUN, "--gt-mesh", case / "gt.ply"], [str(case / "gt.ply")]


def _frame_name(name_of: Callable[[Path], str]):
    def make(ws, case):
        name = name_of(case)
        scan = copy_scan(ws, case, lambda doc: doc["frames"][1].update(name=name))
        return ["run", scan, "--out", case / "out", *RUN], [repr(name).strip("'")]
    return make


def _pose(value):
    return lambda ws, case: copy_scan(ws, case, lambda doc: set_pose(doc, 2, value))


def _file(folder: str, index: int):
    """The fragment an error must hold: the full path of the index-th file of a scan's folder."""
    return lambda scan: str(nth_file(scan / folder, index))


def _empty_folder(ws, case):
    (case / "empty").mkdir(parents=True, exist_ok=True)
    return case / "empty"


def _junk_video(ws, case):
    case.mkdir(parents=True, exist_ok=True)
    return _garbage("clip.mp4", b"\x00\x01garbage" * 50)(case)


def _duplicate_name(doc: dict) -> None:
    doc["frames"][2]["name"] = doc["frames"][1]["name"]


def _foreign_checkpoint(case: Path) -> Path:
    torch.save({"w": torch.zeros(2)}, case / "other.pt")
    return case / "other.pt"


CASES = [
    Case("missing input", lambda ws, case: (["run", case / "nothing", "--out", case / "out", *RUN], ["nothing"])),
    Case("empty folder", run_input(_empty_folder)),
    Case("corrupt video", run_input(_junk_video, "clip.mp4", "cannot be opened")),
    Case("truncated video", run_input(lambda ws, case: truncated(write_video(case / "full.mp4", 20), case / "cut.mp4"),
                                      "cut.mp4")),
    Case("3-frame video", run_input(lambda ws, case: write_video(case / "three.mp4", 3), "three.mp4", "usable frames")),
    Case("static video", run_input(lambda ws, case: write_video(case / "still.mp4", 15, moving=False), "still.mp4",
                                   "barely moved")),
    Case("video --fps 0", run_input(lambda ws, case: write_video(case / "clip.mp4", 12), "--fps",
                                    extra=("--fps", "0"))),
    Case("NaN pose", run_input(_pose([[float("nan")] * 4] * 4), "scan.json", "NaN")),
    Case("non-rigid pose", run_input(_pose(np.ones((4, 4)).tolist()), "scan.json", "rigid")),
    Case("pose of wrong shape", run_input(_pose([[1, 0], [0, 1]]), "scan.json", "shape")),
    Case("image/pose count mismatch", run_input(_simplerecon(_drop_last_pose), "4 images but 3 poses")),
    Case("zero focal length", run_input(_simplerecon(_zero_focal), "K.txt", "focal")),
    Case("image size differs from intrinsics", run_input(_resized_image, _file("images", 0))),
    Case("zero-byte image", run_input(_corrupt("images", 3, b""), _file("images", 3), "empty")),
    Case("truncated image", run_input(_corrupt("images", 3, truncate=True), _file("images", 3))),
    Case("corrupt depth PNG", run_input(_corrupt("depth", 4, b"\x89PNG garbage"), _file("depth", 4))),
    Case("truncated depth PNG", run_input(_corrupt("depth", 4, truncate=True), _file("depth", 4), "truncated")),
    Case("invalid scan.json", run_input(_corrupt("scan.json", data=b"{ not json"), "scan.json", "invalid JSON")),
    Case("duplicate frame names", run_input(lambda ws, case: copy_scan(ws, case, _duplicate_name), "duplicate")),
    Case("frame name climbing out (../)", _frame_name(lambda case: "../../../pwn_frame")),
    Case("frame name absolute", _frame_name(lambda case: str(case.parent / "ABS"))),
    Case("frame name with a newline", _frame_name(lambda case: "a\nb")),
    Case("7-Scenes frame without pose", run_input(_sevenscenes_without("pose.txt"), "frame-000002.color.png",
                                                  "no pose")),
    Case("7-Scenes frame without depth", run_input(_sevenscenes_without("depth.png"), "frame-000002.depth.png")),
    Case("unknown --format", run_input(lambda ws, case: ws / "room", "nosuch", extra=("--format", "nosuch"))),
    Case("path with spaces and unicode", run_input(_unicode_input, _file("images", 1))),
    Case("--stride 0", run_with("--stride", "0", "--stride")),
    Case("--start past the end", run_with("--start", "50", "leaves no frames")),
    Case("--max-frames 0", run_with("--max-frames", "0", "--max-frames")),
    Case("--voxel-size 0", run_with("--voxel-size", "0", "--voxel-size")),
    Case("negative --keyframe-distance", run_with("--keyframe-distance", "-1", "--keyframe-distance")),
    Case("--min-confidence out of range", run_with("--min-confidence", "2", "--min-confidence")),
    Case("inverted --depth-range", run_with("--depth-range", "5", "1", "--depth-range")),
    Case("negative --memory", run_with("--memory", "-1", "--memory")),
    Case("missing --gt-mesh", run_with("--gt-mesh", "/nonexistent/gt.ply", "gt.ply")),
    Case("corrupt --gt-mesh", _gt_mesh_broken),
    Case("corrupt --weights", _weights(_garbage("junk.pt", b"garbage\n" * 20), "unreadable")),
    Case("truncated --weights", _weights(lambda case: truncated(lite_checkpoint(case / "full.pt"), case / "cut.pt"),
                                         "truncated")),
    Case("empty --weights", _weights(_garbage("empty.pt", b""), "empty")),
    Case("foreign checkpoint", _weights(_foreign_checkpoint, "not a depth network checkpoint")),
    Case("checkpoint that does not fit", _mismatch),
    Case("--out is a file", _out_is_file, into_finished_run=False),
    Case("--out inside a file", _out_under_file, into_finished_run=False),
    Case("--out not writable", _out_unwritable, into_finished_run=False),
    Case("linked scan/frames, --force scan", lambda ws, case: linked(ws, case, "scan/frames", ["--force", "scan"])),
    Case("linked depth/.estm-memory, --force depth",
         lambda ws, case: linked(ws, case, "depth/.estm-memory", ["--force", "depth"])),
    Case("convert --size 50000x40000", _convert_huge, into_finished_run=False),
    Case("batch with a corrupt --gt-mesh", _batch_gt_mesh, into_finished_run=False),
]


def test_the_table_covers_at_least_30_classes():
    assert len({c.name for c in CASES}) == len(CASES) >= 30


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input(case: Case, ws: Path, recon):
    folder = ws / "cases" / case.name.replace("/", "_")
    out = folder / "out"
    if case.into_finished_run:
        shutil.copytree(ws / "finished", out)
    argv, fragments = case.make(ws, folder)
    before, kept = snapshot(ws, skip=out), contents(out) if case.into_finished_run else {}
    result = recon(*argv)
    lines = [ln for ln in result["stderr"].splitlines() if ln.strip()]
    assert result["rc"] == 2, result["stderr"]
    assert "Traceback" not in result["stderr"]
    assert len(lines) == 1 and lines[0].startswith("recon: error: "), result["stderr"]
    for fragment in fragments:
        assert str(fragment) in lines[0], (fragment, lines[0])
    assert snapshot(ws, skip=out) == before, "something was written (or deleted) outside --out"
    if case.into_finished_run:
        after = contents(out)
        lost = [name for name, data in kept.items() if after.get(name) != data]
        assert not lost, f"earlier results lost or changed: {lost[:5]}"


# -- the guarantees behind the table ----------------------------------------------------------------------------

def test_changed_inputs_are_noticed(ws):
    """The scan stage's fingerprint is the input's content: a replaced image or a pose moved by 1 m redoes the
    run; the same input named by a relative path (or touched back to its old state) is still up to date."""
    from apps.cli import build_parser
    from apps.commands.run import config_from_args
    from apps.pipeline import STAGES, Pipeline

    room, out = ws / "room", ws / "finished"  # edited below and put back exactly (bytes and times)

    def current(path) -> list[str]:
        """The stages a re-run would skip (a stage that runs redoes every later one)."""
        args = build_parser().parse_args(["run", str(path), "--out", str(out), *RUN])
        pipeline = Pipeline(config_from_args(args, args.input, args.out))
        pipeline._load_state()
        return list(itertools.takewhile(pipeline.is_current, STAGES))

    def edited(path: Path, change: Callable[[Path], None], keep_time: bool = False) -> list[str]:
        original, st = path.read_bytes(), path.stat()
        try:
            change(path)
            if keep_time:  # then only the content hash can tell
                os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
            return current(room)
        finally:
            path.write_bytes(original)
            os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))

    def move_pose(path: Path) -> None:
        doc = json.loads(path.read_text())
        doc["frames"][3]["camera_to_world"][0][3] += 1.0
        path.write_text(json.dumps(doc))

    assert current(room) == list(STAGES)
    assert current(os.path.relpath(room, ROOT)) == list(STAGES)  # the worker's and this test's cwd is ROOT
    assert edited(nth_file(room / "images", 2), lambda p: cv2.imwrite(str(p), np.zeros((24, 32, 3), np.uint8))) == []
    assert edited(room / "scan.json", move_pose, keep_time=True) == []
    assert current(room) == list(STAGES)  # put back as it was: up to date again


def test_no_delete_through_links(tmp_path):
    """Cleaning a folder that is a link removes the link, never what it points to."""
    from depth.store import MEMORY_DIR, DepthStore
    from poses.ingest import IngestConfig, ingest
    from recon.io import atomic_dir, remove_path

    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(3):
        cv2.imwrite(str(photos / f"p{i}.jpg"), np.full((8, 8, 3), 50 * i, np.uint8))
    kept = contents(photos)

    def plant(link: Path) -> Path:
        link.parent.mkdir(parents=True, exist_ok=True)
        link.symlink_to(photos, target_is_directory=True)
        return link

    remove_path(plant(tmp_path / "a" / "link"))
    ingest(write_video(tmp_path / "clip.mp4", 12), plant(tmp_path / "run" / "frames"), IngestConfig(min_frames=1))
    assert not (tmp_path / "run" / "frames").is_symlink() and any((tmp_path / "run" / "frames").glob("*.jpg"))
    store = DepthStore(tmp_path / "depth", {"settings": 1})
    plant(tmp_path / "depth" / MEMORY_DIR)
    store.begin()
    store.finish({"settings": 1, "frames": []})
    with atomic_dir(plant(tmp_path / "scan")) as tmp:
        (tmp / "scan.json").write_text("{}")
    assert (tmp_path / "scan" / "scan.json").is_file() and not (tmp_path / "scan").is_symlink()
    assert contents(photos) == kept


def test_stale_temporaries_of_killed_writers_are_removed(tmp_path):
    """A folder written through atomic_dir by a process that died is removed by the next writer; a live
    writer's is left alone."""
    from recon.io import atomic_dir

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    stale = [tmp_path / f".scan.tmp-{pid}-x1", tmp_path / f".scan.old-{pid}-"]
    live = tmp_path / f".scan.tmp-{os.getpid()}-x2"
    for folder in (*stale, live):
        (folder / "images").mkdir(parents=True)
    with atomic_dir(tmp_path / "scan") as tmp:
        (tmp / "scan.json").write_text("{}")
    assert not any(p.exists() for p in stale) and live.is_dir() and (tmp_path / "scan" / "scan.json").is_file()


def test_native_decoder_messages_become_one_error(tmp_path, capfd):
    """libpng prints its complaint straight to stderr; it comes back inside our one error instead."""
    from recon.errors import ReconError
    from recon.io import read_depth_png, read_image

    rng = np.random.default_rng(1)
    cv2.imwrite(str(tmp_path / "a.png"), rng.integers(0, 255, (24, 32, 3), dtype=np.uint8))
    data = bytearray((tmp_path / "a.png").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (tmp_path / "flipped.png").write_bytes(bytes(data))
    truncated(tmp_path / "a.png", tmp_path / "cut.png")
    for name, read, why in (("flipped.png", read_image, "libpng error"), ("cut.png", read_image, "truncated"),
                            ("cut.png", read_depth_png, "truncated")):
        with pytest.raises(ReconError, match=name) as err:
            read(tmp_path / name)
        assert why in str(err.value) and "\n" not in str(err.value)
    assert capfd.readouterr().err == ""
