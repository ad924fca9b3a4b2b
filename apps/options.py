"""The one set of command-line options: every command that takes a setting takes it under the same
name, type and default, and builds the stage's own config from it (the defaults are the config
dataclasses' own, written once).

Each `add_*` function adds one group; the matching builder turns parsed arguments into that
stage's config. Heavy libraries are imported only by the builders, so `recon --help` stays fast.
"""
from __future__ import annotations

import argparse
import dataclasses

DEPTH_MODES = ("estm", "joint", "independent", "planesweep")  # checked against depth.options.MODES in tests
DEVICES = ("auto", "cpu", "cuda")


def _default(cls, name):
    return {f.name: f for f in dataclasses.fields(cls)}[name].default


def add_selection(parser: argparse.ArgumentParser) -> None:
    """--start/--stride/--max-frames: every command that takes a scan accepts them."""
    g = parser.add_argument_group("frame selection")
    g.add_argument("--start", type=int, default=0, metavar="N", help="first frame to use (default 0)")
    g.add_argument("--stride", type=int, default=1, metavar="N", help="use every N-th frame (default 1)")
    g.add_argument("--max-frames", type=int, default=None, metavar="N", help="use at most N frames (default all)")


def add_input(parser: argparse.ArgumentParser, name: str = "scan", help: str = "scan folder or file") -> None:
    parser.add_argument(name, help=f"{help} (any supported format, see `recon formats`)")
    parser.add_argument("--format", default="auto", help="input format (default: auto-detect)")
    add_selection(parser)


def add_device(parser) -> None:
    parser.add_argument("--device", choices=DEVICES, default="auto",
                        help="where the network and fusion run (default auto: CUDA when present)")


