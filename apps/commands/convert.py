"""`recon convert`: any readable scan -> the canonical scan folder."""
from apps import options
from apps.common import open_selected_scan, parse_size
from apps.progress import progress_bar


def register(subparsers):
    subparsers.add_parser("convert", help="write a scan as a canonical scan folder",
                          description="Read a scan in any supported format (undistorting and resizing as asked) "
                                      "and write it as a canonical folder: scan.json, images/, depth/.",
                          arguments=add_arguments)


def add_arguments(p) -> None:
    options.add_input(p)
    p.add_argument("--out", required=True, help="output folder (replaced atomically when complete)")
    p.add_argument("--size", default=None, metavar="WxH", help="resize images (intrinsics follow)")
    p.set_defaults(func=run)


def run(args):
    from recon.scan import save_scan

    scan = open_selected_scan(args.scan, args)
    if args.size:
        scan = scan.resized(*parse_size(args.size))
    with progress_bar("convert", len(scan), quiet=args.quiet) as advance:
        save_scan(scan, args.out, progress=lambda i, n: advance())
    print(f"wrote {len(scan)} frames to {args.out}")
    return 0
