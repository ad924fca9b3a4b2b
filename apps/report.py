"""report.html: one self-contained page, templated with Jinja2 (`apps/templates/report.html.j2`).

plotly.js, which the plotly package ships (MIT), is inlined once and draws the interactive 3D view
(the mesh decimated for the browser, the camera path and keyframe frustums) and the plots; the
pictures are PNG data URIs with colour scales in their units. Nothing is fetched: the page's
Content-Security-Policy refuses any request, and <body> records in data-* attributes how many
images loaded, whether the 3D view drew (and how much of it is not background), script errors
and refused fetches, so a headless browser can check it.
"""
from __future__ import annotations

import base64
import json
import math
from pathlib import Path

import cv2
import numpy as np

from recon.io import write_bytes_atomic

TEMPLATE = "report.html.j2"
MAX_VIEW_FACES = 60_000  # triangles the 3D view gets; a fused room has several hundred thousand
MAX_FRUSTUMS = 80
TILE_WIDTH = 320
COLORMAP = cv2.COLORMAP_TURBO

# Known report figures: key -> (label, what it is, kind); kind says how to print it.
METRICS = {
    "abs_rel": ("Abs Rel", "mean |d - d*| / d* over valid pixels", "ratio"),
    "abs": ("Abs", "mean |d - d*|", "length"),
    "sq_rel": ("Sq Rel", "mean (d - d*)^2 / d*", "length"),
    "rmse": ("RMSE", "root mean squared depth error", "length"),
    "rmse_log": ("RMSE log", "root mean squared error of log depth", "ratio"),
    "a1": ("δ < 1.25", "share of pixels with max(d/d*, d*/d) < 1.25", "share"),
    "a2": ("δ < 1.25²", "share of pixels with max(d/d*, d*/d) < 1.5625", "share"),
    "a3": ("δ < 1.25³", "share of pixels with max(d/d*, d*/d) < 1.953", "share"),
    "within_5cm": ("within 5 cm", "share of pixels whose depth is within 5 cm (the mesh score's threshold)", "share"),
    "near_5cm": ("over 5 cm near", "share of pixels whose depth is more than 5 cm too near: surfaces in front of the true ones",
                 "share"),
    "edge_precision": ("edge precision", "share of predicted occluding edges (a >10 % depth jump between neighbours) "
                       "within 2 px of a true one", "share"),
    "edge_recall": ("edge recall", "share of true occluding edges with a predicted one within 2 px", "share"),
    "edge_f": ("edge F", "harmonic mean of edge precision and recall: 0 for depth that blurs over object edges", "ratio"),
    "coverage": ("coverage", "share of ground-truth pixels that got a prediction", "share"),
    "median_ratio": ("scale", "median of d / d*: 1 = no scale bias, 1.1 = everything 10 % too far", "ratio"),
    "frames": ("frames", "frames scored", "count"),
    "min_depth": ("range from", "evaluation range start", "length"),
    "max_depth": ("range to", "evaluation range end", "length"),
    "align": ("alignment", "none: metric as predicted; median: each map rescaled to the ground truth", "text"),
    "mae_mean": ("MAE mean", "mean over frames of each frame's mean absolute error", "length"),
    "mae_std": ("MAE std", "its standard deviation over frames (the paper's temporal figure)", "length"),
    "flicker": ("flicker", "relative disagreement of consecutive maps reprojected with the poses", "ratio"),
    "acc": ("accuracy", "mean distance from predicted mesh points to the ground truth", "length"),
    "comp": ("completeness", "mean distance from ground-truth points to the predicted mesh", "length"),
    "chamfer": ("chamfer", "mean of accuracy and completeness", "length"),
    "prec": ("precision", "share of predicted points within 5 cm of the ground truth", "share"),
    "recall": ("recall", "share of ground-truth points within 5 cm of the prediction", "share"),
    "fscore": ("F-score", "harmonic mean of precision and recall", "ratio"),
    "ate_rmse": ("ATE RMSE", "camera-centre error after a Sim(3) alignment", "length"),
    "ate_median": ("ATE median", "median camera-centre error after the alignment", "length"),
    "registered": ("registered", "share of ground-truth frames SfM posed", "share"),
    "sim3_scale": ("Sim(3) scale", "ground-truth metres per SfM unit", "ratio"),
    "scale": ("Sim(3) scale", "ground-truth metres per SfM unit", "ratio"),
    "frames_matched": ("frames matched", "frames scored by name", "count"),
    "trajectory_length": ("path length", "length of the ground-truth camera path", "length"),
    "pred_points": ("predicted points", "points sampled on the predicted mesh after culling", "count"),
    "gt_points": ("ground-truth points", "points sampled on the ground truth after culling", "count"),
    "threshold": ("threshold", "distance under which a point counts as matched", "length"),
}
SECTIONS = (("depth", "depth accuracy"), ("temporal", "temporal coherence"), ("mesh", "mesh accuracy"),
            ("poses", "pose accuracy"))


