"""Cross-section profiles of a log: the best upper half-circle through what a downward scan shows of a
short chunk of it (:func:`_profile_circle`), and the frame across an axis it is measured in.

Seen from above, every lateral position across a short straight chunk shows ONE surface, so the chunk is
reduced to its visible profile, and an exhaustive search with a visibility test (nothing can be seen
*below* a log's top inside its footprint) finds the circle; robust to neighbouring logs, the ground and
obstacles. Used by the cylinder fit (:mod:`reconstruct.fitting.cylinder`) and by the scan's own logs
(:mod:`reconstruct.fitting.scan_logs`)."""

from __future__ import annotations

import numpy as np

from reconstruct.errors import FitError
from reconstruct.fitting.fit_config import FitConfig


# a profile bin holds at least this many points, and a chunk's profile at least this many such bins [-]
PROFILE_BIN_MIN_POINTS = 3
PROFILE_MIN_BINS = 4
# the circle search steps 1/this of a profile bin in centre offset and radius; a circle's footprint stops
# that far inside its rim [-]
PROFILE_SEARCH_DIVISOR = 2
# a bin more than this many profile_tolerance_m under a circle is seen below it (impossible inside its
# footprint), and costs the circle this many explained bins each [-]
PROFILE_BELOW_TOLERANCES = 2
PROFILE_BELOW_WEIGHT = 3
# a cross-section circle loses this much score per footprint bin it does not explain (the profile
# there lies above it or off it): where a neighbour lies against a log, or the stereo fills the
# valley between them, that side shows no edge, and without this a wider circle, centred toward
# the neighbour, explained as many bins as the true one [-]
PROFILE_UNSEEN_WEIGHT = 0.5


def _frame(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``u``: e1 horizontal, e2 'up-ish'."""
    e1 = np.cross((0.0, 0.0, 1.0), u)
    if np.linalg.norm(e1) < 1e-6:  # vertical axis
        e1 = np.cross((1.0, 0.0, 0.0), u)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return e1, e2


def _profile_circle(sw: np.ndarray, prior_centre: np.ndarray, cfg: FitConfig,
                    ) -> tuple[np.ndarray, float, int]:
    """Best upper half-circle (centre (2,), radius, bins explained) for one axial chunk.

    ``sw``: points in cross-section coordinates (s horizontal across the axis, w up-ish). Seen
    from above, every lateral position ``s`` shows ONE surface along a short straight chunk, so
    the chunk is reduced to its visible profile (the median ``w`` per ``profile_bin_m`` bin). An
    exhaustive search over centre offset and radius then scores each upper half-circle by the
    bins it explains minus ``PROFILE_BELOW_WEIGHT`` times the bins that lie clearly BELOW it inside its footprint
    (impossible: ground beside a too-wide circle, points inside the log), less
    ``PROFILE_UNSEEN_WEIGHT`` for each other footprint bin (above it: an occluder, or a neighbour
    over its flank; it may be there, but nothing shows it, so of two circles that explain as much the
    one that claims less unseen width wins). Robust to neighbouring logs, the ground and obstacles.
    """
    step = cfg.profile_bin_m
    reach = cfg.max_radius_m + cfg.axis_tolerance_m + abs(float(prior_centre[0]))
    nb = int(np.ceil(2 * reach / step))
    idx = np.floor((sw[:, 0] + reach) / step).astype(np.int64)
    ok = (idx >= 0) & (idx < nb)
    idx, w = idx[ok], sw[ok, 1]
    order = np.lexsort((w, idx))
    idx, w = idx[order], w[order]
    starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
    ends = np.r_[starts[1:], len(idx)]
    counts = ends - starts
    good = counts >= PROFILE_BIN_MIN_POINTS
    if good.sum() < PROFILE_MIN_BINS:
        raise FitError("too few profile bins")
    bins = idx[starts[good]]
    wb = w[(starts[good] + ends[good] - 1) // 2]  # per-bin median (sorted within a bin)
    sb = -reach + (bins + 0.5) * step
    tol = cfg.profile_tolerance_m
    cs = prior_centre[0] + np.arange(-cfg.axis_tolerance_m, cfg.axis_tolerance_m + 1e-9, step / PROFILE_SEARCH_DIVISOR)
    rs = np.arange(cfg.min_radius_m, cfg.max_radius_m + 1e-9, step / PROFILE_SEARCH_DIVISOR)
    C, R = np.meshgrid(cs, rs, indexing="ij")
    C, R = C.ravel(), R.ravel()
    ds = sb[None, :] - C[:, None]
    fp = np.abs(ds) < R[:, None] - step / PROFILE_SEARCH_DIVISOR
    sq = np.sqrt(np.clip(R[:, None] ** 2 - ds ** 2, 0.0, None))
    cw = _row_medians(wb[None, :] - sq, fp)
    valid = np.isfinite(cw) & (np.abs(cw - prior_centre[1]) <= cfg.axis_tolerance_m)
    if not valid.any():
        raise FitError("no half-circle near the axis")
    e = wb[None, :] - (cw[:, None] + sq)
    rad = np.hypot(ds, wb[None, :] - cw[:, None]) - R[:, None]
    upper = wb[None, :] > cw[:, None] - tol  # the visible (upper) half only
    on = fp & upper & ((np.abs(e) < tol) | (np.abs(rad) < tol))
    below = fp & (e < -PROFILE_BELOW_TOLERANCES * tol) & ~(upper & (np.abs(rad) < tol))
    unseen = fp & ~on & ~below  # footprint bins the circle does not explain: above it, or off it
    score = np.where(valid, on.sum(axis=1) - PROFILE_BELOW_WEIGHT * below.sum(axis=1)
                     - PROFILE_UNSEEN_WEIGHT * unseen.sum(axis=1),
                     -10**9)
    best = int(np.argmax(score))
    return np.array([C[best], cw[best]]), float(R[best]), int(on[best].sum())


def _row_medians(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Median of each row's ``values`` where ``mask`` holds (NaN for an empty row): what
    ``np.nanmedian`` gives on the masked-out values set to NaN, without its slow masked-array path."""
    v = np.where(mask, values, np.inf)
    v.sort(axis=1)
    n = mask.sum(axis=1)
    rows = np.arange(len(v))
    lo = v[rows, np.maximum((n - 1) // 2, 0)]
    hi = v[rows, np.maximum(n // 2, 0)]
    out = 0.5 * (lo + hi)
    out[n == 0] = np.nan
    return out
