"""`recon export RUN --to FORMAT`: a finished run as a mesh file, a nerfstudio or COLMAP dataset, or a Rerun recording."""
from __future__ import annotations


def register(subparsers):
    subparsers.add_parser(
        "export", help="write a finished run as glb / obj / nerfstudio / colmap / rerun", arguments=add_arguments,
        description="glb, obj: the mesh with vertex colours. nerfstudio: transforms.json + images/ for ns-train. "
                    "colmap: a COLMAP text model (sparse/0) + images/, for COLMAP, gsplat or nerfstudio. rerun: a "
                    ".rrd recording with cameras, images, depth and the mesh (needs the rerun extra). Poses are the "
                    "run's, in its units (the run's report says whether they are metres).")


def add_arguments(p) -> None:
    from apps.export import DEFAULT_NAMES, FORMATS

    p.add_argument("run", help="a run folder of `recon run` / `recon demo` / `recon batch`")
    p.add_argument("--to", required=True, choices=FORMATS, help="output format")
    p.add_argument("--out", default=None, metavar="PATH",
                   help="output file or folder (default RUN/export/ + "
                        + ", ".join(f"{v} ({k})" for k, v in DEFAULT_NAMES.items()) + ")")
    p.set_defaults(func=run)


def run(args) -> int:
    from apps.export import export_run

    path = export_run(args.run, args.to, args.out)
    print(f"wrote {path}")
    return 0
