"""`recon eval depth|mesh|poses`: the evaluation protocols of DESIGN.md, each with --json."""
import math

from apps import options
from apps.common import open_selected_scan, print_json
from apps.progress import progress_bar


def register(subparsers):
    subparsers.add_parser("eval", help="evaluate depth maps, a mesh or poses against ground truth",
                          description="Evaluation against ground truth; every sub-command prints a table, "
                                      "or one JSON object with --json.", arguments=add_arguments)


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="what", metavar="WHAT")
    sub.add_parser("depth", help="depth accuracy and temporal coherence", arguments=_depth_arguments,
                   description="Eigen metrics (abs_rel abs sq_rel rmse rmse_log a1 a2 a3) averaged per frame, then "
                               "over frames, plus temporal coherence (mae_mean, mae_std, pose-aware flicker).")
    sub.add_parser("mesh", help="mesh accuracy / completeness / F-score", arguments=_mesh_arguments,
                   description="TransformerFusion protocol: points sampled with a fixed seed on each mesh, a "
                               "5 cm threshold, distances capped at 1 m; --scan culls points its cameras never saw.")
    sub.add_parser("poses", help="absolute trajectory error after Sim(3) alignment", arguments=_poses_arguments,
                   description="ATE RMSE of camera centres after a similarity alignment; frames matched by name.")
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _depth_arguments(d) -> None:
    from apps.pipeline import EvalConfig

    d.add_argument("--pred", required=True, help="folder of predicted depth maps (<frame name>.npy or .png)")
    d.add_argument("--scan", required=True, help="scan with ground-truth depth")
    options.add_format(d)
    options.add_selection(d)
    d.add_argument("--min-depth", type=float, default=1e-3, help="evaluation range start in metres")
    d.add_argument("--max-depth", type=float, default=EvalConfig.max_depth, help="evaluation range end in metres")
    d.add_argument("--size", default=None, metavar="WxH", help="evaluate at this resolution (GT resized, nearest)")
    d.add_argument("--align", choices=["none", "median"], default="none",
                   help="median: rescale each prediction to GT (for non-metric predictions; say so when reporting)")
    d.add_argument("--json", action="store_true", help="print one JSON object (with the per-frame rows)")
    d.set_defaults(func=run_depth)


def _mesh_arguments(m) -> None:
    from fusion.evaluate import MeshEvalConfig

    m.add_argument("pred", help="predicted mesh")
    m.add_argument("gt", help="ground-truth mesh")
    m.add_argument("--scan", default=None, help="scan whose cameras define the observed region (visibility culling)")
    options.add_format(m)
    options.add_selection(m)
    m.add_argument("--points", type=int, default=MeshEvalConfig.n_points, help="points sampled per mesh")
    m.add_argument("--threshold", type=float, default=MeshEvalConfig.threshold, help="distance threshold in metres")
    m.add_argument("--occlusion-margin", type=float, default=MeshEvalConfig.occlusion_margin,
                   help="with --scan: points up to this far (m) behind the GT depth still count as seen")
    m.add_argument("--seed", type=int, default=MeshEvalConfig.seed, help="point sampling seed")
    m.add_argument("--json", action="store_true", help="print one JSON object")
    m.set_defaults(func=run_mesh)


def _poses_arguments(q) -> None:
    q.add_argument("--pred", required=True, help="scan with estimated poses")
    q.add_argument("--gt", required=True, help="scan with ground-truth poses")
    q.add_argument("--no-scale", action="store_true", help="rigid (SE(3)) alignment instead of Sim(3)")
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=run_poses)


def _print(result: dict, as_json: bool) -> None:
    if as_json:
        print_json(result)
        return
    for k, v in result.items():
        print(f"{k:16s} {v:.4f}" if isinstance(v, float) and math.isfinite(v) else f"{k:16s} {v}")


def run_depth(args):
    from apps.common import parse_size
    from depth.metrics import evaluate_depth_folder

    scan = open_selected_scan(args.scan, args)
    if args.size:
        scan = scan.resized(*parse_size(args.size))
    with progress_bar("eval depth", len(scan), quiet=args.quiet or args.json) as advance:
        result = evaluate_depth_folder(args.pred, scan, args.min_depth, args.max_depth, args.align,
                                       progress=lambda i, n: advance())
    if not args.json:
        result.pop("per_frame")
    _print(result, args.json)
    return 0


def run_mesh(args):
    from fusion.evaluate import MeshEvalConfig, mesh_metrics
    from recon.errors import ReconError

    if args.points < 1 or args.threshold <= 0:
        raise ReconError("--points must be >= 1 and --threshold > 0")
    scan = open_selected_scan(args.scan, args) if args.scan else None
    config = MeshEvalConfig(n_points=args.points, threshold=args.threshold, seed=args.seed,
                            occlusion_margin=args.occlusion_margin)
    _print(mesh_metrics(args.pred, args.gt, scan, config), args.json)
    return 0


def run_poses(args):
    from poses.evaluate import pose_metrics
    from recon.readers import open_scan

    pred = open_scan(args.pred)
    result = pose_metrics(pred, open_scan(args.gt), with_scale=not args.no_scale)
    if not args.json:
        result.pop("alignment")
    result["metric_scale"] = pred.metadata.metric_scale
    _print(result, args.json)
    return 0