def add_sfm(parser) -> None:
    from poses.ingest import IngestConfig
    from poses.sfm import SfMConfig

    g = parser.add_argument_group("poses (SfM)")
    g.add_argument("--mapper", choices=("incremental", "global"), default=_default(SfMConfig, "mapper"),
                   help="SfM mapper; the other one is the fallback (default %(default)s)")
    g.add_argument("--camera-model", choices=("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "OPENCV", "RADIAL"),
                   default=_default(SfMConfig, "camera_model"),
                   help="shared SfM camera (default %(default)s)")
    g.add_argument("--fps", type=float, default=_default(IngestConfig, "fps"), metavar="F",
                   help="videos: keep about F frames per second, the sharpest of each interval (default: all)")


def add_pose_source(parser) -> None:
    g = parser.add_argument_group("pose source")
    g.add_argument("--poses", choices=("auto", "supplied", "colmap"), default="auto",
                   help="auto: the input's own poses when it has them, else SfM; colmap: always SfM (default auto)")
    g.add_argument("--gt-poses", default=None, metavar="SCAN",
                   help="scan whose poses score SfM's and align its mesh and depth (frames matched by name)")


def add_keyframes(parser) -> None:
    from recon.keyframes import KeyframeConfig

    parser.add_argument("--keyframe-distance", type=float, default=_default(KeyframeConfig, "keyframe_distance"),
                        metavar="D", help="camera motion (translation + rotation measure) between keyframes; "
                                          "0 = every frame (default %(default)s)")


def add_depth(parser, with_device: bool = False) -> None:
    from recon.keyframes import SourceConfig

    g = parser.add_argument_group("depth")
    g.add_argument("--mode", choices=DEPTH_MODES, default=None,
                   help="default: estm with the shipped (or --weights) network; planesweep when none ship")
    g.add_argument("--weights", default=None, metavar="NAME|PATH",
                   help="network weights: a shipped name or a checkpoint path (default: the shipped default)")
    g.add_argument("--config", default=None, help="refuse a checkpoint of another network config (lite, compact, paper)")
    g.add_argument("--window", choices=("offline", "online"), default=_default(SourceConfig, "window"),
                   help="sources before and after each frame (offline) or before only (online) (default %(default)s)")
    g.add_argument("--memory", type=int, default=None, metavar="N", help="ESTM memory length (default: the network's, 2)")
    g.add_argument("--depth-range", type=float, nargs=2, metavar=("MIN", "MAX"), default=None,
                   help="depth planes' range (default: the weights' trained range, else the scan's)")
    g.add_argument("--fit", choices=("stretch", "crop"), default="stretch",
                   help="fit frames to the network size: stretch the whole frame, or crop (scale to cover, keep "
                        "the aspect ratio; the cropped-off borders get no depth) (default %(default)s)")
    g.add_argument("--baseline", type=float, default=_default(SourceConfig, "source_baseline"),
                   help="translation a frame's sources should ideally have, in scan units (default %(default)s)")
    g.add_argument("--precision", choices=("fp32", "bf16"), default="fp32",
                   help="network arithmetic; bf16 autocast is faster on GPUs and bf16-capable CPUs (default fp32)")
    g.add_argument("--compile", action="store_true",
                   help="torch.compile the network: about a minute of compiling, then faster frames (GPU above all)")
    if with_device:
        add_device(g)


def add_fusion(parser, with_device: bool = False) -> None:
    from fusion.tsdf import TSDFConfig

    g = parser.add_argument_group("fusion")
    for flag, name, what in (("--voxel-size", "voxel_size", "voxel size in metres"),
                             ("--trunc-voxels", "trunc_voxels", "truncation distance in voxels"),
                             ("--depth-min", "depth_min", "fuse depth from this distance (m)"),
                             ("--depth-max", "depth_max", "fuse depth up to this distance (m)"),
                             ("--min-weight", "min_weight", "mesh only voxels observed at least this much")):
        g.add_argument(flag, type=float, default=_default(TSDFConfig, name), help=f"{what} (default %(default)s)")
    g.add_argument("--min-confidence", type=float, default=None,
                   help="drop predicted depth with confidence below this (needs <name>.conf.npy files; default off)")
    if with_device:
        add_device(g)


def add_evaluation(parser) -> None:
    g = parser.add_argument_group("evaluation")
    g.add_argument("--gt-mesh", default=None, help="ground-truth mesh to score against (default: the scan's own, or "
                                                   "the fusion of its ground-truth depth)")


# -- builders ---------------------------------------------------------------------------------------
def keyframe_config(args):
    from recon.keyframes import KeyframeConfig

    return KeyframeConfig(keyframe_distance=args.keyframe_distance).validate()


def depth_options(args, mode: str):
    from depth.options import DepthOptions
    from recon.keyframes import SourceConfig

    return DepthOptions(mode=mode, weights=args.weights, memory_size=args.memory,
                        depth_range=tuple(args.depth_range) if args.depth_range else None,
                        sources=SourceConfig(window=args.window, source_baseline=args.baseline),
                        device=args.device, config=args.config, precision=args.precision, fit=args.fit,
                        compile=args.compile).validate()


def tsdf_config(args):
    from fusion.tsdf import TSDFConfig

    return TSDFConfig(voxel_size=args.voxel_size, trunc_voxels=args.trunc_voxels, depth_min=args.depth_min,
                      depth_max=args.depth_max, min_confidence=args.min_confidence, min_weight=args.min_weight,
                      device=args.device).validate()


def poses_config(args):
    from poses.ingest import IngestConfig
    from poses.sfm import PosesConfig, SfMConfig

    return PosesConfig(ingest=IngestConfig(stride=args.stride, fps=args.fps, max_frames=args.max_frames),
                       sfm=SfMConfig(mapper=args.mapper, camera_model=args.camera_model))


def pick_mode(requested: str | None, weights: str | None) -> str:
    """ESTM with the given or shipped weights; the classical plane sweep, said out loud, when none ship."""
    if requested:
        return requested
    if weights is not None:
        return "estm"  # the depth stage names a missing or unreadable file
    from depth.checkpoint import DEFAULT_WEIGHTS, resolve_weights
    from recon.errors import ReconError

    try:
        resolve_weights(DEFAULT_WEIGHTS)
        return "estm"
    except ReconError:
        print(f"note: the shipped depth weights ({DEFAULT_WEIGHTS}) are missing, so depth comes from the classical "
              "plane sweep (pass --weights PATH to use a checkpoint from `recon train`)")
        return "planesweep"
