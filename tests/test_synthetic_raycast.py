"""The renderer's two ray casters: the torch one (for machines without Open3D) answers as Open3D's does."""
import numpy as np
import pytest

from recon.scan import Intrinsics
from recon.synthetic.raycast import Open3DRaycaster, TorchRaycaster, make_raycaster
from recon.synthetic.render import Renderer
from recon.synthetic.scene import SceneConfig, generate_scene
from recon.synthetic.textures import texture_library
from recon.synthetic.trajectory import TrajectoryConfig, handheld_trajectory

pytestmark = pytest.mark.usefixtures("single_torch_thread")

TRIANGLE = np.array([[[0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [0.0, 1.0, 2.0]]])


def test_one_triangle_hit_miss_parallel_and_behind():
    caster = TorchRaycaster(TRIANGLE, device="cpu")
    dirs = np.array([[0.25, 0.5, 2.0],   # hits at t = 1: u = 0.25, v = 0.5
                     [0.8, 0.8, 2.0],    # outside (u + v > 1)
                     [1.0, 0.0, 0.0],    # parallel to the plane
                     [0.25, 0.5, -2.0]], np.float32)  # the triangle lies behind
    t, face, bary = caster.nearest(np.zeros(3, np.float32), dirs)
    assert t[0] == pytest.approx(1.0) and face[0] == 0 and bary[0] == pytest.approx([0.25, 0.5])
    assert np.isinf(t[1:]).all() and (face[1:] == np.iinfo(np.uint32).max).all()
    starts = np.array([[0.2, 0.2, 3.0], [0.2, 0.2, 1.0], [2.0, 2.0, 3.0]], np.float32)
    light = np.array([0.2, 0.2, 0.0], np.float32)
    assert caster.blocked(starts, light - starts, light).tolist() == [True, False, False]
    assert caster.sees(np.zeros(3), np.array([0.25, 0.5, 4.0]), 0.4) and not caster.sees(
        np.zeros(3), np.array([0.25, 0.5, 4.0]), 0.6)


@pytest.fixture(scope="module")
def room():
    library = texture_library(64)
    scene = generate_scene(5, library, SceneConfig())
    poses = handheld_trajectory(scene.free_space, 30, 10.0, np.random.default_rng(1), TrajectoryConfig(),
                                SceneConfig().camera_clearance_m)
    return scene, library, poses[::10]


def test_torch_caster_agrees_with_open3d_on_a_room(room):
    scene, _, poses = room
    o3d_caster, torch_caster = Open3DRaycaster(scene.vertices), TorchRaycaster(scene.vertices, device="cpu")
    rng = np.random.default_rng(0)
    for pose in poses:
        dirs = (pose[:3, :3] @ np.c_[rng.uniform(-0.6, 0.6, (600, 2)), np.ones(600)].T).T.astype(np.float32)
        origin = pose[:3, 3].astype(np.float32)
        (t0, f0, b0), (t1, f1, b1) = o3d_caster.nearest(origin, dirs), torch_caster.nearest(origin, dirs)
        assert np.isfinite(t0).all() and np.mean(f0 == f1) > 0.99  # inside a closed room every ray hits
        same = f0 == f1
        assert np.abs(t1[same] / t0[same] - 1).max() < 1e-4 and np.abs(b1[same] - b0[same]).max() < 1e-3
    verts = scene.vertices.reshape(-1, 3)
    points = rng.uniform(verts.min(0), verts.max(0), (2000, 3)).astype(np.float32)  # some behind walls or furniture
    lights = scene.light_positions.astype(np.float32)
    shadowed = np.stack([o3d_caster.blocked(points, light - points, light) for light in lights])
    assert 0.05 < shadowed.mean() < 0.95
    assert np.mean(np.stack([torch_caster.blocked(points, light - points, light) for light in lights])
                   == shadowed) > 0.99


def test_renders_match_across_casters(room):
    scene, library, poses = room
    pose = poses[0]
    camera = Intrinsics(fx=30.0, fy=30.0, cx=23.5, cy=17.5, width=48, height=36)
    (r0, d0), (r1, d1) = (Renderer(scene, library, raycaster=name).render_linear(pose, camera)
                          for name in ("open3d", "torch"))
    assert np.abs(d1 - d0).max() < 1e-3 and d0.min() > 0
    assert np.mean(np.abs(r1 - r0).max(-1) < 1e-3) > 0.99 and r0.mean() > 0.01


def test_unknown_caster_is_refused():
    with pytest.raises(ValueError, match="open3d, torch or auto"):
        make_raycaster(TRIANGLE, "embree")
    assert isinstance(make_raycaster(TRIANGLE), Open3DRaycaster)  # Open3D where it is installed
