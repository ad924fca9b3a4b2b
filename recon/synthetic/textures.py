"""The texture library: photographs bundled with scikit-image plus procedural patterns.

Every texture is a square, seamlessly repeating RGB image of `size` texels (a power
of two) stored in linear light with its mip pyramid, all of them packed into one
flat array so the renderer finds any texel of any texture and level with a single
gather. Per-scene variety comes from tints and UV scales, so the library itself is
built once per process.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
import skimage.data

from recon.errors import ReconError


@dataclass(frozen=True)
class TextureSpec:
    """What a texture is for: `tile_m` metres per repeat when tiled, or a picture placed once (decal)."""

    name: str
    tile_m: float  # physical size of one repeat (0 for decals, which span the face once)
    aspect: float = 1.0  # width / height of the original picture (decals keep it on the face)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear light."""
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0), 1 / 2.4) - 0.055)


def periodic_noise(size: int, rng: np.random.Generator, scale_texels: float, octaves: int = 1) -> np.ndarray:
    """Smooth noise that repeats seamlessly every `size` texels (filtered in the Fourier domain).

    Returns (size, size) float with zero mean and unit standard deviation.
    """
    total = np.zeros((size, size))
    freqs = np.fft.fftfreq(size)
    radius = np.hypot(freqs[:, None], freqs[None, :])
    for octave in range(octaves):
        white = rng.standard_normal((size, size))
        sigma_f = 1.0 / (scale_texels / 2 ** octave)
        filtered = np.real(np.fft.ifft2(np.fft.fft2(white) * np.exp(-(radius / sigma_f) ** 2)))
        total += filtered / (filtered.std() + 1e-12) * 0.5 ** octave
    return (total - total.mean()) / (total.std() + 1e-12)


def _mirror_tile(gray_or_rgb: np.ndarray) -> np.ndarray:
    """Make a photograph repeat seamlessly by mirroring it into a 2x2 block."""
    top = np.concatenate([gray_or_rgb, gray_or_rgb[:, ::-1]], axis=1)
    return np.concatenate([top, top[::-1]], axis=0)


def _to_rgb01(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img, dtype=np.float64)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return img[..., :3] / 255.0


def _fit(img: np.ndarray, size: int) -> np.ndarray:
    return cv2.resize(img.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA).astype(np.float64)


def _normalise_photo(rgb01: np.ndarray, mean: float) -> np.ndarray:
    """Rescale a photographic texture to a chosen mean so tints decide the final colour."""
    return np.clip(rgb01 * (mean / max(rgb01.mean(), 1e-6)), 0, 1)


# -- procedural patterns (sRGB values in [0, 1], size x size, periodic) --------------------------

def _plain(size: int, rng: np.random.Generator) -> np.ndarray:
    return np.ones((size, size, 3))


def _paint(size: int, rng: np.random.Generator) -> np.ndarray:
    """Painted wall: a few percent of very slow brightness variation (rollers and uneven light)."""
    n = periodic_noise(size, rng, size / 2, octaves=2)
    return np.repeat((0.96 + 0.025 * n)[..., None], 3, axis=2)


def _plaster(size: int, rng: np.random.Generator) -> np.ndarray:
    n = periodic_noise(size, rng, 24, octaves=4)
    return np.repeat((0.88 + 0.06 * n)[..., None], 3, axis=2)


def _wood(size: int, rng: np.random.Generator, planks: int = 0) -> np.ndarray:
    """Wood grain along x; with `planks` > 0, boards of alternating tone separated by dark seams."""
    y, x = np.mgrid[0:size, 0:size] / size
    warp = 0.04 * periodic_noise(size, rng, size / 4, octaves=2)
    rings = np.sin(2 * np.pi * (y * 18 + warp * 6 + 0.15 * np.sin(2 * np.pi * x * 2)))
    fibre = periodic_noise(size, rng, 3, octaves=1)
    tone = 0.55 + 0.12 * rings + 0.05 * fibre
    if planks:
        board = np.floor(y * planks).astype(int)
        tone = tone * (0.85 + 0.3 * rng.random(planks))[board]
        seam = np.abs(((y * planks) % 1.0) - 0.5) > 0.485
        # Boards also end along x, staggered per board.
        offsets = rng.random(planks)
        end = np.abs((((x + offsets[board]) * 2) % 1.0) - 0.5) > 0.495
        tone = np.where(seam | end, tone * 0.45, tone)
    colour = np.array([0.72, 0.50, 0.32])
    return np.clip(tone[..., None] * colour / 0.55, 0, 1)


def _tiles(size: int, rng: np.random.Generator, count: int = 2) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size] / size * count
    grout = (np.abs((x % 1.0) - 0.5) > 0.475) | (np.abs((y % 1.0) - 0.5) > 0.475)
    tone = (0.9 + 0.08 * rng.random((count, count)))[y.astype(int) % count, x.astype(int) % count]
    tone = tone + 0.02 * periodic_noise(size, rng, 6)
    return np.repeat(np.where(grout, 0.55, tone)[..., None], 3, axis=2)


def _stripes(size: int, rng: np.random.Generator) -> np.ndarray:
    """Wallpaper: vertical stripes in two tones with a thin accent line."""
    x = np.mgrid[0:size, 0:size][1] / size
    phase = (x * 4) % 1.0
    base = np.where(phase < 0.5, 0.92, 0.78)
    base = np.where(np.abs(phase - 0.75) < 0.02, 0.55, base)
    rgb = np.repeat(base[..., None], 3, axis=2) * np.array([1.0, 0.96, 0.9])
    return rgb


