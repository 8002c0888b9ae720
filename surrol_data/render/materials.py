"""Surface materials chosen from what PyBullet knows of a visual shape: its kind, size and colour.

The scene's bodies carry only an RGBA colour, so the look is inferred from it (rules below, first match
wins). Every material keeps the shape's colour as its diffuse albedo, so a renderer that ignores materials
(TinyRenderer) and this one agree on what is what:

* reddish, saturated colours → **tissue**: wet, so a tight faint highlight, and a mottled albedo texture
  (capillaries and uneven perfusion) — the pads;
* small round shapes (radius under 3 mm real) and dark neutral colours → **metal**: strong tight highlight
  — needles, instrument shafts, wrists and jaws;
* light neutral colours → **silicone**: the practice trays, peg boards and gauze; broad soft highlight and
  a faint surface grain;
* anything else → **plastic**: weak broad highlight.
"""

from __future__ import annotations

import colorsys
import functools
from typing import NamedTuple

import numpy as np

# Texture tiles: one tile spans this many real metres of surface.
TISSUE_TILE_M = 0.02
SILICONE_TILE_M = 0.01


class Look(NamedTuple):
    name: str
    specular: float          # specular reflectance (grey)
    shininess: float         # Phong exponent
    texture: str | None      # "tissue", "grain" or None
    texture_strength: float  # how far the texture darkens the albedo (0..1)


TISSUE = Look("tissue", 0.35, 40.0, "tissue", 0.35)
METAL = Look("metal", 0.8, 80.0, None, 0.0)
SILICONE = Look("silicone", 0.12, 12.0, "grain", 0.08)
PLASTIC = Look("plastic", 0.1, 8.0, None, 0.0)

# pybullet GEOM_SPHERE, GEOM_CYLINDER, GEOM_CAPSULE, and GEOM_MESH by its thinnest half-extent (the needle's wire)
_ROUND_SHAPES = {2, 4, 5, 7}
_METAL_RADIUS_M = 0.003


def look_for(geometry_type: int, radius_m: float | None, rgba) -> Look:
    """The material of a visual shape (``radius_m``: of round shapes, real metres; None for others)."""
    r, g, b = (float(v) for v in rgba[:3])
    hue, saturation, value = colorsys.rgb_to_hsv(r, g, b)
    reddish = (hue < 0.06 or hue > 0.9) and saturation > 0.25
    if reddish:
        return TISSUE
    if geometry_type in _ROUND_SHAPES and radius_m is not None and radius_m < _METAL_RADIUS_M \
            and saturation < 0.15:
        return METAL
    if saturation < 0.15:
        return METAL if value < 0.65 else SILICONE
    return PLASTIC


@functools.cache
def texture_pixels(kind: str, size: int = 256) -> np.ndarray:
    """A seamless (tiling) greyscale albedo modulation in [0, 1] (1 = unchanged), deterministic.

    ``tissue``: smooth blotches plus thin darker vessel-like ridges; ``grain``: fine isotropic noise.
    Made by low-pass filtering white noise in the Fourier domain, which wraps around at the edges."""
    rng = np.random.default_rng(17)
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.fftfreq(size)[None, :]
    radius = np.hypot(fx, fy)

    def band(cutoff: float) -> np.ndarray:
        noise = np.fft.fft2(rng.standard_normal((size, size)))
        field = np.real(np.fft.ifft2(noise * np.exp(-(radius / cutoff) ** 2)))
        return (field - field.mean()) / (field.std() + 1e-12)

    if kind == "tissue":
        blotches = band(0.02)
        # Vessels: where a mid-frequency field crosses zero, a thin dark line.
        vessels = np.exp(-(band(0.03) / 0.12) ** 2)
        shade = 0.5 + 0.5 * np.tanh(0.6 * blotches)
        out = 1.0 - 0.55 * (1.0 - shade) - 0.45 * vessels
    elif kind == "grain":
        out = 0.5 + 0.5 * np.tanh(0.5 * band(0.25))
    else:
        raise ValueError(f"unknown texture kind {kind!r}; use 'tissue' or 'grain'")
    return np.clip(out, 0.0, 1.0).astype(np.float32)
