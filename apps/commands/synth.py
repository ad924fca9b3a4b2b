"""`recon synth`: render a synthetic room to a canonical scan with exact GT depth and mesh."""
import logging

from apps.common import parse_size

log = logging.getLogger(__name__)


def register(subparsers):
    about = ("Generate a procedural room from a seed, walk a handheld-like camera through it and write a "
             "canonical scan with exact depth and the ground-truth mesh; optionally also an .mp4 video with "
             "its poses as a nerfstudio transforms.json.")
    subparsers.add_parser("synth", help="render a synthetic room (images, exact depth, poses, gt_mesh.ply)",
                          description=about, arguments=add_arguments)


def add_arguments(p) -> None:
    p.add_argument("--out", required=True, metavar="DIR", help="output scan folder (replaced when it exists)")
    p.add_argument("--frames", type=int, default=300, metavar="N", help="number of frames (default 300)")
    p.add_argument("--size", default="320x256", metavar="WxH", help="image size (default 320x256)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="room and camera path seed (default 0)")
    p.add_argument("--frame-rate", type=float, default=30.0, metavar="FPS",
                   help="frames per second of the walk and its video (default 30)")
    p.add_argument("--hfov", type=float, default=None, metavar="DEG",
                   help="horizontal field of view (default: drawn from 55-75 per seed)")
    p.add_argument("--effects", action="store_true",
                   help="add phone-like sensor effects: noise, motion blur, exposure/white-balance drift, JPEG")
    p.add_argument("--video", action="store_true", help="also write video.mp4 and transforms.json (nerfstudio)")
    p.add_argument("--preview", metavar="PNG", default=None, help="also write a contact sheet of frames and depth")
    p.set_defaults(func=run)


def run(args) -> int:
    from recon.io import write_image
    from recon.synthetic import SensorEffects, SynthConfig, contact_sheet, write_synthetic_scan
    from recon.scan import load_scan

    width, height = parse_size(args.size)
    config = SynthConfig(seed=args.seed, frames=args.frames, width=width, height=height, fps=args.frame_rate,
                         hfov_deg=args.hfov, effects=SensorEffects.realistic() if args.effects else SensorEffects())
    out = write_synthetic_scan(config, args.out, video=args.video)
    scan = load_scan(out)
    scene = scan.metadata.extra["scene"]
    extent = "x".join(f"{v:g}" for v in scene["extent_m"])
    print(f"wrote {out}: {len(scan)} frames {width}x{height}, {scene['layout']} room {extent} m, "
          f"{len(scene['objects'])} objects, {scene['triangles']} triangles, gt_mesh.ply"
          + (", video.mp4 + transforms.json" if args.video else ""))
    if args.preview:
        write_image(args.preview, contact_sheet([scan], frames_per_scan=4))
        log.info("contact sheet: %s", args.preview)
    return 0