def png_data_uri(rgb: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode()


def colorize(values: np.ndarray, lo: float, hi: float, valid: np.ndarray | None = None,
             colormap: int = COLORMAP) -> np.ndarray:
    """Float map -> uint8 RGB with a perceptual colour map; invalid pixels black."""
    norm = np.clip((values - lo) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.cvtColor(cv2.applyColorMap((norm * 255).astype(np.uint8), colormap), cv2.COLOR_BGR2RGB)
    if valid is not None:
        rgb[~valid] = 0
    return rgb


def color_scale(label: str, lo: float, hi: float, digits: int = 2, colormap: int = COLORMAP) -> dict:
    """A horizontal colour bar with five ticks for a map drawn by `colorize(…, lo, hi)`."""
    ramp = colorize(np.linspace(lo, hi, 256, dtype=np.float32)[None, :].repeat(4, 0), lo, hi, colormap=colormap)
    return {"label": label, "uri": png_data_uri(ramp),
            "ticks": [f"{v:.{digits}f}" for v in np.linspace(lo, hi, 5)]}


def format_value(value, kind: str, unit: str) -> str:
    """A figure as people read it: rounded, with its unit; n/a for a missing one."""
    if value is None or isinstance(value, float) and not math.isfinite(value):
        return "n/a"
    if kind == "share" and isinstance(value, (int, float)):
        return f"{100 * value:.1f} %"
    if kind == "length" and isinstance(value, (int, float)):
        return f"{value:.3f} {unit}"
    if kind == "count" or isinstance(value, (bool, int)):
        return str(value)
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def metric_tables(report: dict, unit: str) -> list[dict]:
    """One table per metric section the run has (depth, temporal, mesh, poses)."""
    tables = []
    for key, title in SECTIONS:
        section = report.get(key)
        if not isinstance(section, dict):
            continue
        rows = []
        for name, value in section.items():
            if isinstance(value, (dict, list)) or name == "metric_scale":
                continue
            label, help_text, kind = METRICS.get(name, (name, "", "ratio"))
            rows.append({"label": label, "help": help_text, "value": format_value(value, kind, unit)})
        tables.append({"title": title, "rows": rows})
    return tables


def _seconds(value: float) -> str:
    return f"{value:.1f} s" if value < 120 else f"{value / 60:.1f} min"


def summary_cards(report: dict, frames: int, keyframes: int, metric: bool, posed: str | None) -> list[dict]:
    """What a run is, even without ground truth: frames, keyframes, scale, mesh size, time, memory."""
    stages = report.get("stages", {})
    cards = [{"label": "frames", "value": frames}, {"label": "keyframes (depth maps)", "value": keyframes},
             {"label": "scale", "value": "metres" if metric else "SfM units"}]
    if posed:
        cards.append({"label": "frames posed by SfM", "value": posed})
    fusion = stages.get("fusion", {})
    if "faces" in fusion:
        cards.append({"label": "mesh triangles", "value": f"{fusion['faces']:,}"})
        cards.append({"label": "mesh vertices", "value": f"{fusion['vertices']:,}"})
    depth_filter = report.get("filter")
    if depth_filter:
        checks = ", ".join(depth_filter["checks"]) or "range only"
        cards.append({"label": f"depth filter ({checks})", "value": f"kept {depth_filter['kept_share']:.0%} of the "
                                                                    f"pixels in {_seconds(depth_filter['seconds'])}"})
    depth = stages.get("depth", {})
    if depth.get("seconds_per_frame") is not None:
        arithmetic = f", {depth['precision']}" if depth.get("precision") else ""  # the network's, if one ran
        cards.append({"label": f"depth per keyframe ({depth.get('mode', '')}{arithmetic})",
                      "value": _seconds(depth["seconds_per_frame"])})
    adaptation = depth.get("adaptation")
    if adaptation:
        cards.append({"label": f"network adapted to the scan ({adaptation['steps']} steps, included above)",
                      "value": f"{_seconds(adaptation['seconds'])}, photometric loss {adaptation['loss_start']:.3f} "
                               f"-> {adaptation['loss_end']:.3f}"})
    timing = report.get("timing", {})
    if timing:
        cards.append({"label": "total time", "value": _seconds(sum(timing.values()))})
    peak = report.get("memory", {}).get("peak_rss_mb")
    if peak:
        cards.append({"label": "peak memory", "value": f"{peak / 1024:.1f} GB" if peak >= 1024 else f"{peak:.0f} MB"})
    return cards


def sfm_section(scan) -> dict | None:
    """Registered frames, model size, track lengths and reprojection error of an SfM run (None otherwise)."""
    sfm = scan.metadata.extra.get("sfm")
    if not sfm:
        return None
    ingest = scan.metadata.extra.get("ingest", {})
    displaced = sfm.get("displaced") or []
    rows = [("mapper", sfm.get("mapper"), "the pycolmap mapper whose model was kept"),
            ("frames posed", f"{sfm.get('registered')} of {ingest.get('kept', sfm.get('registered'))}",
             "frames with a pose (of the frames SfM was given)"),
            ("3D points", sfm.get("points3D"), "triangulated points of the model"),
            ("mean track length", sfm.get("mean_track_length"), "images that see each point, on average"),
            ("mean reprojection error", sfm.get("mean_reprojection_error_px"), "pixels, after bundle adjustment"),
            ("observations per image", sfm.get("mean_observations_per_image"), "points each image sees"),
            ("camera", (sfm.get("camera") or {}).get("model"), "the shared camera model SfM refined"),
            ("parallax", sfm.get("parallax"), "median homography parallax of the matched pairs")]
    compared = [a for a in sfm.get("attempts") or [] if "agreeing_inliers" in a]
    if len(compared) > 1:
        kept = Path(sfm.get("model_dir", "")).parent.name
        rows.append(("mappers compared", "; ".join(
            f"{a['attempt']}{' (kept)' if a['attempt'] == kept else ''}: {a['registered']} frames, "
            f"{a['agreeing_inliers']} agreeing inliers" for a in compared),
            "a short clip is mapped by each mapper, and the model more matched pairs agree with is kept"))
    pruning = sfm.get("pair_pruning") or {}
    if pruning.get("pruned"):
        rows.append(("pairs far off the model", f"{pruning['pruned']} of {pruning['pairs']}; kept the "
                     f"{'second mapping, without them' if pruning['kept'] == 'pruned' else 'first mapping'}",
                     "photos: verified pairs whose own geometry is far off the first model (repeated textures); "
                     "SfM mapped again without them and kept the model more pairs agree with"))
    return {"rows": [{"label": k, "value": "n/a" if v is None else v, "help": h} for k, v, h in rows],
            "timings": [(k, _seconds(v)) for k, v in (sfm.get("timings_s") or {}).items()],
            "unregistered": ", ".join(_with_links(n, sfm.get("unregistered_links") or {})
                                      for n in sfm.get("unregistered") or [] if n not in displaced),
            "displaced": ", ".join(displaced),
            "tracks": track_length_plot(sfm.get("track_length_histogram") or {})}


def _with_links(name: str, links: dict[str, int]) -> str:
    """An unregistered frame's name, with the most verified matches it shares with a posed frame when known."""
    return f"{name} ({links[name]} matches with a posed frame)" if name in links else name


def track_length_plot(histogram: dict[str, int]) -> str | None:
    """How many 3D points each number of images sees (the last bar: that many or more)."""
    import plotly.graph_objects as go

    if not histogram:
        return None
    last = max(histogram, key=int)
    labels = [f"{k}+" if k == last and int(k) >= 12 else k for k in histogram]
    fig = go.Figure(go.Bar(x=labels, y=list(histogram.values()), marker={"color": "#2ca02c"}))
    fig.update_xaxes(title_text="images seeing the point (track length)", type="category")
    fig.update_yaxes(title_text="3D points")
    fig.update_layout(height=260, width=520, margin={"l": 60, "r": 10, "t": 36, "b": 50},
                      title={"text": "track lengths", "x": 0})
    return _plot_html(fig)


def decimated(mesh, max_faces: int = MAX_VIEW_FACES):
    """The mesh with at most `max_faces` triangles (quadric decimation; vertex colours kept), as trimesh."""
    if len(mesh.faces) <= max_faces:
        return mesh
    import open3d as o3d
    import trimesh

    o3 = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
                                   o3d.utility.Vector3iVector(np.asarray(mesh.faces, np.int32)))
    o3.vertex_colors = o3d.utility.Vector3dVector(np.asarray(mesh.visual.vertex_colors)[:, :3] / 255.0)
    small = o3.simplify_quadric_decimation(target_number_of_triangles=max_faces)
    colors = np.clip(np.asarray(small.vertex_colors) * 255, 0, 255).astype(np.uint8)
    return trimesh.Trimesh(np.asarray(small.vertices), np.asarray(small.triangles), vertex_colors=colors,
                           process=False)


def frustum_lines(poses: np.ndarray, intrinsics, size: float) -> np.ndarray:
    """Line segments (NaN-separated points) of a pyramid per camera: apex to the image corners at `size`."""
    K_inv = np.linalg.inv(intrinsics.K)
    w, h = intrinsics.width, intrinsics.height
    corners = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float) @ K_inv.T
    corners *= size / corners[:, 2:3]
    order = [0, 1, 2, 3, 0]
    gap = np.full((1, 3), np.nan)
    parts = []
    for pose in poses:
        world = corners @ pose[:3, :3].T + pose[:3, 3]
        apex = pose[:3, 3][None]
        parts += [world[order], gap]
        for c in world:
            parts += [apex, c[None], gap]
    return np.concatenate(parts) if parts else np.zeros((0, 3))


