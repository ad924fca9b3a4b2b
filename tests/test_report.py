"""report.html's parts: figures rounded with units, colour scales, the decimated mesh and frustums of the 3D
view, and the page of a run without ground truth or metric scale (what a plain video gives)."""
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from apps.pipeline import InputConfig, Pipeline, RunConfig
from apps.report import (color_scale, decimated, format_value, frustum_lines, metric_tables, sfm_section,
                         summary_cards, write_report)
from recon.scan import Intrinsics
from tests.fixtures.box_room import box_room_scan


def test_figures_are_rounded_with_units():
    assert format_value(0.62519, "share", "m") == "62.5 %"
    assert format_value(1.01449, "length", "m") == "1.014 m" and format_value(2.0, "length", "units") == "2.000 units"
    assert format_value(float("nan"), "ratio", "m") == "n/a" and format_value(None, "length", "m") == "n/a"
    assert format_value(16, "count", "m") == "16" and format_value(0.226612, "ratio", "m") == "0.2266"
    cards = summary_cards({"memory": {"peak_rss_mb": 879.9375}, "timing": {"scan": 1.25, "depth": 159.61},
                           "stages": {"fusion": {"vertices": 22263, "faces": 37400},
                                      "depth": {"mode": "estm", "precision": "bf16", "seconds_per_frame": 0.47}}},
                          120, 16, False, "118 of 120")
    values = {c["label"]: c["value"] for c in cards}
    assert values["depth per keyframe (estm, bf16)"] == "0.5 s"  # and which arithmetic made the depth
    assert values["peak memory"] == "880 MB" and values["total time"] == "2.7 min"
    assert values["mesh triangles"] == "37,400" and values["scale"] == "SfM units"
    assert values["frames posed by SfM"] == "118 of 120"
    assert not any(label.startswith("network adapted") for label in values)
    adapted = {"mode": "estm", "seconds_per_frame": 9.1,
               "adaptation": {"steps": 60, "seconds": 258.4, "loss_start": 0.0612, "loss_end": 0.0498}}
    values = {c["label"]: c["value"] for c in summary_cards({"stages": {"depth": adapted}}, 30, 30, True, None)}
    assert values["network adapted to the scan (60 steps, included above)"] == "4.3 min, photometric loss 0.061 -> 0.050"
    table = metric_tables({"depth": {"abs_rel": 0.1234567, "a1": 0.8, "rmse": 0.5}}, "m")[0]
    assert [(r["label"], r["value"]) for r in table["rows"]] == [("Abs Rel", "0.1235"), ("δ < 1.25", "80.0 %"),
                                                                 ("RMSE", "0.500 m")]


def test_color_scale_ticks_span_the_range():
    scale = color_scale("depth (m)", 0.5, 4.5)
    assert scale["ticks"] == ["0.50", "1.50", "2.50", "3.50", "4.50"]
    assert scale["uri"].startswith("data:image/png;base64,")


def test_decimation_keeps_shape_and_colours():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=2.0)  # 20480 faces
    colors = np.zeros((len(sphere.vertices), 4), np.uint8)
    colors[:, 0] = np.where(sphere.vertices[:, 2] > 0, 220, 20)  # red top half, dark bottom half
    colors[:, 3] = 255
    sphere.visual.vertex_colors = colors
    small = decimated(sphere, 2000)
    assert 1500 <= len(small.faces) <= 2000
    assert np.allclose(np.linalg.norm(small.vertices, axis=1), 2.0, atol=0.05)  # still the sphere
    top = np.asarray(small.visual.vertex_colors)[small.vertices[:, 2] > 0.3, 0]
    bottom = np.asarray(small.visual.vertex_colors)[small.vertices[:, 2] < -0.3, 0]
    assert top.mean() > 200 and bottom.mean() < 40
    assert decimated(sphere, 50_000) is sphere  # small enough already


def test_frustum_corners_are_the_image_corners_at_the_given_depth():
    K = Intrinsics(100.0, 100.0, 50.0, 40.0, 100, 80)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 3.0]
    pts = frustum_lines(pose[None], K, 2.0)
    corners = pts[:4] - pose[:3, 3]
    assert np.allclose(corners, [[-1.0, -0.8, 2.0], [1.0, -0.8, 2.0], [1.0, 0.8, 2.0], [-1.0, 0.8, 2.0]])
    assert np.isnan(pts[5]).all() and np.allclose(pts[6], pose[:3, 3])  # then apex-to-corner segments


