"""The command line: one name, type and default per setting in every command, defaults in every help,
`--version`, and a `recon --help` that loads none of the heavy libraries."""
import argparse
import importlib.metadata
import json
import subprocess
import sys
from pathlib import Path

import pytest

from apps import options
from apps.cli import build_parser
from apps.commands import CommandParser, iter_commands, subcommands

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "open3d", "trimesh", "pycolmap", "plotly", "ray", "rerun", "scipy")
# Benchmarks run fixed workloads (their frame counts and configs are the benchmark); `train` builds a network
# config and its planes, where the other commands check a checkpoint's: those names mean other settings there.
OWN_MEANING = {("train", "--config"), ("train", "--depth-range")}


def signature(action: argparse.Action) -> tuple:
    return (type(action).__name__, getattr(action.type, "__name__", action.type), action.default,
            tuple(action.choices) if action.choices else None, action.nargs, action.dest)


def shared_options() -> dict[str, tuple]:
    """Every option of apps.options (each `add_*` group), as each command gets it, by option string."""
    shared = {}
    for name in dir(options):
        if name.startswith("add_"):
            p = CommandParser(prog=name)
            getattr(options, name)(p)
            shared.update({s: signature(a) for a in p._actions for s in a.option_strings if s.startswith("--")})
    assert {"--voxel-size", "--keyframe-distance", "--camera-model", "--start", "--device"} <= set(shared)
    return shared


def commands() -> dict[str, argparse.ArgumentParser]:
    return {" ".join(path): p for path, p in iter_commands(build_parser())}


def test_every_shared_option_has_one_name_type_and_default_everywhere():
    shared = shared_options()
    seen: dict[str, set[str]] = {}
    for name, parser in commands().items():
        if name.startswith("bench "):
            continue
        for action in parser._actions:
            for flag in action.option_strings:
                if flag in shared and (name, flag) not in OWN_MEANING:
                    assert signature(action) == shared[flag], f"recon {name} {flag}"
                    seen.setdefault(flag, set()).add(name)
    # The pipeline commands take every stage's settings; the stage commands their stage's.
    for name in ("run", "demo", "batch"):
        for flag in ("--keyframe-distance", "--device", "--depth-min", "--precision", "--camera-model", "--fps",
                     "--stride", "--max-frames", "--start", "--voxel-size", "--full-res-depth", "--mapper"):
            assert name in seen.get(flag, ()), f"recon {name} lacks {flag}"
    for name, flags in {"depth": ("--keyframe-distance", "--device", "--mode", "--fit", "--format", "--start"),
                        "fuse": ("--voxel-size", "--device", "--min-confidence", "--format"),
                        "poses": ("--camera-model", "--fps", "--stride", "--mapper", "--blur-ratio"),
                        "eval depth": ("--format", "--start", "--stride")}.items():
        assert all(name in seen.get(f, ()) for f in flags), name
    everything = {f for p in commands().values() for a in p._actions for f in a.option_strings}
    for retired in ("--keyframe-threshold", "--fusion-device", "--colmap"):
        assert retired not in everything  # the names one setting used to have besides its own


def test_every_help_says_the_defaults():
    for name, parser in commands().items():
        formatter = parser._get_formatter()
        for action in parser._actions:
            default = action.default
            if (not action.option_strings or default in (None, False, argparse.SUPPRESS) or default == []
                    or isinstance(action, argparse._HelpAction)):
                continue
            assert "default" in formatter._expand_help(action), f"recon {name} {action.option_strings[0]}"
    assert "(default 0.04)" in " ".join(commands()["fuse"].format_help().split())


def test_help_and_version_load_no_heavy_library():
    code = ("import sys; from apps.cli import build_parser; build_parser().format_help(); "
            f"print([m for m in {HEAVY!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert json.loads(out.stdout.replace("'", '"')) == [], out.stderr
    version = subprocess.run([sys.executable, "-m", "apps.cli", "--version"], cwd=ROOT, capture_output=True,
                             text=True, timeout=60)
    assert version.returncode == 0 and version.stdout.strip() == f"recon {importlib.metadata.version('recon-est')}"


def test_a_command_builds_its_options_only_when_used():
    parser = build_parser()
    run = subcommands(parser)["run"]
    assert "--voxel-size" not in {f for a in run._actions for f in a.option_strings}  # not built by `recon --help`
    args = parser.parse_args(["run", "scan", "--out", "o", "--voxel-size", "0.02", "--quiet"])
    assert args.voxel_size == 0.02 and args.quiet and args.func.__module__ == "apps.commands.run"
    with pytest.raises(SystemExit):
        parser.parse_args(["run", "scan", "--out", "o", "--device", "tpu"])