def view3d_figure(mesh, scan, key_mask: np.ndarray, up: np.ndarray, unit: str) -> str:
    """The plotly figure (JSON) of the 3D view: the vertex-coloured mesh, the camera path, keyframe frustums."""
    import plotly.graph_objects as go

    poses = scan.camera_to_world
    centres = poses[:, :3, 3]
    traces = []
    if mesh is not None and len(mesh.faces):
        v, f = np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int32)
        colors = np.asarray(mesh.visual.vertex_colors)[:, :3]
        traces.append(go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2], name="mesh",
                                vertexcolor=[f"rgb({r},{g},{b})" for r, g, b in colors], showlegend=True,
                                flatshading=False, hoverinfo="skip",
                                lighting={"ambient": 0.65, "diffuse": 0.5, "specular": 0.05, "roughness": 0.9}))
        extent = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))
    else:
        extent = float(np.linalg.norm(np.ptp(centres, axis=0))) or 1.0
    keys = np.flatnonzero(key_mask)[:: max(1, int(np.ceil(key_mask.sum() / MAX_FRUSTUMS)))]
    lines = frustum_lines(poses[keys], scan.intrinsics, 0.04 * extent)
    traces.append(go.Scatter3d(x=centres[:, 0], y=centres[:, 1], z=centres[:, 2], mode="lines", name="camera path",
                               line={"color": "#1f77b4", "width": 4}, hoverinfo="skip"))
    traces.append(go.Scatter3d(x=lines[:, 0], y=lines[:, 1], z=lines[:, 2], mode="lines", name="keyframe cameras",
                               line={"color": "#d62728", "width": 2}, hoverinfo="skip"))
    traces.append(go.Scatter3d(x=centres[key_mask, 0], y=centres[key_mask, 1], z=centres[key_mask, 2],
                               mode="markers", name="keyframes", marker={"size": 3, "color": "#d62728"},
                               text=[f.name for f, k in zip(scan.frames, key_mask) if k], hoverinfo="text"))
    up = up / np.linalg.norm(up)
    eye = 0.9 * up + 1.5 * _behind_cameras(poses, up)  # looking the way the cameras look, from above them
    axis = {"title": {"text": ""}, "showbackground": False, "gridcolor": "#e5e5e5", "zeroline": False}
    layout = go.Layout(
        margin={"l": 0, "r": 0, "t": 0, "b": 0}, legend={"x": 0.01, "y": 0.99, "bgcolor": "rgba(255,255,255,0.7)"},
        paper_bgcolor="white", scene={
            "aspectmode": "data", "xaxis": {**axis, "title": {"text": f"x ({unit})"}},
            "yaxis": {**axis, "title": {"text": f"y ({unit})"}}, "zaxis": {**axis, "title": {"text": f"z ({unit})"}},
            "camera": {"up": dict(zip("xyz", map(float, up))), "eye": dict(zip("xyz", map(float, eye)))}})
    return go.Figure(traces, layout).to_json(validate=False)


