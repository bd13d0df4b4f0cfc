"""The ground under and around the pile from the scan points no log explains.

The ground is the grey-scale *opening* of the per-cell lowest points (window ``ground_window_m``, wider
than the obstacles) followed by the median of the points near that surface, on the :class:`TerrainSpec`
grid; holes are filled (OpenCV ``inpaint``, Telea); the unseen ground under a log is lowered to the log's
underside where needed, between the grid samples too: the twin's terrain is linear over each cell
(:func:`_clamp_under_logs`)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Sequence

import numpy as np

from reconstruct.errors import FitError
from reconstruct.fitting.fit_config import FitConfig
from reconstruct.fitting.geometry import UNDER_LOG_GAP_M, _underside_z
from synth.scene.pile import LogSpec, TerrainSpec

# fewer ground candidates inside the patch than this: the scan does not see the ground [-]
MIN_GROUND_POINTS = 10
# a cell's low value: this quantile of its points' heights (robust to single low outliers) [-]
CELL_LOW_QUANTILE = 0.1
# the opening window is at least this many cells [-]
MIN_OPENING_CELLS = 3
# ground points lie at most this many ground_band_m under the opened surface [-]
GROUND_BAND_BELOW = 3
# holes are inpainted (Telea) with this radius [cells], on a 16-bit image of this many levels [-]
INPAINT_RADIUS_CELLS = 3
INPAINT_LEVELS = 65535
# the heights are smoothed by a median over this many cells square [-]
SMOOTHING_CELLS = 3


def fit_terrain(ground_candidates: np.ndarray, extent_m: float, cfg: FitConfig | None = None,
                colour: tuple[float, float, float] = (0.45, 0.40, 0.30)) -> tuple[TerrainSpec, np.ndarray, float]:
    """A :class:`TerrainSpec` (explicit heights) from points that are ground or obstacles.

    Returns the terrain, a boolean mask of the points accepted as ground, and the share of grid
    cells that had ground points (the rest are filled)."""
    from scipy import ndimage

    cfg = cfg or FitConfig()
    n = cfg.terrain_resolution
    P = np.asarray(ground_candidates, dtype=np.float64)
    step = extent_m / (n - 1)
    half = extent_m / 2
    ix = np.rint((P[:, 0] + half) / step).astype(np.int64)
    iy = np.rint((P[:, 1] + half) / step).astype(np.int64)
    inside = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n)
    if inside.sum() < MIN_GROUND_POINTS:
        raise FitError("almost no ground points inside the terrain patch; the scan does not see "
                       "the ground around the pile (scan from higher up, or enlarge the scanned area)")
    flat = iy * n + ix
    # per-cell low value (robust to single low outliers)
    low = np.full(n * n, np.nan)
    order = np.lexsort((P[:, 2], flat))
    order = order[inside[order]]
    f_sorted = flat[order]
    starts = np.flatnonzero(np.r_[True, f_sorted[1:] != f_sorted[:-1]])
    ends = np.r_[starts[1:], len(order)]
    for s, e in zip(starts, ends):
        k = s + int(CELL_LOW_QUANTILE * (e - s))
        low[f_sorted[s]] = P[order[k], 2]
    low = low.reshape(n, n)
    have = np.isfinite(low)
    filled = _fill(low, have)
    w = max(MIN_OPENING_CELLS, int(round(cfg.ground_window_m / step)) | 1)
    opened = ndimage.grey_opening(filled, size=(w, w))
    # ground points: within the band above the opened surface (bilinear)
    from synth.scene.pile import height_at

    z_open = height_at(opened, extent_m, P[:, 0], P[:, 1])
    is_ground = (inside & (P[:, 2] < z_open + cfg.ground_band_m)
                 & (P[:, 2] > z_open - GROUND_BAND_BELOW * cfg.ground_band_m))
    med = np.full(n * n, np.nan)
    g = np.flatnonzero(is_ground)
    if g.size:
        fg = flat[g]
        o = np.lexsort((P[g, 2], fg))
        fs = fg[o]
        st = np.flatnonzero(np.r_[True, fs[1:] != fs[:-1]])
        en = np.r_[st[1:], len(o)]
        for s, e in zip(st, en):
            med[fs[s]] = P[g[o[(s + e - 1) // 2]], 2]
    med = med.reshape(n, n)
    have_g = np.isfinite(med)
    coverage = float(have_g.mean())
    if not have_g.any():
        heights = opened
    else:
        heights = _fill(med, have_g)
        # holes: OpenCV inpainting (Telea) from the cells with ground, smoother than the
        # nearest-cell fill it starts from
        if (~have_g).any():
            import cv2

            # on a 16-bit image spanning the measured heights (OpenCV 5's float32 inpainting
            # returned values far outside the data); quantisation < 0.02 mm per metre of relief
            lo, hi = float(heights.min()), float(heights.max())
            span = max(hi - lo, 1e-6)
            img = np.rint((heights - lo) / span * INPAINT_LEVELS).astype(np.uint16)
            inp = cv2.inpaint(img, (~have_g).astype(np.uint8), INPAINT_RADIUS_CELLS, cv2.INPAINT_TELEA)
            heights = np.where(have_g, heights, lo + inp.astype(np.float64) / INPAINT_LEVELS * span)
    heights = ndimage.median_filter(heights, size=SMOOTHING_CELLS, mode="nearest")
    terrain = TerrainSpec(extent_m=extent_m, resolution=n, amplitude_m=0.0,
                          heights_m=tuple(tuple(float(v) for v in row) for row in heights), colour=colour)
    return terrain, is_ground, coverage


def _fill(grid: np.ndarray, have: np.ndarray) -> np.ndarray:
    """Fill cells without data from the nearest cell with data."""
    from scipy import ndimage

    if have.all():
        return grid.copy()
    _, (iy, ix) = ndimage.distance_transform_edt(~have, return_indices=True)
    return grid[iy, ix]


def _clamp_under_logs(terrain: TerrainSpec, logs: Sequence[LogSpec], gap_m: float = UNDER_LOG_GAP_M) -> TerrainSpec:
    """Lower the (unseen, interpolated) ground under each log so that the twin's terrain, the
    surface *between* the samples included, stays under the log: the ground cannot be above a
    log lying on it. Returns a new :class:`TerrainSpec`.

    The physics interpolates the heights linearly over triangles of one grid cell, and a chord
    under the log's round underside rises above it (by ~1.4 cm for a 24 cm log across a cell
    diagonal of 11 cm, the case of logs diagonal to the grid). So every sample is held under the
    lowest point of the underside within one cell diagonal of it (less the axis' rise over that
    reach), which bounds each triangle, whose vertices are all that close to its points."""
    h = terrain.height_grid().copy()
    xs, ys = terrain.grid_xy()
    reach = math.sqrt(2.0) * float(xs[1] - xs[0])  # one cell diagonal [m]
    X, Y = np.meshgrid(xs, ys)
    flat = np.minimum(h.ravel(), _underside_z(logs, np.column_stack([X.ravel(), Y.ravel()]), reach) - gap_m)
    h = flat.reshape(h.shape)
    return replace(terrain, heights_m=tuple(tuple(float(v) for v in row) for row in h))
