"""Procedural textures for the synthetic scene (seeded, feature-rich so that SfM and matchers find corners).

Each function returns an (H, W, 3) uint8 RGB array; the world builder saves them as PNG for PyBullet.
Drawn with Pillow's ImageDraw (shapes) and numpy (smooth noise): no texture files are shipped.
"""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw


def _smooth_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """(size, size) smooth noise in [0, 1]: bicubic upsampling of a (cells, cells) random grid."""
    grid = (rng.random((cells, cells)) * 255).astype(np.uint8)
    img = Image.fromarray(grid).resize((size, size), Image.BICUBIC)
    return np.asarray(img, dtype=np.float64) / 255.0


def _random_color(rng: np.random.Generator, lo: int = 30, hi: int = 230) -> tuple[int, int, int]:
    return tuple(int(c) for c in rng.integers(lo, hi, 3))


def _draw_shapes(rng: np.random.Generator, img: Image.Image, n: int, min_size: int, max_size: int) -> None:
    draw = ImageDraw.Draw(img)
    W, H = img.size
    for _ in range(n):
        s = int(rng.integers(min_size, max_size))
        x, y = int(rng.integers(-s // 2, W)), int(rng.integers(-s // 2, H))
        kind = rng.integers(0, 4)
        col = _random_color(rng)
        if kind == 0:
            draw.rectangle([x, y, x + s, y + int(s * rng.uniform(0.3, 1.0))], fill=col)
        elif kind == 1:
            draw.ellipse([x, y, x + s, y + s], fill=col)
        elif kind == 2:
            pts = [(x + int(rng.integers(0, s)), y + int(rng.integers(0, s))) for _ in range(3)]
            draw.polygon(pts, fill=col)
        else:
            draw.line([x, y, x + s, y + int(rng.integers(-s, s))], fill=col, width=max(2, s // 8))


def table_texture(rng: np.random.Generator, size: int = 1024) -> np.ndarray:
    """A light wood-like top (streaky grain, blotches) with scattered small marks (stickers, scuffs)."""
    base = np.array([196.0, 160.0, 118.0]) + rng.uniform(-20, 20, 3)
    grain = np.asarray(Image.fromarray((rng.random((6, 160)) * 255).astype(np.uint8))
                       .resize((size, size), Image.BICUBIC), dtype=np.float64) / 255.0  # long streaks along x
    blotch = _smooth_noise(rng, size, 8)
    shade = 0.78 + 0.14 * grain + 0.12 * blotch
    img = np.clip(base[None, None, :] * shade[..., None], 0, 255).astype(np.uint8)
    pil = Image.fromarray(img)
    _draw_shapes(rng, pil, n=160, min_size=8, max_size=36)
    return np.asarray(pil)


def floor_texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """A grey tiled floor with a mottled pattern."""
    tiles = 8
    idx = np.arange(size) * tiles // size
    checker = ((idx[:, None] + idx[None, :]) % 2).astype(np.float64)
    mottle = _smooth_noise(rng, size, 48)
    g = 95 + 25 * checker + 40 * mottle
    img = np.repeat(g[..., None], 3, axis=2) * np.array([1.0, 1.0, 1.05])
    return np.clip(img, 0, 255).astype(np.uint8)


def wall_texture(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A pale painted wall with faint blotches and a few posters."""
    base = np.array([214.0, 210.0, 200.0]) + rng.uniform(-15, 15, 3)
    shade = 0.9 + 0.1 * _smooth_noise(rng, size, 6)
    pil = Image.fromarray(np.clip(base[None, None, :] * shade[..., None], 0, 255).astype(np.uint8))
    draw = ImageDraw.Draw(pil)
    for _ in range(int(rng.integers(2, 5))):
        w, h = int(rng.integers(15, 40)), int(rng.integers(20, 50))
        x, y = int(rng.integers(0, size - w)), int(rng.integers(size // 4, size - h))
        draw.rectangle([x, y, x + w, y + h], fill=_random_color(rng, 40, 200))
    return np.asarray(pil)


def object_texture(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A printed-package look: a base colour with smooth shading, bands and shapes."""
    base = np.array(_random_color(rng, 20, 235), dtype=np.float64)
    noise = _smooth_noise(rng, size, 24)
    img = np.clip(base[None, None, :] * (0.75 + 0.4 * noise[..., None]), 0, 255).astype(np.uint8)
    pil = Image.fromarray(img)
    draw = ImageDraw.Draw(pil)
    for _ in range(int(rng.integers(1, 4))):  # bands across the print
        y = int(rng.integers(0, size))
        draw.rectangle([0, y, size, y + int(rng.integers(8, 40))], fill=_random_color(rng))
    _draw_shapes(rng, pil, n=int(rng.integers(25, 45)), min_size=8, max_size=60)
    return np.asarray(pil)