def _behind_cameras(poses: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The horizontal unit direction opposite to where the cameras look on average."""
    forward = poses[:, :3, 2].mean(0)
    back = -(forward - (forward @ up) * up)
    if np.linalg.norm(back) < 1e-6:  # cameras looking straight down (or all ways): any horizontal direction
        back = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
    return back / np.linalg.norm(back)


def _plot_html(fig) -> str:
    import plotly.io as pio

    return pio.to_html(fig, full_html=False, include_plotlyjs=False, config={"displaylogo": False, "responsive": True})


def per_frame_plot(rows: list[dict]) -> str | None:
    """Abs Rel and flicker per keyframe, on two y axes with ticks and labels."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    if not rows:
        return None
    names = [r["name"] for r in rows]
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, vertical_spacing=0.08,
                        subplot_titles=("Abs Rel per keyframe (lower is better)",
                                        "flicker with the previous keyframe (relative disagreement)"))
    fig.add_trace(go.Scatter(x=names, y=[r.get("abs_rel") for r in rows], mode="lines+markers", name="Abs Rel"), 1, 1)
    fig.add_trace(go.Scatter(x=names, y=[r.get("flicker") for r in rows], mode="lines+markers", name="flicker",
                             line={"color": "#d62728"}), 2, 1)
    fig.update_yaxes(title_text="Abs Rel", rangemode="tozero", row=1, col=1)
    fig.update_yaxes(title_text="flicker", rangemode="tozero", row=2, col=1)
    fig.update_xaxes(title_text="keyframe", type="category", row=2, col=1)
    fig.update_layout(height=460, margin={"l": 70, "r": 20, "t": 40, "b": 60}, showlegend=False,
                      title={"text": "Per-frame error and flicker", "x": 0})
    return _plot_html(fig)


