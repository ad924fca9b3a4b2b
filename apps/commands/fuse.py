"""`recon fuse`: TSDF-fuse a scan's depth (GT or predicted, through the depth filter) into a colored mesh."""
from apps import options
from apps.common import open_selected_scan
from apps.progress import progress_bar


def register(subparsers):
    subparsers.add_parser("fuse", help="fuse depth maps into a mesh (TSDF)",
                          description="Integrate the depth of every selected frame into an Open3D TSDF volume "
                                      "and export the cleaned, colored mesh.", arguments=add_arguments)


def add_arguments(p) -> None:
    options.add_input(p)
    p.add_argument("--depth", default="gt", help="'gt' for the scan's own depth, or a folder of predicted depth maps")
    p.add_argument("--out", required=True, help="mesh file (.ply, .obj, .glb)")
    options.add_fusion(p, with_device=True)
    p.set_defaults(func=run)


def run(args):
    from fusion.filtering import filtered_depth
    from fusion.mesh import check_mesh_path, save_mesh
    from fusion.tsdf import fuse_scan

    config = options.tsdf_config(args)
    depth_filter = options.filter_config(args)
    cleanup = options.cleanup_config(args)
    check_mesh_path(args.out)
    scan = open_selected_scan(args.scan, args)
    source = filtered_depth(scan, args.depth, depth_filter, config)
    with progress_bar("fuse", len(scan), quiet=args.quiet) as advance:
        mesh = fuse_scan(scan, source, config, cleanup=cleanup, progress=lambda i, n: advance())
    save_mesh(mesh, args.out)
    stats = source.stats.as_dict()
    print(f"wrote {args.out}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces from {len(scan)} frames; "
          f"filter {','.join(source.config.checks) or 'none'} kept {stats['kept_share']:.1%} of the depth pixels "
          f"({stats['seconds']:.1f} s)")
    return 0
