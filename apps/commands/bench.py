"""`recon bench NAME`: benchmarks that print a table (or one JSON object with --json).

Each benchmark is a module of apps/bench/ exposing `add_arguments(parser)` and `run(args) -> int`;
this table maps names to modules (imported only when their command runs, so `recon bench depth`
needs torch alone).
"""
import importlib

BENCHMARKS = {
    "fusion": ("apps.bench.fusion", "TSDF fusion throughput against a bare Open3D loop; mesh evaluation time"),
    "synth": ("apps.bench.synth", "synthetic room rendering frames/s against bare Open3D ray casting"),
    "pipeline": ("apps.bench.pipeline", "end-to-end time and peak memory per stage (demo, 7-Scenes x100)"),
    "depth": ("apps.bench.depth", "EST depth network: params, MACs, peak memory, s/frame (ESTM) against plane sweep"),
    "poses": ("apps.bench.poses", "SfM on 200 7-Scenes frames at 640x480: time per step, global vs incremental mapper"),
}


def register(subparsers):
    p = subparsers.add_parser("bench", help="run a benchmark and print a table",
                              description="Benchmarks measured against a baseline in the same run.")
    sub = p.add_subparsers(dest="bench", metavar="NAME")
    for name, (module, help_text) in BENCHMARKS.items():
        bp = sub.add_parser(name, help=help_text, description=help_text)
        mod = importlib.import_module(module)
        mod.add_arguments(bp)
        bp.set_defaults(func=mod.run)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
