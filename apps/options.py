"""The one set of command-line options: every command that takes a setting takes it under the same
name, type and default, and builds the stage's own config from it (the defaults are the config
dataclasses' own, written once).

Each `add_*` function adds one group; the matching builder turns parsed arguments into that
stage's config. Heavy libraries are imported only by the builders, so `recon --help` stays fast.
"""
from __future__ import annotations

import argparse
import dataclasses

DEVICES = ("auto", "cpu", "cuda")


def _default(cls, name):
    return {f.name: f for f in dataclasses.fields(cls)}[name].default


def add_selection(parser: argparse.ArgumentParser, start: bool = True) -> None:
    """--start/--stride/--max-frames: every command that takes a scan accepts them (SfM: no --start)."""
    g = parser.add_argument_group("frame selection")
    if start:
        g.add_argument("--start", type=int, default=0, metavar="N", help="first frame to use (default 0)")
    g.add_argument("--stride", type=int, default=1, metavar="N", help="use every N-th frame (default 1)")
    g.add_argument("--max-frames", type=int, default=None, metavar="N", help="use at most N frames (default all)")


def add_format(parser) -> None:
    parser.add_argument("--format", default="auto", help="input format, see `recon formats` (default: auto-detect)")


def add_input(parser: argparse.ArgumentParser, name: str = "scan", help: str = "scan folder or file") -> None:
    parser.add_argument(name, help=f"{help} (any supported format, see `recon formats`)")
    add_format(parser)
    add_selection(parser)


def add_device(parser) -> None:
    parser.add_argument("--device", choices=DEVICES, default="auto",
                        help="where the network and fusion run (default auto: CUDA when present)")


def add_sfm(parser) -> None:
    """Every setting of SfM from plain images: frame choice, pycolmap, and the scale it is given."""
    from poses.ingest import IngestConfig
    from poses.scale import ScaleConfig
    from poses.sfm import CAMERA_MODELS, MAPPERS, MATCHERS, SfMConfig

    g = parser.add_argument_group("poses (SfM)")
    g.add_argument("--mapper", choices=MAPPERS, default=_default(SfMConfig, "mapper"),
                   help="SfM mapper; the other one is the fallback (default %(default)s)")
    g.add_argument("--camera-model", choices=CAMERA_MODELS, default=_default(SfMConfig, "camera_model"),
                   help="shared SfM camera; auto: pinhole unless the data shows lens distortion, starting from the "
                        "capture's own camera when it has one (default %(default)s)")
    g.add_argument("--matcher", choices=MATCHERS, default=_default(SfMConfig, "matcher"),
                   help="auto: all pairs for short clips and photo folders, neighbours in order for longer videos "
                        "(default %(default)s)")
    g.add_argument("--parallel-mapping", action="store_true",
                   help="match and map on all cores: faster, but poses can differ from run to run")
    g.add_argument("--fps", type=float, default=_default(IngestConfig, "fps"), metavar="F",
                   help="videos: keep about F frames per second, the sharpest of each interval (default: all)")
    g.add_argument("--min-motion", type=float, default=_default(IngestConfig, "min_motion_px"), metavar="PX",
                   help="keep a frame only once the image moved PX pixels (median) since the last kept one")
    g.add_argument("--blur-ratio", type=float, default=_default(IngestConfig, "blur_ratio"), metavar="R",
                   help="drop frames sharper than less than R x their neighbours' median (0 keeps all)")
    g.add_argument("--max-size", type=int, default=_default(IngestConfig, "max_size"), metavar="PX",
                   help="long side of the working images")
    g.add_argument("--no-fallback", action="store_true",
                   help="map once: no retry when the first mapping registers too few frames (other mapper, looser "
                        "initial pair, other camera model, all-pairs matching), and no comparison of the mappers on "
                        "a short clip")
    g.add_argument("--features", type=int, default=_default(SfMConfig, "max_num_features"), metavar="N",
                   help="SIFT features per image")
    g.add_argument("--overlap", type=int, default=_default(SfMConfig, "sequential_overlap"), metavar="N",
                   help="sequential matching window")
    g.add_argument("--no-loop-detection", action="store_true",
                   help="sequential matching: do not also match far-apart frames that look alike (revisits)")
    g.add_argument("--no-motion-check", action="store_true",
                   help="videos: keep a block of frames posed away from the path around it (by default such "
                        "frames, a repeating texture matched one repeat away, are left unposed)")
    g.add_argument("--no-placement-check", action="store_true",
                   help="photo folders: keep a photo that none of its matched pairs' own geometry agrees with (by "
                        "default such photos, a wall matched to a look-alike elsewhere, are left unposed)")
    g.add_argument("--no-pair-pruning", action="store_true",
                   help="photo folders: map once (by default SfM maps again without the matched pairs far off the "
                        "first model, repeated textures matched across walls, and keeps the model more pairs agree with)")
    c = parser.add_argument_group("SfM scale (default: normalised so the median scene depth is --target-depth)")
    x = c.add_mutually_exclusive_group()
    x.add_argument("--scale", type=float, default=None, metavar="FACTOR", help="metres per SfM unit")
    x.add_argument("--known-distance", nargs=3, metavar=("FRAME_A", "FRAME_B", "METRES"), default=None,
                   help="metres between the cameras of two frames (names as in the output scan)")
    c.add_argument("--target-depth", type=float, default=_default(ScaleConfig, "target_median_depth"), metavar="M",
                   help="normalisation: median sparse-point depth after scaling")


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
    from depth.options import FITS, MODES, PRECISIONS, AdaptOptions, DepthOptions
    from recon.keyframes import SourceConfig

    g = parser.add_argument_group("depth")
    g.add_argument("--mode", choices=MODES, default=None,
                   help="estm, joint, independent: the network; planesweep: classical stereo (sparse, precise); hybrid: "
                        "estm refined by a narrow plane sweep around its depth where the images match (about 1.5x estm's time). "
                        "Default: estm with the shipped (or --weights) network; planesweep when none ship")
    g.add_argument("--weights", default=None, metavar="NAME|PATH",
                   help="network weights: a shipped name or a checkpoint path (default: the shipped default)")
    g.add_argument("--config", default=None, help="refuse a checkpoint of another network config (lite, compact, paper)")
    g.add_argument("--window", choices=("offline", "online"), default=_default(SourceConfig, "window"),
                   help="sources before and after each frame (offline) or before only (online) (default %(default)s)")
    g.add_argument("--memory", type=int, default=None, metavar="N", help="ESTM memory length (default: the network's, 2)")
    g.add_argument("--depth-range", type=float, nargs=2, metavar=("MIN", "MAX"), default=None,
                   help="depth planes' range (default: the weights' trained range, else the scan's)")
    g.add_argument("--fit", choices=FITS, default=_default(DepthOptions, "fit"),
                   help="fit frames to the network size: stretch the whole frame, or crop (scale to cover, keep "
                        "the aspect ratio; the cropped-off borders get no depth) (default %(default)s)")
    g.add_argument("--baseline", type=float, default=_default(SourceConfig, "source_baseline"),
                   help="translation a frame's sources should ideally have, in scan units (default %(default)s)")
    g.add_argument("--precision", choices=PRECISIONS, default=_default(DepthOptions, "precision"),
                   help="network arithmetic: bf16 autocast, fp32, or auto (the default): bf16 where the GPU or CPU "
                        "computes it in hardware (AMX, AVX512-BF16), else fp32")
    g.add_argument("--compile", action="store_true",
                   help="torch.compile the network: about a minute of compiling, then faster frames (GPU above all)")
    g.add_argument("--mirror-pass", action="store_true",
                   help="also run the left-right mirrored video and keep, per pixel, the more confident depth: "
                        "better depth and meshes for twice the network time (docs/depth.md)")
    g.add_argument("--adapt-steps", type=int, default=_default(AdaptOptions, "steps"), metavar="N",
                   help="fine-tune the network on the scan itself first (photometric, no ground truth needed; "
                        "about 4-6 s a step on a CPU, 60 steps measured best; docs/depth.md) (default %(default)s: off)")
    g.add_argument("--adapt-lr", type=float, default=_default(AdaptOptions, "lr"), metavar="LR",
                   help="learning rate of --adapt-steps (default %(default)s)")
    if with_device:
        add_device(g)


