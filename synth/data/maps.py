"""The paper's five grasp target maps ``G = (C, S, W, U, B)`` on the orthographic pixel grid.

Channels (index order is fixed, see :data:`MAP_CHANNELS`):

* ``C = cos 2φ`` and ``S = sin 2φ`` — φ is the grasp angle **in the pile frame**
  (:attr:`synth.geometry.grasp.Grasp.phi_rad`: closing axis counter-clockwise from pile +x, π-periodic),
  *not* the image-space angle. Decode with ``φ = atan2(S, C) / 2`` (:func:`decode_at`); convert
  to image space with :func:`synth.geometry.frames.phi_to_image` if ever needed.
* ``W`` — grasp opening width in metres (0.30–1.55 m where ``U = 1``). :func:`normalise_width`
  maps it to [0, 1] if a network prefers that; the stored maps are always metres.
* ``U`` — 1 where a pixel centre lies inside the *graspable region* of a successful grasp, else
  0: a square of :data:`U_LENGTH_M` (20 cm) along the closing axis by :data:`U_BREADTH_M` (20 cm,
  the claw breadth) across it, centred on (x, y) — :func:`region_mask`. This is Morrison et
  al.'s "centre of the grasp rectangle" with the paper's constant 20 cm instead of a third of the
  opening: the pixels marked are the grasp *centres* that work, not the whole footprint between
  the claw tips (:meth:`synth.geometry.grasp.Grasp.rectangle`, ``width_m`` x 20 cm, which Algorithm 1's
  0.04 m² overlap rule uses). Measured on 19 accepted grasps of ``data/train-v2`` (fast trials):
  moving the centre along the closing axis by 0.1/0.2/0.3 m leaves 79/26/5 % successes, across it
  95/84/68 % — so marking the footprint taught a network grasps 0.3–0.7 m off centre.
  (Data set format 1.0 marked the footprint; its shards are re-encoded from their grasps on
  load, :func:`synth.data.shards.load_shard`.)
* ``B`` — balance ``cos β`` of the grasp (β: grapple tilt from the world z axis after the lift).

Outside every region C, S, W and B are 0 (the paper's convention: only pixels with ``U = 1``
carry grasp parameters; a loss should mask C/S/W/B by U).

**Overlapping regions** (a pixel covered by several accepted grasps): ``U`` is the union. For
C, S, W and B the grasp whose centre (x, y) is nearest to the pixel centre wins; exact ties go
to the grasp listed first. Each pixel therefore carries the parameters of exactly one real
grasp — never an average of two grasps, which the paper warns is not necessarily a valid grasp.

Rasterisation is a vectorised point-in-rectangle test at pixel centres (the grid of
:class:`synth.geometry.frames.OrthoGrid`), exact up to float rounding.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from synth.geometry.frames import OrthoGrid, wrap_phi
from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, RECT_WIDTH_M, Grasp

#: Channel order of a (5, H, W) map stack.
MAP_CHANNELS = ("C", "S", "W", "U", "B")
C, S, W, U, B = range(5)

#: The graspable region marked in U: extent along the closing axis and across it [m].
U_LENGTH_M = 0.20
U_BREADTH_M = RECT_WIDTH_M

_EPS = 1e-9  # pixel centres exactly on a rectangle edge count as inside [m]


def normalise_width(width_m):
    """Width [m] -> [0, 1] over the grapple's range 0.30–1.55 m."""
    return (np.asarray(width_m, dtype=np.float64) - MIN_WIDTH_M) / (MAX_WIDTH_M - MIN_WIDTH_M)


def denormalise_width(w01):
    """Inverse of :func:`normalise_width`: [0, 1] -> metres."""
    return MIN_WIDTH_M + np.asarray(w01, dtype=np.float64) * (MAX_WIDTH_M - MIN_WIDTH_M)


def _local_coords(grid: OrthoGrid, grasp: Grasp) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel centre in the grasp's frame: u along the closing axis, v across it [m]."""
    X, Y = grid.pixel_centres()
    dx, dy = X - grasp.x_m, Y - grasp.y_m
    ca, sa = math.cos(grasp.phi_rad), math.sin(grasp.phi_rad)
    return dx * ca + dy * sa, -dx * sa + dy * ca


def rectangle_mask(grid: OrthoGrid, grasp: Grasp, rect_width_m: float = RECT_WIDTH_M) -> np.ndarray:
    """(H, W) bool: pixel centres inside the grasp rectangle, the footprint between the claw tips
    (``width_m`` x ``rect_width_m``); U marks the smaller :func:`region_mask`."""
    u, v = _local_coords(grid, grasp)
    return _inside(u, v, grasp.width_m, rect_width_m)


def _inside(u: np.ndarray, v: np.ndarray, length_m: float, breadth_m: float) -> np.ndarray:
    """Pixel centres with grasp-local coordinates (u along the closing axis, v across) inside a
    ``length_m`` x ``breadth_m`` rectangle centred on the grasp (edges count as inside)."""
    return (np.abs(u) <= length_m / 2 + _EPS) & (np.abs(v) <= breadth_m / 2 + _EPS)


def region_mask(grid: OrthoGrid, grasp: Grasp, length_m: float = U_LENGTH_M,
                breadth_m: float = U_BREADTH_M) -> np.ndarray:
    """(H, W) bool: pixel centres inside the grasp's graspable region (``length_m`` along the
    closing axis x ``breadth_m`` across, centred on (x, y)) — what U marks."""
    u, v = _local_coords(grid, grasp)
    return _inside(u, v, length_m, breadth_m)


