"""Scoring a video run (issue 13): poses from SfM, ground truth from `--gt-poses`, metrics in the GT's frame and scale."""
import pytest

from apps.pipeline import InputConfig, Pipeline, RunConfig


@pytest.mark.slow
def test_video_run_with_gt_poses_scores_like_the_supplied_pose_run(tmp_path):
    """The same synthetic room twice: its recorded scan (supplied poses) and its video through pycolmap with the
    scan as --gt-poses. The video run's mesh is moved by the trajectory's Sim(3) and scored against the scan's
    GT mesh, its depth scaled into metres and scored against the scan's GT depth: the figures must match."""
    from recon.synthetic import SynthConfig, write_synthetic_scan

    room = write_synthetic_scan(SynthConfig(seed=1, frames=48, width=320, height=240, fps=8.0), tmp_path / "room",
                                video=True)
    reports = {}
    for name, source in (("supplied", InputConfig(str(room))),
                         ("video", InputConfig(str(room / "video.mp4"), gt_poses=str(room)))):
        pipeline = Pipeline(RunConfig(source, str(tmp_path / name)))
        pipeline.run(until="evaluate")
        reports[name] = pipeline.summary()
    supplied, video = reports["supplied"], reports["video"]
    assert "poses" not in supplied and video["poses"]["registered"] > 0.9 and video["poses"]["ate_rmse"] < 0.05
    assert video["metric_scale"] is False and video["stages"]["reference"]["source"].endswith("gt_mesh.ply")
    assert video["depth"]["align"] == "sim3" and supplied["depth"]["align"] == "none"
    assert video["depth"]["abs_rel"] == pytest.approx(supplied["depth"]["abs_rel"], abs=0.05)
    assert supplied["mesh"]["fscore"] > 0.3  # a real reconstruction, so agreement means something
    assert video["mesh"]["fscore"] == pytest.approx(supplied["mesh"]["fscore"], abs=0.02), (video["mesh"],
                                                                                            supplied["mesh"])
