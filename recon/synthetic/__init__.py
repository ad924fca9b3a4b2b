"""Synthetic rooms with exact ground truth: procedural scenes, handheld camera paths, CPU rendering.

Used as training data for the depth network (`iter_training_scans`), as end-to-end test
fixtures and as demo input (`render_scan`, `write_synthetic_scan`). See docs/synthetic.md.
"""
from .effects import SensorEffects
from .generate import (TRAINING_SIZES, SynthConfig, camera_intrinsics, iter_training_mix, iter_training_scans,
                       render_scan, scene_mesh, write_synthetic_scan)
from .preview import contact_sheet
from .render import Renderer
from .scene import Scene, SceneConfig, generate_scene
from .textures import TextureLibrary, texture_library
from .trajectory import TrajectoryConfig, handheld_trajectory

__all__ = ["SensorEffects", "SynthConfig", "TRAINING_SIZES", "camera_intrinsics", "iter_training_mix",
           "iter_training_scans", "render_scan", "scene_mesh",
           "write_synthetic_scan", "contact_sheet", "Renderer", "Scene", "SceneConfig", "generate_scene",
           "TextureLibrary", "texture_library", "TrajectoryConfig", "handheld_trajectory"]
