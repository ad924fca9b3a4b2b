"""`recon batch DATASET --out DIR`: every scan of a dataset, locally or on a Ray cluster."""


from apps import options


def register(subparsers):
    subparsers.add_parser("batch", help="run the pipeline over every scan of a dataset",
                          description="One run folder per scan under --out and a summary (summary.csv, "
                                      "summary.json, index.html). Resumable; a failed scan is recorded and "
                                      "the others go on. Frame selection and every pipeline option apply to "
                                      "each scan. Exit status: 0 when every scan is done or skipped, 1 when any "
                                      "scan failed (the others still finish), 2 for bad options.",
                          arguments=add_arguments)


def add_arguments(p) -> None:
    from apps.commands.run import add_pipeline_args

    p.add_argument("dataset", help="folder whose sub-folders are scans (or video files), or a list file of paths")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--engine", choices=["local", "ray"], default="local",
                   help="local process pool or Ray tasks")
    p.add_argument("--workers", type=int, default=1, help="local: scans at once")
    p.add_argument("--address", default=None, help="ray: address of an existing cluster (default: start a local one)")
    p.add_argument("--cpus-per-scan", type=float, default=None,
                   help="CPU threads each scan computes with; ray: also the CPUs its task requests "
                        "(default: local the cores over --workers, ray 1)")
    p.add_argument("--gpus-per-scan", type=float, default=0.0, help="ray: GPUs each scan's task requests")
    options.add_format(p)
    add_pipeline_args(p, with_input=False)
    p.set_defaults(func=run)


def run(args):
    from apps.batch import run_batch
    from apps.commands.run import config_from_args

    template = config_from_args(args, "", "")

    def report(r):
        tail = f": {r['error']}" if r["status"] == "failed" else f" ({r['seconds']:.0f} s)"
        print(f"{r['name']}: {r['status']}{tail}", flush=True)

    summary = run_batch(args.dataset, args.out, template, args.engine, args.workers, args.address,
                        args.cpus_per_scan, args.gpus_per_scan, on_result=report)
    c = summary["counts"]
    print(f"{c['done']} done, {c['skipped']} skipped, {c['failed']} failed; summary in {args.out}/index.html")
    return 0 if c["failed"] == 0 else 1
