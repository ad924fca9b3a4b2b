"""`recon bench NAME`: benchmarks that print a table (or one JSON object with --json).

Each benchmark lives beside the code it measures, in a module exposing
`add_arguments(parser)` and `run(args) -> int`; this table maps names to modules.
"""
import importlib

BENCHMARKS = {
    "fusion": ("fusion.bench", "TSDF fusion throughput against a bare Open3D loop; mesh evaluation time"),
    "synth": ("recon.synthetic.bench", "synthetic room rendering frames/s against bare Open3D ray casting"),
    "pipeline": ("recon.bench_pipeline", "end-to-end time and peak memory per stage (demo, 7-Scenes x100)"),
    "depth": ("depth.bench", "EST depth network: params, MACs, peak memory, s/frame (ESTM) against plane sweep"),
    "poses": ("poses.bench", "SfM on 200 7-Scenes frames at 640x480: time per step, global vs incremental mapper"),
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
