"""report.html: one self-contained page (pictures embedded as data URIs, plots as inline SVG).

It loads offline and records, in `data-*` attributes of <body>, how many images loaded and
any script error, so a headless browser can check it.
"""
from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

import cv2
import numpy as np

from recon.io import write_bytes_atomic

PLOT_W, PLOT_H = 560, 220


def png_data_uri(rgb: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode()


def colorize(values: np.ndarray, lo: float, hi: float, valid: np.ndarray | None = None) -> np.ndarray:
    """Float map -> uint8 RGB with a perceptual colormap; invalid pixels black."""
    norm = np.clip((values - lo) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.cvtColor(cv2.applyColorMap((norm * 255).astype(np.uint8), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    if valid is not None:
        rgb[~valid] = 0
    return rgb


def svg_line_plot(series: dict[str, list[float | None]], title: str, y_label: str) -> str:
    """A small multi-series line plot; None values are gaps."""
    colors = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"]
    vals = [v for s in series.values() for v in s if v is not None and math.isfinite(v)]
    if not vals:
        return f"<p>{html.escape(title)}: no data</p>"
    lo, hi = min(0.0, min(vals)), max(vals) * 1.05 or 1.0
    n = max(len(s) for s in series.values())
    pad = 40

    def xy(i, v):
        x = pad + (PLOT_W - pad - 10) * (i / max(n - 1, 1))
        y = PLOT_H - pad + (-(PLOT_H - pad - 20)) * ((v - lo) / (hi - lo))
        return f"{x:.1f},{y:.1f}"

    parts = [f'<svg width="{PLOT_W}" height="{PLOT_H}" xmlns="http://www.w3.org/2000/svg" role="img">',
             f'<text x="{PLOT_W / 2}" y="14" text-anchor="middle" font-size="13">{html.escape(title)}</text>',
             f'<line x1="{pad}" y1="{PLOT_H - pad}" x2="{PLOT_W - 10}" y2="{PLOT_H - pad}" stroke="#888"/>',
             f'<line x1="{pad}" y1="20" x2="{pad}" y2="{PLOT_H - pad}" stroke="#888"/>',
             f'<text x="4" y="24" font-size="11">{hi:.3g}</text>',
             f'<text x="4" y="{PLOT_H - pad}" font-size="11">{lo:.3g}</text>',
             f'<text x="{PLOT_W / 2}" y="{PLOT_H - 8}" text-anchor="middle" font-size="11">keyframe</text>',
             f'<text x="4" y="{PLOT_H / 2}" font-size="11">{html.escape(y_label)}</text>']
    for k, (name, s) in enumerate(series.items()):
        color = colors[k % len(colors)]
        pts = " ".join(xy(i, v) for i, v in enumerate(s) if v is not None and math.isfinite(v))
        parts.append(f'<polyline fill="none" stroke="{color}" stroke-width="1.5" points="{pts}"/>')
        parts.append(f'<text x="{PLOT_W - 150}" y="{34 + 14 * k}" font-size="11" fill="{color}">{html.escape(name)}</text>')
    parts.append("</svg>")
    return "".join(parts)


def svg_trajectory(centres: np.ndarray, keyframe_mask: np.ndarray, up: np.ndarray) -> str:
    """Top-down view of the camera path (projected along `up`); keyframes as dots."""
    up = up / np.linalg.norm(up)
    a = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    xy = np.stack([centres @ a, centres @ b], 1)
    lo, hi = xy.min(0), xy.max(0)
    span = max((hi - lo).max(), 1e-6)
    size, pad = 320, 20
    pts = pad + (xy - lo) / span * (size - 2 * pad)
    path = " ".join(f"{x:.1f},{y:.1f}" for x, y in pts)
    dots = "".join(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="2.5" fill="#d62728"/>' for x, y in pts[keyframe_mask])
    return (f'<svg width="{size}" height="{size}" xmlns="http://www.w3.org/2000/svg" role="img">'
            f'<rect width="{size}" height="{size}" fill="#fafafa" stroke="#ccc"/>'
            f'<polyline fill="none" stroke="#1f77b4" stroke-width="1.5" points="{path}"/>{dots}'
            f'<circle cx="{pts[0, 0]:.1f}" cy="{pts[0, 1]:.1f}" r="5" fill="none" stroke="#2ca02c" stroke-width="2"/>'
            f'<text x="6" y="{size - 6}" font-size="11">{span:.2f} units across; green: start, red: keyframes</text></svg>')


def svg_bars(values: dict[str, float], title: str, unit: str) -> str:
    if not values:
        return ""
    top = max(values.values()) or 1.0
    rows = []
    for k, (name, v) in enumerate(values.items()):
        w = 300 * v / top
        y = 24 + 22 * k
        rows.append(f'<text x="4" y="{y + 12}" font-size="12">{html.escape(name)}</text>'
                    f'<rect x="90" y="{y}" width="{w:.1f}" height="15" fill="#1f77b4"/>'
                    f'<text x="{96 + w:.1f}" y="{y + 12}" font-size="11">{v:.2f} {unit}</text>')
    height = 30 + 22 * len(values)
    return (f'<svg width="{PLOT_W}" height="{height}" xmlns="http://www.w3.org/2000/svg" role="img">'
            f'<text x="4" y="14" font-size="13">{html.escape(title)}</text>{"".join(rows)}</svg>')


def _table(section: dict) -> str:
    cells = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{_fmt(v)}</td></tr>" for k, v in section.items()
                    if not isinstance(v, (dict, list)))
    return f"<table>{cells}</table>"


def _fmt(v) -> str:
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.4f}"
    return html.escape(str(v))


def depth_panels(pipeline, count: int) -> list[tuple[str, str]]:
    """(frame name, data URI) of image | predicted depth | GT depth | abs error, for sampled keyframes."""
    from recon.io import load_depth_map

    scan = pipeline.keyframe_scan()
    picks = np.unique(np.linspace(0, len(scan) - 1, min(count, len(scan))).round().astype(int))
    out = []
    for i in picks:
        rgb = scan.image(i)
        pred = load_depth_map(pipeline.out / "depth", scan.frames[i].name)
        h, w = rgb.shape[:2]
        if pred.shape != (h, w):
            pred = cv2.resize(pred, (w, h), interpolation=cv2.INTER_NEAREST)
        gt = scan.depth(i)
        ref = gt if gt is not None and (gt > 0).any() else pred
        lo, hi = np.percentile(ref[ref > 0], [2, 98]) if (ref > 0).any() else (0.0, 1.0)
        tiles = [rgb, colorize(pred, lo, hi, pred > 0)]
        if gt is not None:
            valid = (gt > 0) & (pred > 0)
            tiles += [colorize(gt, lo, hi, gt > 0), colorize(np.abs(pred - gt), 0, 0.25 * hi, valid)]
        strip = np.concatenate([cv2.resize(t, (240, int(240 * h / w))) for t in tiles], 1)
        out.append((scan.frames[i].name, png_data_uri(strip)))
    return out


def write_report(pipeline, report: dict, path: Path) -> None:
    """Render the run's report page from report.json's content and the run folder's files."""
    from fusion.mesh import load_mesh
    from fusion.render import preview_views

    scan = pipeline.load_scan()
    poses = scan.camera_to_world
    up = -poses[:, :3, 1].mean(0)  # cameras are held upright: their image-down axis points at the floor
    keys = set(pipeline.keyframe_names())
    key_mask = np.array([f.name in keys for f in scan.frames])
    body = [f"<h1>Reconstruction report</h1><p>Input <code>{html.escape(pipeline.config.input.path)}</code>, "
            f"{len(scan)} frames, {key_mask.sum()} keyframes, depth mode <b>{html.escape(pipeline.config.depth.mode)}</b>. "
            f"Scale: <b>{'metric (metres)' if report.get('metric_scale') else 'unknown (arbitrary units)'}</b>.</p>"]
    body.append("<h2>Summary</h2><div class='row'>")
    for name in ("depth", "temporal", "mesh", "poses"):
        if name in report:
            body.append(f"<div><h3>{name}</h3>{_table(report[name])}</div>")
    body.append(f"<div><h3>memory</h3>{_table({'peak_rss_mb': report['memory']['peak_rss_mb']})}</div></div>")
    body.append("<h2>Camera path (top-down)</h2>" + svg_trajectory(poses[:, :3, 3], key_mask, up))
    metrics_path = pipeline.out / "metrics.json"
    per_frame = json.loads(metrics_path.read_text()).get("depth_per_frame", []) if metrics_path.is_file() else []
    if per_frame:
        body.append("<h2>Per-frame error and flicker</h2>")
        body.append(svg_line_plot({"abs rel": [r["abs_rel"] for r in per_frame]}, "Abs Rel per keyframe", "abs rel"))
        body.append(svg_line_plot({"flicker": [r["flicker"] for r in per_frame]},
                                  "Flicker with the previous keyframe", "rel. disagreement"))
    body.append("<h2>Depth</h2><p>image | predicted depth | ground truth | absolute error (when GT exists)</p>")
    for name, uri in depth_panels(pipeline, pipeline.config.report.frames):
        body.append(f"<figure><img src='{uri}' alt='depth of frame {html.escape(name)}'>"
                    f"<figcaption>frame {html.escape(name)}</figcaption></figure>")
    mesh_path = pipeline.out / "mesh.ply"
    if mesh_path.is_file():
        body.append("<h2>Mesh</h2><div class='row'>")
        for label, img in preview_views(load_mesh(mesh_path), up):
            body.append(f"<figure><img src='{png_data_uri(img)}' alt='mesh {label}'><figcaption>{label}</figcaption></figure>")
        body.append("</div>")
    body.append("<h2>Stage timings</h2>" + svg_bars(report.get("timing", {}), "wall time per stage", "s"))
    body.append(f"<h2>Configuration</h2><pre>{html.escape(json.dumps(report.get('config', {}), indent=1))}</pre>")
    page = f"""<!doctype html><html lang="en"><head><meta charset="utf-8"><title>Reconstruction report</title>
<style>body{{font-family:sans-serif;margin:24px;max-width:1200px}} table{{border-collapse:collapse;margin:4px}}
th,td{{border:1px solid #ddd;padding:2px 8px;text-align:left;font-size:13px}} .row{{display:flex;flex-wrap:wrap;gap:16px}}
figure{{margin:6px}} img{{max-width:100%}} pre{{background:#f6f6f6;padding:8px;font-size:12px}}</style>
<script>window.addEventListener('error',function(e){{document.body.dataset.errors=(document.body.dataset.errors||'')+e.message+';'}});
window.addEventListener('load',function(){{var imgs=[].slice.call(document.images);
document.body.dataset.images=imgs.length;document.body.dataset.imagesLoaded=imgs.filter(function(i){{return i.complete&&i.naturalWidth>0}}).length;}});</script>
</head><body>{''.join(body)}</body></html>"""
    write_bytes_atomic(path, page.encode())
