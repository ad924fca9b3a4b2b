"""Honest capture metadata: transforms.json scale as the file states it, missing images skipped and counted."""
import json
import logging

import pytest

from apps.cli import main
from recon.readers import open_scan
from recon.scan import load_scan
from recon.synthetic.generate import SynthConfig, write_synthetic_scan


@pytest.fixture
def transforms_folder(tmp_path):
    """A rendered room exported as transforms.json + images/ (the canonical scan.json removed), 12 listed frames."""
    room = write_synthetic_scan(SynthConfig(seed=2, frames=12, width=160, height=128, fps=6.0), tmp_path / "room",
                                video=True)
    (room / "scan.json").unlink()
    return room


def _edit(folder, change):
    doc = json.loads((folder / "transforms.json").read_text())
    change(doc)
    (folder / "transforms.json").write_text(json.dumps(doc))


def test_transforms_json_is_metric_only_when_it_says_so(transforms_folder):
    assert open_scan(transforms_folder).metadata.metric_scale is True  # our writer states it
    _edit(transforms_folder, lambda doc: doc.pop("metric_scale"))
    assert open_scan(transforms_folder).metadata.metric_scale is False  # nerfstudio / instant-ngp: no unit
    _edit(transforms_folder, lambda doc: doc.update(metric_scale="yes"))
    assert open_scan(transforms_folder).metadata.metric_scale is False  # only a JSON true counts


def test_missing_images_are_skipped_with_one_warning_and_counted(transforms_folder, caplog, capsys):
    for name in ("frame_000003", "frame_000004", "frame_000009"):
        (transforms_folder / "images" / f"{name}.jpg").unlink()
    with caplog.at_level(logging.WARNING):
        scan = open_scan(transforms_folder)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "3 of 12 listed images are missing" in warnings[0].getMessage()
    assert len(scan) == 9 and "frame_000004" not in scan.names
    assert scan.metadata.extra["missing_images"] == 3
    assert main(["info", str(transforms_folder), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == 9 and info["missing_images"] == 3


def _drop_two(folder):
    for name in ("frame_000002", "frame_000007"):
        (folder / "images" / f"{name}.jpg").unlink()


def test_pipeline_scan_stage_takes_the_frames_that_exist(transforms_folder, tmp_path):
    from apps.pipeline import InputConfig, Pipeline, RunConfig

    _drop_two(transforms_folder)
    out = tmp_path / "run"
    Pipeline(RunConfig(input=InputConfig(path=str(transforms_folder)), out=str(out)).validate()).run(until="scan")
    scan = load_scan(out / "scan")
    assert len(scan) == 10 and "frame_000007" not in scan.names and scan.metadata.metric_scale
    keyframes = json.loads((out / "keyframes.json").read_text())["keyframes"]
    assert keyframes and set(keyframes) <= set(scan.names)


@pytest.mark.slow
def test_run_on_a_transforms_json_with_missing_images_uses_the_rest(transforms_folder, tmp_path):
    _drop_two(transforms_folder)
    out = tmp_path / "run"
    code = main(["run", str(transforms_folder), "--out", str(out), "--mode", "planesweep", "--keyframe-distance", "0",
                 "--quiet"])
    assert code == 0
    assert len(load_scan(out / "scan")) == 10 and (out / "mesh.ply").is_file()


def test_a_transforms_json_without_any_image_is_one_line_error(transforms_folder, capsys):
    for image in (transforms_folder / "images").glob("*.jpg"):
        image.unlink()
    assert main(["info", str(transforms_folder)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("recon: error:") and "\n" not in err and "none of the 12 listed images exists" in err
