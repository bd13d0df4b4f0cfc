"""Procedural terrain: fractal Perlin gradient noise, vectorised in numpy."""

from __future__ import annotations

import numpy as np


def _perlin_octave(rng: np.random.Generator, x: np.ndarray, y: np.ndarray, cells: int) -> np.ndarray:
    """One octave of 2-D Perlin noise on [0, 1)² coordinates with ``cells`` lattice cells."""
    angles = rng.uniform(0.0, 2 * np.pi, size=(cells + 1, cells + 1))
    gx, gy = np.cos(angles), np.sin(angles)
    fx, fy = x * cells, y * cells
    ix = np.clip(np.floor(fx).astype(int), 0, cells - 1)
    iy = np.clip(np.floor(fy).astype(int), 0, cells - 1)
    tx, ty = fx - ix, fy - iy

    def dot(ox: int, oy: int) -> np.ndarray:
        return gx[iy + oy, ix + ox] * (tx - ox) + gy[iy + oy, ix + ox] * (ty - oy)

    fade = lambda t: t * t * t * (t * (t * 6 - 15) + 10)  # noqa: E731 - Perlin's quintic
    u, v = fade(tx), fade(ty)
    top = dot(0, 0) * (1 - u) + dot(1, 0) * u
    bottom = dot(0, 1) * (1 - u) + dot(1, 1) * u
    return top * (1 - v) + bottom * v


def perlin_heightfield(
    seed: int, resolution: int, extent_m: float, amplitude_m: float, feature_size_m: float,
    octaves: int = 3,
) -> np.ndarray:
    """Heights [m], shape (resolution, resolution), indexed [iy, ix], zero-mean.

    ``amplitude_m`` is the approximate peak-to-peak relief; ``feature_size_m`` the wavelength of
    the coarsest octave. Deterministic in ``seed``.
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x7E55A1]))
    s = np.linspace(0.0, 1.0, resolution, endpoint=False) + 0.5 / resolution
    x, y = np.meshgrid(s, s)
    h = np.zeros((resolution, resolution))
    cells = max(1, int(round(extent_m / feature_size_m)))
    weight, total = 1.0, 0.0
    for _ in range(octaves):
        h += weight * _perlin_octave(rng, x, y, cells)
        total += weight
        weight *= 0.5
        cells *= 2
    h /= total
    h -= h.mean()
    span = float(h.max() - h.min())
    if span > 0:
        h *= amplitude_m / span
    return h