def _fabric(size: int, rng: np.random.Generator) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size]
    weave = 0.04 * np.sin(2 * np.pi * x / 4) * np.sin(2 * np.pi * y / 4)
    n = periodic_noise(size, rng, 2, octaves=2)
    return np.repeat((0.8 + weave + 0.05 * n)[..., None], 3, axis=2)


def _dots(size: int, rng: np.random.Generator) -> np.ndarray:
    """Wallpaper with a staggered dot pattern."""
    y, x = np.mgrid[0:size, 0:size] / size * 6
    row = np.floor(y)
    dx = (x + 0.5 * (row % 2)) % 1.0 - 0.5
    dy = y % 1.0 - 0.5
    dot = np.hypot(dx, dy) < 0.16
    rgb = np.where(dot[..., None], np.array([0.55, 0.62, 0.75]), np.array([0.93, 0.92, 0.88]))
    return rgb


def _photo_tiled(loader, mean: float, rotate: bool = False):
    def make(size: int, rng: np.random.Generator) -> np.ndarray:
        img = _to_rgb01(loader())
        if rotate:
            img = np.rot90(img)
        return _normalise_photo(_fit(_mirror_tile(img), size), mean)
    return make


def _photo_decal(loader):
    def make(size: int, rng: np.random.Generator) -> np.ndarray:
        return _fit(_to_rgb01(loader()), size)
    return make


def _aspect(loader) -> float:
    img = loader()
    return img.shape[1] / img.shape[0]


# name -> (maker, tile_m). Tile sizes make a brick about 20 cm long, a floor board about 15 cm wide,
# floor tiles 30 cm and paint gradients a few metres across. tile_m = 0 marks a decal (a picture).
_TILED = {
    "plain": (_plain, 1.0),
    "paint": (_paint, 3.0),
    "plaster": (_plaster, 1.2),
    "wood_planks": (functools.partial(_wood, planks=8), 1.2),
    "wood": (_wood, 0.9),
    "tiles": (_tiles, 0.6),
    "stripes": (_stripes, 0.6),
    "dots": (_dots, 0.6),
    "fabric": (_fabric, 0.25),
    "brick": (_photo_tiled(skimage.data.brick, 0.55, rotate=True), 1.1),
    "gravel": (_photo_tiled(skimage.data.gravel, 0.5), 0.8),
    "grass": (_photo_tiled(skimage.data.grass, 0.5), 0.7),
}
_DECALS = {
    "astronaut": skimage.data.astronaut,
    "coffee": skimage.data.coffee,
    "chelsea": skimage.data.chelsea,
    "rocket": skimage.data.rocket,
    "camera": skimage.data.camera,
    "hubble": skimage.data.hubble_deep_field,
    "ihc": skimage.data.immunohistochemistry,
    "coins": skimage.data.coins,
    "moon": skimage.data.moon,
    "clock": skimage.data.clock,
}
DECAL_NAMES = tuple(_DECALS)


class TextureLibrary:
    """All textures with their mip pyramids in one flat (N, 3) float32 array of linear RGB.

    Texel (x, y) of texture `t` at mip level `l` is row
    `level_base[l] + t * (size >> l) ** 2 + (y >> l) * (size >> l) + (x >> l)` for level-0 texel
    coordinates x, y already wrapped into [0, size).
    """

    def __init__(self, size: int = 256, seed: int = 7):
        if size < 16 or size & (size - 1):
            raise ReconError(f"texture size must be a power of two >= 16, got {size}")
        self.size = size
        rng = np.random.default_rng(seed)
        specs, images = [], []
        for name, (maker, tile_m) in _TILED.items():
            specs.append(TextureSpec(name, tile_m))
            images.append(maker(size, rng))
        for name, loader in _DECALS.items():
            specs.append(TextureSpec(name, 0.0, _aspect(loader)))
            images.append(_photo_decal(loader)(size, rng))
        self.specs = tuple(specs)
        self.index = {s.name: i for i, s in enumerate(specs)}
        base = np.stack([srgb_to_linear(np.clip(im, 0, 1)) for im in images]).astype(np.float32)
        levels, bases, offset = [], [], 0
        level = base
        while level.shape[1] >= 4:
            levels.append(level.reshape(-1, 3))
            bases.append(offset)
            offset += levels[-1].shape[0]
            t, h, w, c = level.shape
            level = level.reshape(t, h // 2, 2, w // 2, 2, c).mean(axis=(2, 4))
        self.texels = np.ascontiguousarray(np.concatenate(levels))
        self.level_base = np.array(bases, dtype=np.int64)
        self.num_levels = len(bases)
        # Mean colour of each texture (level of 1 texel would be its average): for mesh vertex colours.
        self.mean_linear = base.reshape(len(specs), -1, 3).mean(axis=1)

    def __getitem__(self, name: str) -> int:
        return self.index[name]

    def spec(self, name: str) -> TextureSpec:
        return self.specs[self.index[name]]


@functools.lru_cache(maxsize=2)
def texture_library(size: int = 256) -> TextureLibrary:
    """The process-wide library (building it takes about a second; it never changes)."""
    return TextureLibrary(size)