def timing_plot(report: dict) -> str | None:
    """Wall time and peak memory per stage, as horizontal bars with their values."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    timing = report.get("timing", {})
    if not timing:
        return None
    stages = list(timing)
    memory = report.get("memory", {}).get("per_stage_mb", {})
    fig = make_subplots(rows=1, cols=2, shared_yaxes=True, horizontal_spacing=0.06,
                        subplot_titles=("wall time per stage", "peak memory (RSS) per stage"))
    fig.add_trace(go.Bar(y=stages, x=[timing[s] for s in stages], orientation="h", name="time",
                         text=[_seconds(timing[s]) for s in stages], textposition="auto"), 1, 1)
    fig.add_trace(go.Bar(y=stages, x=[memory.get(s, 0) for s in stages], orientation="h", name="memory",
                         marker={"color": "#9467bd"}, text=[f"{memory.get(s, 0):.0f} MB" for s in stages],
                         textposition="auto"), 1, 2)
    fig.update_xaxes(title_text="seconds", row=1, col=1)
    fig.update_xaxes(title_text="MB", row=1, col=2)
    fig.update_yaxes(autorange="reversed")
    fig.update_layout(height=80 + 34 * len(stages), margin={"l": 90, "r": 20, "t": 40, "b": 50}, showlegend=False,
                      title={"text": "Stage timings and memory", "x": 0})
    return _plot_html(fig)


def _picks(n: int, count: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(count, n)).round().astype(int))


def _tile(rgb: np.ndarray, width: int = TILE_WIDTH) -> str:
    h, w = rgb.shape[:2]
    return png_data_uri(cv2.resize(rgb, (width, max(1, round(width * h / w))), interpolation=cv2.INTER_NEAREST))


def depth_rows(pipeline, count: int, unit: str) -> tuple[list[dict], list[dict], list[str]]:
    """Sampled keyframes as tiles (image, prediction, GT and error when metric GT exists, confidence),
    the colour scales they share, and the column names."""
    from depth.metrics import on_gt_grid
    from recon.io import load_confidence_map, load_depth_map

    scan = pipeline.keyframe_scan()
    folder = pipeline.out / "depth"
    frames = []
    for i in _picks(len(scan), count):
        name = scan.frames[i].name
        gt = scan.depth(i) if scan.metadata.metric_scale else None
        frames.append((name, scan.image(i), load_depth_map(folder, name), load_confidence_map(folder, name),
                       gt if gt is not None and (gt > 0).any() else None))
    with_gt = any(f[4] is not None for f in frames)
    with_conf = any(f[3] is not None for f in frames)
    ref = np.concatenate([(f[4] if f[4] is not None else f[2]).ravel() for f in frames])
    lo, hi = np.percentile(ref[ref > 0], [2, 98]) if (ref > 0).any() else (0.0, 1.0)
    errors = [np.abs(on_gt_grid(f[2], f[4]) - f[4])[(f[4] > 0) & (on_gt_grid(f[2], f[4]) > 0)] for f in frames if
              f[4] is not None]
    err_hi = max(float(np.percentile(np.concatenate(errors), 95)), 1e-3) if errors and sum(map(len, errors)) else 1.0
    rows = []
    for name, rgb, pred, conf, gt in frames:
        tiles = [{"label": "image", "uri": _tile(rgb)}, {"label": f"predicted depth ({unit})",
                                                         "uri": _tile(colorize(pred, lo, hi, pred > 0))}]
        if with_gt:
            tiles.append({"label": f"ground truth ({unit})",
                          "uri": _tile(colorize(gt, lo, hi, gt > 0)) if gt is not None else _tile(rgb * 0)})
            if gt is not None:
                p = on_gt_grid(pred, gt)
                tiles.append({"label": f"|error| ({unit})", "uri": _tile(colorize(np.abs(p - gt), 0, err_hi,
                                                                                    (gt > 0) & (p > 0)))})
        if with_conf:
            tiles.append({"label": "confidence", "uri": _tile(colorize(conf, 0, 1, colormap=cv2.COLORMAP_VIRIDIS))
                          if conf is not None else _tile(rgb * 0)})
        rows.append({"name": name, "tiles": tiles})
    scales = [color_scale(f"depth ({unit}); black: no depth", lo, hi)]
    if with_gt:
        scales.append(color_scale(f"absolute error ({unit}), 95th percentile and above at the top", 0.0, err_hi, 3))
    if with_conf:
        scales.append(color_scale("confidence (0-1) of the prediction", 0.0, 1.0, colormap=cv2.COLORMAP_VIRIDIS))
    return rows, scales, [t["label"] for t in rows[0]["tiles"]] if rows else []


def write_report(pipeline, report: dict, path: Path) -> None:
    """Render the run's report page from report.json's content and the run folder's files."""
    import jinja2
    from plotly.offline import get_plotlyjs

    from fusion.mesh import load_mesh
    from fusion.render import preview_views

    scan = pipeline.load_scan()
    metric = bool(scan.metadata.metric_scale)
    unit = "m" if metric else "units"
    up = -scan.camera_to_world[:, :3, 1].mean(0)  # cameras are held upright: their image-down axis points at the floor
    keys = set(pipeline.keyframe_names())
    key_mask = np.array([f.name in keys for f in scan.frames])
    mesh_path = pipeline.out / "mesh.ply"
    mesh = load_mesh(mesh_path) if mesh_path.is_file() else None
    view_mesh = decimated(mesh) if mesh is not None else None
    metrics_path = pipeline.out / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
    sfm = sfm_section(scan)
    posed = next((r["value"] for r in sfm["rows"] if r["label"] == "frames posed"), None) if sfm else None
    rows, scales, columns = depth_rows(pipeline, pipeline.config.report.frames, unit)
    notes = [metrics[k] for k in ("mesh_skipped", "mesh_alignment") if isinstance(metrics.get(k), str)]
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(Path(__file__).parent / "templates"),
                             autoescape=True, undefined=jinja2.StrictUndefined)
    page = env.get_template(TEMPLATE).render(
        title=Path(pipeline.config.input.path).name or pipeline.config.input.path, input=pipeline.config.input.path,
        frames=len(scan), keyframes=int(key_mask.sum()), depth_mode=pipeline.config.depth.mode, metric=metric,
        pose_source="from SfM (pycolmap)" if pipeline.poses_from_sfm else
        f"supplied by the input ({scan.metadata.source_format or 'canonical'})",
        cards=summary_cards(report, len(scan), int(key_mask.sum()), metric, posed),
        tables=metric_tables(report, unit), notes=notes, sfm=sfm, plotly_js=get_plotlyjs(),
        view3d_json=view3d_figure(view_mesh, scan, key_mask, up, unit).replace("</", "<\\/"),
        view_faces=len(view_mesh.faces) if view_mesh is not None else 0,
        mesh_faces=len(mesh.faces) if mesh is not None else 0,
        plots=[p for p in (per_frame_plot(metrics.get("depth_per_frame", [])), timing_plot(report)) if p],
        depth_rows=rows, depth_scales=scales, depth_columns=max(len(columns), 1),
        depth_caption="Each row is a keyframe: " + " | ".join(columns) + ".",
        renders=[(label, png_data_uri(img)) for label, img in preview_views(mesh, up)] if mesh is not None and len(
            mesh.faces) else [],
        config=json.dumps(report.get("config", {}), indent=1))
    write_bytes_atomic(path, page.encode())