def encode_grasps(grid: OrthoGrid, grasps: Sequence[Grasp], balances: Sequence[float],
                  length_m: float = U_LENGTH_M, breadth_m: float = U_BREADTH_M) -> np.ndarray:
    """The target maps ``(5, H, W)`` float32, channels C, S, W, U, B, of successful ``grasps``
    with balances ``balances`` (cos β, one per grasp). No grasps -> all zeros (a negative).
    U marks each grasp's region (:func:`region_mask`); where regions overlap the nearest grasp
    centre gives C, S, W and B.

    Raises ``ValueError`` for a balance that is not a finite number in [-1, 1], a length
    mismatch or a non-positive region; widths are already checked by :class:`~synth.geometry.grasp.Grasp`.
    """
    grasps = list(grasps)
    balances = [float(b) for b in balances]
    if len(grasps) != len(balances):
        raise ValueError(f"need one balance per grasp, got {len(grasps)} grasps and {len(balances)} balances")
    if not (length_m > 0 and breadth_m > 0):
        raise ValueError(f"the graspable region must have a positive size, got {length_m} x {breadth_m} m")
    for g in grasps:
        if not isinstance(g, Grasp):
            raise ValueError(f"encode_grasps takes synth.geometry.grasp.Grasp objects, got {type(g).__name__}")
    for b in balances:
        if not (math.isfinite(b) and -1.0 <= b <= 1.0):
            raise ValueError(f"balance must be cos(beta), a finite number in [-1, 1], got {b}")
    n = grid.size_px
    out = np.zeros((5, n, n), dtype=np.float32)
    if not grasps:
        return out
    best = np.full((n, n), np.inf)  # distance to the winning grasp's centre per pixel [m]
    for g, b in zip(grasps, balances):
        u, v = _local_coords(grid, g)
        inside = _inside(u, v, length_m, breadth_m)
        d = np.hypot(u, v)
        win = inside & (d < best)  # strict: ties keep the grasp listed first
        best[win] = d[win]
        out[C][win] = math.cos(2 * g.phi_rad)
        out[S][win] = math.sin(2 * g.phi_rad)
        out[W][win] = g.width_m
        out[B][win] = b
        out[U][inside] = 1.0
    return out


def decode_at(maps: np.ndarray, row: int, col: int) -> tuple[float, float, float, float]:
    """``(phi_rad, width_m, u, b)`` at pixel (row, col) of a (5, H, W) map stack (targets or a
    network's output): ``phi = atan2(S, C) / 2`` wrapped to [-π/2, π/2) in the pile frame."""
    maps = np.asarray(maps)
    if maps.ndim != 3 or maps.shape[0] != 5:
        raise ValueError(f"maps must have shape (5, H, W), got {maps.shape}")
    c, s, w, u, b = (float(maps[k, row, col]) for k in range(5))
    phi = float(wrap_phi(math.atan2(s, c) / 2.0))
    return phi, w, u, b


def decode_maps(maps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Whole-image version of :func:`decode_at`: (phi, width, u, b) arrays of shape (H, W)."""
    maps = np.asarray(maps)
    if maps.ndim != 3 or maps.shape[0] != 5:
        raise ValueError(f"maps must have shape (5, H, W), got {maps.shape}")
    phi = wrap_phi(np.arctan2(maps[S], maps[C]) / 2.0)
    return phi, maps[W], maps[U], maps[B]


def encode_outcomes(grid: OrthoGrid, grasps: Sequence[Grasp], successes: Sequence[float],
                    balances: Sequence[float], length_m: float = U_LENGTH_M,
                    breadth_m: float = U_BREADTH_M) -> tuple[np.ndarray, np.ndarray]:
    """Target maps ``(5, H, W)`` of *tried* grasps and the pixels they cover ``(H, W)`` bool.

    Unlike :func:`encode_grasps` (U the union of successful grasps), each pixel inside a tried
    grasp's region takes everything — U included — from the nearest tried centre: U is that
    trial's success value in [0, 1] (1 success, 0 failure, or a success fraction), so a failed
    centre is a negative even where a successful neighbour's region overlaps it. Ties go to the
    grasp listed first; C, S, W, B as in :func:`encode_grasps` (a failure's B is 1, masked by U = 0)."""
    grasps, successes = list(grasps), [float(s) for s in successes]
    if not (len(grasps) == len(successes) == len(balances)):
        raise ValueError(f"need one success value and one balance per grasp, got {len(grasps)} grasps, "
                         f"{len(successes)} values and {len(balances)} balances")
    for s in successes:
        if not (math.isfinite(s) and 0.0 <= s <= 1.0):
            raise ValueError(f"a trial's success value must be in [0, 1], got {s}")
    n = grid.size_px
    out = np.zeros((5, n, n), dtype=np.float32)
    best = np.full((n, n), np.inf)  # distance to the winning trial's centre per pixel [m]
    for g, s, b in zip(grasps, successes, balances):
        u, v = _local_coords(grid, g)
        d = np.hypot(u, v)
        win = _inside(u, v, length_m, breadth_m) & (d < best)
        best[win] = d[win]
        out[C][win] = math.cos(2 * g.phi_rad)
        out[S][win] = math.sin(2 * g.phi_rad)
        out[W][win] = g.width_m
        out[U][win] = s
        out[B][win] = min(1.0, max(-1.0, float(b))) if math.isfinite(float(b)) else 1.0
    return out, np.isfinite(best)