def add_depth_storage(parser) -> None:
    parser.add_argument("--full-res-depth", action="store_true",
                        help="store depth maps at the images' resolution (default: at the network's, whose long "
                             "side they have: an upsampled copy holds no more information and is many times larger)")


def add_fusion(parser, with_device: bool = False) -> None:
    """TSDF settings, mesh cleanup and the depth filter."""
    from fusion.mesh import MeshCleanup
    from fusion.tsdf import TSDFConfig

    g = parser.add_argument_group("fusion")
    for flag, name, what in (("--voxel-size", "voxel_size", "voxel size in metres"),
                             ("--trunc-voxels", "trunc_voxels", "truncation distance in voxels"),
                             ("--depth-min", "depth_min", "fuse depth from this distance (m)"),
                             ("--depth-max", "depth_max", "fuse depth up to this distance (m)"),
                             ("--min-weight", "min_weight", "mesh only voxels observed at least this much")):
        g.add_argument(flag, type=float, default=_default(TSDFConfig, name), help=f"{what} (default %(default)s)")
    g.add_argument("--min-confidence", type=float, default=None,
                   help="drop depth with confidence below this (0-1): the stored confidence maps (the network's), "
                        "for depth without them the depth filter's consistency score (default off)")
    g.add_argument("--min-component-area", type=float, default=_default(MeshCleanup, "min_component_area"),
                   metavar="M2", help="drop mesh pieces smaller than this many square metres; 0 keeps all "
                                      "(default %(default)s)")
    if with_device:
        add_device(g)
    add_depth_filter(parser)


