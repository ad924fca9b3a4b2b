"""`recon bench NAME`: benchmarks that print a table (or one JSON object with --json).

Each benchmark is a module of apps/bench/ exposing `add_arguments(parser)` and `run(args) -> int`;
this table maps names to modules (imported only when their command runs, so `recon bench depth`
needs torch alone).
"""
import functools
import importlib

BENCHMARKS = {
    "fusion": ("apps.bench.fusion", "TSDF fusion throughput against a bare Open3D loop; mesh evaluation time"),
    "synth": ("apps.bench.synth", "synthetic room rendering frames/s against bare Open3D ray casting"),
    "pipeline": ("apps.bench.pipeline", "end-to-end time and peak memory per stage (demo, 7-Scenes x100)"),
    "depth": ("apps.bench.depth", "EST depth network: params, MACs, peak memory, s/frame (ESTM) against plane sweep"),
    "train": ("apps.bench.train", "depth network training: seconds per step, fp32 against bf16 autocast"),
    "poses": ("apps.bench.poses", "SfM repeatability and completeness: rendered rooms, a photo folder, 7-Scenes"),
    "cli": ("apps.bench.cli", "start-up time of `recon --help` / `--version` against a bare Python start"),
}


def register(subparsers):
    subparsers.add_parser("bench", help="run a benchmark and print a table", arguments=add_arguments,
                          description="Benchmarks measured against a baseline in the same run.")


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="bench", metavar="NAME")
    for name, (module, help_text) in BENCHMARKS.items():
        sub.add_parser(name, help=help_text, description=help_text, arguments=functools.partial(_benchmark, module))
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _benchmark(module: str, parser) -> None:
    """A benchmark's own arguments, imported only when that benchmark runs or shows its help."""
    mod = importlib.import_module(module)
    mod.add_arguments(parser)
    parser.set_defaults(func=mod.run)
