"""Camera imperfections, all optional and seeded: exposure and white-balance drift, motion
blur, sensor noise and JPEG compression. Depth stays exact: they change only the color image.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from recon.errors import ReconError
from recon.geometry import backproject_pixels, invert_pose, project, transform_points
from recon.scan import Intrinsics

from .trajectory import smooth_noise

MAX_BLUR_PX = 15.0


@dataclass(frozen=True)
class SensorEffects:
    """Strength of each effect; the defaults switch every effect off (clean images)."""

    noise_sigma: float = 0.0  # Gaussian noise, standard deviation in 8-bit levels
    motion_blur: float = 0.0  # shutter open time as a fraction of the frame interval (0.5 = 1/60 s at 30 fps)
    exposure_drift: float = 0.0  # standard deviation of the slow log-exposure drift (auto-exposure hunting)
    white_balance_drift: float = 0.0  # standard deviation of the slow per-channel gain drift
    jpeg_quality: int | None = None  # re-encode every frame at this quality (None = off)

    @classmethod
    def realistic(cls) -> "SensorEffects":
        """A phone-like mix: mild noise, 1/60 s shutter, gentle auto-exposure drift, JPEG 85."""
        return cls(noise_sigma=2.0, motion_blur=0.5, exposure_drift=0.08, white_balance_drift=0.02, jpeg_quality=85)

    def validate(self) -> "SensorEffects":
        if not 0 <= self.noise_sigma <= 50:
            raise ReconError(f"sensor noise sigma must be in [0, 50] levels, got {self.noise_sigma}")
        if not 0 <= self.motion_blur <= 1:
            raise ReconError(f"motion blur (shutter fraction) must be in [0, 1], got {self.motion_blur}")
        if not (0 <= self.exposure_drift <= 1 and 0 <= self.white_balance_drift <= 1):
            raise ReconError("exposure and white-balance drift must be in [0, 1]")
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            raise ReconError(f"JPEG quality must be in [1, 100], got {self.jpeg_quality}")
        return self


def camera_gains(effects: SensorEffects, frames: int, fps: float, rng: np.random.Generator) -> np.ndarray:
    """(frames, 3) per-channel multipliers of linear radiance: exposure times white balance."""
    t = np.arange(frames) / fps
    exposure = np.exp(effects.exposure_drift * smooth_noise(t, rng, (0.05, 0.3)))
    balance = np.stack([np.exp(effects.white_balance_drift * smooth_noise(t, rng, (0.02, 0.2)))
                        for _ in range(3)], axis=1)
    return (exposure[:, None] * balance).astype(np.float32)


def image_motion_px(prev_to_world: np.ndarray, camera_to_world: np.ndarray, depth: np.ndarray,
                    intrinsics: Intrinsics) -> np.ndarray:
    """Mean image displacement (dx, dy) of a grid of scene points between two poses (pixels)."""
    h, w = depth.shape
    v, u = np.mgrid[h // 6:h:h // 3, w // 6:w:w // 3].reshape(2, -1)
    z = depth[v, u].astype(np.float64)
    ok = z > 0
    if not ok.any():
        return np.zeros(2)
    u, v, z = u[ok], v[ok], z[ok]
    pts = backproject_pixels(u, v, z, intrinsics.K)
    q = transform_points(invert_pose(prev_to_world) @ camera_to_world, pts)
    front = q[:, 2] > 1e-3
    if not front.any():
        return np.zeros(2)
    uv, _ = project(q[front], intrinsics.K)
    return np.median(np.stack([u[front], v[front]], 1) - uv, axis=0)


def motion_blur(image: np.ndarray, displacement_px: np.ndarray) -> np.ndarray:
    """Blur along a straight image-space motion of the given (dx, dy) length (pixels)."""
    length = float(np.hypot(*displacement_px))
    if length < 0.75:
        return image
    if length > MAX_BLUR_PX:
        displacement_px = np.asarray(displacement_px) * (MAX_BLUR_PX / length)
        length = MAX_BLUR_PX
    size = 2 * int(math.ceil(length / 2)) + 1
    scale = 8
    kernel = np.zeros((size * scale, size * scale), np.float32)
    centre = np.array([size * scale / 2, size * scale / 2])
    a = centre - np.asarray(displacement_px) * scale / 2
    b = centre + np.asarray(displacement_px) * scale / 2
    cv2.line(kernel, tuple(int(round(x)) for x in a), tuple(int(round(x)) for x in b), 1.0, thickness=scale)
    kernel = cv2.resize(kernel, (size, size), interpolation=cv2.INTER_AREA)
    kernel /= kernel.sum()
    return cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REFLECT)


def add_noise(image: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    noisy = image.astype(np.float32) + rng.standard_normal(image.shape, dtype=np.float32) * np.float32(sigma)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8)


def jpeg_roundtrip(image: np.ndarray, quality: int) -> np.ndarray:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ReconError("could not JPEG-encode a synthetic frame")
    return cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def apply_image_effects(image: np.ndarray, effects: SensorEffects, rng: np.random.Generator,
                        displacement_px: np.ndarray | None) -> np.ndarray:
    """Blur, then noise, then compression: the order a camera applies them."""
    if effects.motion_blur > 0 and displacement_px is not None:
        image = motion_blur(image, np.asarray(displacement_px) * effects.motion_blur)
    if effects.noise_sigma > 0:
        image = add_noise(image, effects.noise_sigma, rng)
    if effects.jpeg_quality is not None:
        image = jpeg_roundtrip(image, effects.jpeg_quality)
    return image