def add_depth_filter(parser) -> None:
    from fusion.filtering import CHECKS, NETWORK_CHECKS, FilterConfig

    g = parser.add_argument_group("depth filter (before fusion)")
    g.add_argument("--filter", default="auto", metavar="CHECKS",
                   help=f"none, or a comma list of {', '.join(CHECKS)}; auto: {','.join(NETWORK_CHECKS)} for a "
                        "network's depth, none for the plane sweep's (already checked against its sources) or a "
                        "scan's own depth (default auto)")
    for flag, name, kind, metavar, what in (
            ("--filter-views", "views", int, "N", "consistency: nearest keyframes each depth map is checked against"),
            ("--filter-min-views", "min_views", int, "N", "consistency: of them, how many must agree"),
            ("--filter-max-diff", "max_rel_diff", float, "REL",
             "consistency: relative depth difference still agreeing"),
            ("--edge-angle", "edge_max_angle", float, "DEG",
             "edges: drop pixels whose surface is seen more than DEG degrees from its normal"),
            ("--photo-max-diff", "max_color_diff", float, "D",
             "photometric: grey-level difference (image / its mean) still agreeing")):
        g.add_argument(flag, type=kind, default=_default(FilterConfig, name), metavar=metavar,
                       help=f"{what} (default %(default)s)")
    g.add_argument("--filter-weights", action=argparse.BooleanOptionalAction,
                   default=_default(FilterConfig, "weights"),
                   help="weigh each pixel in the TSDF by its consistency score (default %(default)s)")
    g.add_argument("--near-weight-m", type=float, default=_default(FilterConfig, "near_weight_m"), metavar="M",
                   help="predicted depth: each pixel weighs M / depth in the TSDF, so nearer views count more "
                        "(0: every pixel alike; default %(default)s)")


def add_evaluation(parser) -> None:
    g = parser.add_argument_group("evaluation")
    g.add_argument("--gt-mesh", default=None, help="ground-truth mesh to score against (default: the scan's own, or "
                                                   "the fusion of its ground-truth depth)")


# -- builders ---------------------------------------------------------------------------------------
def keyframe_config(args):
    from recon.keyframes import KeyframeConfig

    return KeyframeConfig(keyframe_distance=args.keyframe_distance).validate()


def depth_options(args, mode: str):
    from depth.options import AdaptOptions, DepthOptions
    from recon.keyframes import SourceConfig

    return DepthOptions(mode=mode, weights=args.weights, memory_size=args.memory,
                        depth_range=tuple(args.depth_range) if args.depth_range else None,
                        sources=SourceConfig(window=args.window, source_baseline=args.baseline),
                        device=args.device, config=args.config, precision=args.precision, fit=args.fit,
                        compile=args.compile, mirror_pass=args.mirror_pass,
                        adapt=AdaptOptions(steps=args.adapt_steps, lr=args.adapt_lr),
                        full_resolution=args.full_res_depth).validate()


def tsdf_config(args):
    from fusion.tsdf import TSDFConfig

    return TSDFConfig(voxel_size=args.voxel_size, trunc_voxels=args.trunc_voxels, depth_min=args.depth_min,
                      depth_max=args.depth_max, min_confidence=args.min_confidence, min_weight=args.min_weight,
                      device=args.device).validate()


def filter_config(args):
    """The depth filter of the command line; `--filter auto` is settled per depth source when fusion runs."""
    from fusion.filtering import FilterConfig, parse_checks

    return FilterConfig(checks=parse_checks(args.filter), views=args.filter_views, min_views=args.filter_min_views,
                        max_rel_diff=args.filter_max_diff, edge_max_angle=args.edge_angle,
                        max_color_diff=args.photo_max_diff, weights=args.filter_weights,
                        near_weight_m=args.near_weight_m).validate()


def cleanup_config(args):
    from fusion.mesh import MeshCleanup

    return MeshCleanup(min_component_area=args.min_component_area).validate()


def poses_config(args):
    from poses.ingest import IngestConfig
    from poses.scale import ScaleConfig
    from poses.sfm import PosesConfig, SfMConfig
    from recon.errors import ReconError

    known = None
    if args.known_distance:
        try:
            known = (args.known_distance[0], args.known_distance[1], float(args.known_distance[2]))
        except ValueError:
            raise ReconError(f"--known-distance: {args.known_distance[2]!r} is not a number of metres") from None
    return PosesConfig(
        ingest=IngestConfig(stride=args.stride, fps=args.fps, max_frames=args.max_frames, min_motion_px=args.min_motion,
                            blur_ratio=args.blur_ratio, max_size=args.max_size),
        sfm=SfMConfig(mapper=args.mapper, fallback=not args.no_fallback, camera_model=args.camera_model,
                      matcher=args.matcher, deterministic=not args.parallel_mapping,
                      max_num_features=args.features, sequential_overlap=args.overlap,
                      loop_detection=not args.no_loop_detection, motion_check=not args.no_motion_check,
                      placement_check=not args.no_placement_check, pair_pruning=not args.no_pair_pruning).validate(),
        scale=ScaleConfig(factor=args.scale, known_distance=known, target_median_depth=args.target_depth))


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
