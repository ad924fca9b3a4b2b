"""Any orientation: portrait frames reach the depth network at a portrait size, never squashed silently."""
import json
import math

import pytest

from depth.views import describe_view, network_size, network_view, view_message
from recon.synthetic import SynthConfig, render_scan


def upright_and_sideways(seed: int, frames: int, fps: float, size: tuple[int, int] = (320, 256)):
    """One walk through one room filmed with the phone held sideways (landscape, `size`) and upright
    (portrait, `size` turned): the same path and the same lens, so the same focal length in pixels; the
    upright frames see less to the sides and more above and below, gravity down in both."""
    w, h = size
    hfov = 60.0
    focal = w / 2 / math.tan(math.radians(hfov) / 2)
    upright_hfov = math.degrees(2 * math.atan(h / 2 / focal))
    return (render_scan(SynthConfig(seed=seed, frames=frames, width=w, height=h, fps=fps, hfov_deg=hfov)),
            render_scan(SynthConfig(seed=seed, frames=frames, width=h, height=w, fps=fps, hfov_deg=upright_hfov)))


def test_portrait_frames_get_a_portrait_network_size():
    assert network_size((640, 480), 320, 256) == (320, 256)
    assert network_size((1080, 1920), 320, 256) == (256, 320)  # a phone held upright
    (sideways, _), (upright, _) = upright_and_sideways(0, 2, 30.0, (80, 64))
    assert upright.intrinsics.fx == pytest.approx(sideways.intrinsics.fx)  # one lens
    view = network_view(upright, 320, 256, "stretch")
    assert view.intrinsics.size == (256, 320) and view.image(0).shape == (320, 256, 3)
    # Scaled 4x both ways, nothing stretched: square pixels stay square.
    assert view.intrinsics.fx == pytest.approx(view.intrinsics.fy) == pytest.approx(4 * upright.intrinsics.fx)
    said = describe_view((1080, 1920), 320, 256, "stretch")
    assert said["network_size"] == [256, 320] and said["turned"] and said["aspect_change"] == pytest.approx(1.422, 1e-3)
    assert "turned" in view_message(said) and "stretched" in view_message(said)
    assert describe_view((1080, 1920), 320, 256, "crop")["aspect_change"] == 1.0
    assert "aspect ratio kept" in view_message(describe_view((256, 320), 320, 256, "stretch"))


@pytest.mark.slow
def test_portrait_video_keeps_its_aspect_ratio_and_its_mesh_scores_like_the_landscape_twin(tmp_path):
    """ESTM depth and TSDF fusion of one walk filmed sideways (320x256) and upright (256x320): the portrait
    run is not squashed (the network runs at 256x320) and its mesh F-score is within 0.03 of the landscape's."""
    from depth.inference import estimate_depth
    from depth.options import DepthOptions
    from fusion.evaluate import mesh_metrics
    from fusion.tsdf import TSDFConfig, fuse_scan
    from recon.keyframes import KeyframeConfig, select_keyframes

    (sideways, gt_mesh), (upright, _) = upright_and_sideways(1, 40, 4.0)
    scores = {}
    for name, take in (("landscape", sideways), ("portrait", upright)):
        take = take.subset(select_keyframes(take.camera_to_world, KeyframeConfig(keyframe_distance=0.2)))
        summary = estimate_depth(take, tmp_path / name, DepthOptions(mode="estm", device="cpu"))
        assert summary["view"]["frame_size"] == list(take.intrinsics.size)
        assert summary["view"]["network_size"] == list(take.intrinsics.size)  # 320x256 / 256x320: no stretch
        assert json.loads((tmp_path / name / "depth.json").read_text())["view"]["aspect_change"] == 1.0
        mesh = fuse_scan(take, tmp_path / name, TSDFConfig(device="cpu"))
        scores[name] = mesh_metrics(mesh, gt_mesh, scan=take)["fscore"]
    assert scores["landscape"] > 0.2  # the comparison means something only if the meshes are real
    assert abs(scores["portrait"] - scores["landscape"]) <= 0.03, scores
