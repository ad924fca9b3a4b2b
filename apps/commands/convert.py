"""`recon convert`: any readable scan -> the canonical scan folder."""
from apps.common import add_scan_args, open_selected_scan
from apps.progress import progress_bar


def register(subparsers):
    p = subparsers.add_parser("convert", help="write a scan as a canonical scan folder",
                              description="Read a scan in any supported format (undistorting and resizing as asked) "
                                          "and write it as a canonical folder: scan.json, images/, depth/.")
    add_scan_args(p)
    p.add_argument("--out", required=True, help="output folder (replaced atomically when complete)")
    p.add_argument("--size", default=None, metavar="WxH", help="resize images (intrinsics follow)")
    p.set_defaults(func=run)


def parse_size(text: str) -> tuple[int, int]:
    from recon.errors import ReconError

    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ReconError(f"invalid size {text!r}: expected WxH, e.g. 320x256") from None
    if w <= 0 or h <= 0:
        raise ReconError(f"invalid size {text!r}: width and height must be positive")
    return w, h


def run(args):
    from recon.scan import save_scan

    scan = open_selected_scan(args.scan, args)
    if args.size:
        scan = scan.resized(*parse_size(args.size))
    with progress_bar("convert", len(scan), quiet=args.quiet) as advance:
        save_scan(scan, args.out, progress=lambda i, n: advance())
    print(f"wrote {len(scan)} frames to {args.out}")
    return 0