@pytest.fixture
def plain_run(small_run, tmp_path) -> Path:
    """The small run as a plain video would leave it: no ground-truth depth, scale unknown."""
    run = tmp_path / "run"
    shutil.copytree(small_run, run)
    doc = json.loads((run / "scan" / "scan.json").read_text())
    doc["metadata"]["metric_scale"] = False
    for frame in doc["frames"]:
        frame.pop("depth", None)
    (run / "scan" / "scan.json").write_text(json.dumps(doc))
    for name in ("metrics.json", "reference.ply"):
        (run / name).unlink()
    return run


def test_report_of_a_run_without_ground_truth(plain_run):
    pipeline = Pipeline(RunConfig(InputConfig(str(plain_run / "scan")), str(plain_run)))
    pipeline._load_state()
    report = pipeline.summary()
    write_report(pipeline, report, plain_run / "report.html")
    page = (plain_run / "report.html").read_text()
    assert "unknown: SfM units, not metres" in page and "depth accuracy" not in page
    for label in ("frames", "keyframes (depth maps)", "mesh triangles", "total time", "peak memory"):
        assert f'<div class="label">{label}</div>' in page, label
    keyframes = len(json.loads((plain_run / "keyframes.json").read_text())["keyframes"])
    assert f'<div class="value">{keyframes}</div>' in page
    assert "predicted depth (units)" in page and "confidence" in page and "ground truth" not in page
    assert "image | predicted depth (units) | confidence." in page  # the caption names the tiles there are
    figure = json.loads(re.search(r'<script type="application/json" id="view3d-figure">(.*?)</script>', page,
                                  re.S).group(1).replace("<\\/", "</"))
    names = [t["name"] for t in figure["data"]]
    assert names == ["mesh", "camera path", "keyframe cameras", "keyframes"]
    assert len(figure["data"][3]["text"]) == keyframes
    assert figure["layout"]["scene"]["xaxis"]["title"]["text"] == "x (units)"


def test_sfm_section_tells_displaced_frames_from_unregistered_ones():
    scan = box_room_scan(n_frames=4)
    scan.metadata.extra["sfm"] = {"mapper": "incremental", "registered": 5, "unregistered": ["f3", "f7", "f8"],
                                  "displaced": ["f7", "f8"], "track_length_histogram": {"2": 3, "3": 1}}
    section = sfm_section(scan)
    assert section["unregistered"] == "f3" and section["displaced"] == "f7, f8"
    assert dict((r["label"], r["value"]) for r in section["rows"])["frames posed"] == "5 of 5"


def test_sfm_section_says_which_mapping_of_a_photo_folder_was_kept():
    scan = box_room_scan(n_frames=4)
    scan.metadata.extra["sfm"] = {"mapper": "incremental", "registered": 4, "unregistered": [],
                                  "pair_pruning": {"pairs": 905, "pruned": 467, "kept": "pruned"}}
    rows = dict((r["label"], r["value"]) for r in sfm_section(scan)["rows"])
    assert rows["pairs far off the model"] == "467 of 905; kept the second mapping, without them"
    scan.metadata.extra["sfm"]["pair_pruning"] = {"pairs": 343, "pruned": 0, "kept": "first"}
    assert "pairs far off the model" not in [r["label"] for r in sfm_section(scan)["rows"]]


def test_sfm_section_says_which_mapper_a_short_clip_kept():
    scan = box_room_scan(n_frames=4)
    scan.metadata.extra["sfm"] = {
        "mapper": "global", "registered": 40, "unregistered": [], "model_dir": "/x/colmap/sparse/global-pinhole/0",
        "attempts": [{"attempt": "incremental-pinhole", "registered": 40, "agreeing_inliers": 19308},
                     {"attempt": "global-pinhole", "registered": 40, "agreeing_inliers": 41732}]}
    rows = dict((r["label"], r["value"]) for r in sfm_section(scan)["rows"])
    assert rows["mappers compared"] == ("incremental-pinhole: 40 frames, 19308 agreeing inliers; "
                                        "global-pinhole (kept): 40 frames, 41732 agreeing inliers")
    scan.metadata.extra["sfm"]["attempts"] = [{"attempt": "incremental-pinhole", "registered": 40}]
    assert "mappers compared" not in [r["label"] for r in sfm_section(scan)["rows"]]  # one attempt: nothing compared
