"""`recon fuse`: TSDF-fuse a scan's depth (GT or predicted) into a colored mesh."""
from apps.common import add_scan_args, open_selected_scan
from apps.progress import progress_bar


def add_fusion_args(parser):
    from fusion.tsdf import TSDFConfig

    d = TSDFConfig()
    g = parser.add_argument_group("fusion")
    g.add_argument("--voxel-size", type=float, default=d.voxel_size, help=f"voxel size in metres (default {d.voxel_size})")
    g.add_argument("--trunc-voxels", type=float, default=d.trunc_voxels,
                   help=f"truncation distance in voxels (default {d.trunc_voxels})")
    g.add_argument("--depth-min", type=float, default=d.depth_min, help=f"ignore depth below (default {d.depth_min} m)")
    g.add_argument("--depth-max", type=float, default=d.depth_max, help=f"ignore depth beyond (default {d.depth_max} m)")
    g.add_argument("--min-confidence", type=float, default=None,
                   help="drop predicted depth with confidence below this (needs <name>.conf.npy files)")
    g.add_argument("--min-weight", type=float, default=d.min_weight,
                   help=f"mesh only voxels observed at least this many times (default {d.min_weight})")
    g.add_argument("--fusion-device", default="auto", help="auto, cpu, cuda (default auto)")


def fusion_config(args):
    from fusion.tsdf import TSDFConfig

    return TSDFConfig(voxel_size=args.voxel_size, trunc_voxels=args.trunc_voxels, depth_min=args.depth_min,
                      depth_max=args.depth_max, min_confidence=args.min_confidence, min_weight=args.min_weight,
                      device=args.fusion_device)


def register(subparsers):
    p = subparsers.add_parser("fuse", help="fuse depth maps into a mesh (TSDF)",
                              description="Integrate the depth of every selected frame into an Open3D TSDF volume "
                                          "and export the cleaned, colored mesh.")
    add_scan_args(p)
    p.add_argument("--depth", default="gt", help="'gt' for the scan's own depth, or a folder of predicted depth maps")
    p.add_argument("--out", required=True, help="mesh file (.ply, .obj, .glb)")
    p.add_argument("--no-cleanup", action="store_true", help="keep small disconnected pieces")
    add_fusion_args(p)
    p.set_defaults(func=run)


def run(args):
    from fusion.mesh import MeshCleanup, check_mesh_path, save_mesh
    from fusion.tsdf import fuse_scan

    config = fusion_config(args).validate()
    check_mesh_path(args.out)
    scan = open_selected_scan(args.scan, args)
    with progress_bar("fuse", len(scan), quiet=args.quiet) as advance:
        mesh = fuse_scan(scan, args.depth, config, cleanup=None if args.no_cleanup else MeshCleanup(),
                         progress=lambda i, n: advance())
    save_mesh(mesh, args.out)
    print(f"wrote {args.out}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces from {len(scan)} frames")
    return 0
