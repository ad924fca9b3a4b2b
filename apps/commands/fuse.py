"""`recon fuse`: TSDF-fuse a scan's depth (GT or predicted) into a colored mesh."""
from apps import options
from apps.common import open_selected_scan
from apps.progress import progress_bar


def register(subparsers):
    p = subparsers.add_parser("fuse", help="fuse depth maps into a mesh (TSDF)",
                              description="Integrate the depth of every selected frame into an Open3D TSDF volume "
                                          "and export the cleaned, colored mesh.")
    options.add_input(p)
    p.add_argument("--depth", default="gt", help="'gt' for the scan's own depth, or a folder of predicted depth maps")
    p.add_argument("--out", required=True, help="mesh file (.ply, .obj, .glb)")
    p.add_argument("--no-cleanup", action="store_true", help="keep small disconnected pieces")
    options.add_fusion(p, with_device=True)
    p.set_defaults(func=run)


def run(args):
    from fusion.mesh import MeshCleanup, check_mesh_path, save_mesh
    from fusion.tsdf import fuse_scan

    config = options.tsdf_config(args)
    check_mesh_path(args.out)
    scan = open_selected_scan(args.scan, args)
    with progress_bar("fuse", len(scan), quiet=args.quiet) as advance:
        mesh = fuse_scan(scan, args.depth, config, cleanup=None if args.no_cleanup else MeshCleanup(),
                         progress=lambda i, n: advance())
    save_mesh(mesh, args.out)
    print(f"wrote {args.out}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces from {len(scan)} frames")
    return 0
