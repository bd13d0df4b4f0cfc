"""Logs in the scan (:func:`find_scan_logs`): the scan seen from above as a height raster; a log's top is
a ridge (strongly curved across, straight along: the Hessian of the smoothed heights), and ridge pixels
that line up are one log (a Hough transform over ridge pixels voting only near their own direction, so
crossing logs stay apart and a log broken by one lying across it stays whole). Each found log has a
top-view axis, a visible extent, an axis height and a radius estimate."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reconstruct.errors import FitError
from reconstruct.fitting.fit_config import FitConfig
from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.profiles import _profile_circle

# a scan of fewer points than this shows no logs; fewer ridge pixels than this make no more lines [-]
MIN_SCAN_POINTS = 100
MIN_RIDGE_PIXELS = 10
# the height raster holds at most this many cells [-]
MAX_RASTER_CELLS = 25_000_000
# a cell is observed all around when this share of the curvature's window holds points [-]; the window's
# empty single cells are closed over this many cells square first [-]
SEEN_AROUND_SHARE = 0.9
CLOSING_CELLS = 3
# the ridge's top line: the heights smoothed over this many cells (Gaussian sigma) [-]
TOP_SMOOTHING_CELLS = 1.0
# lines are looked for at most this many times per log taken [-]
LINE_TRIES_PER_LOG = 4
# a weak ridge pixel is curved across this many times min_curvature_per_m; a pixel's vote is capped at this
# many weak pixels' (a few sharp pixels do not dominate) [-]
WEAK_RIDGE_CURVATURES = 2
VOTE_CAP_PIXELS = 5
# the Hough offsets reach this far past the farthest ridge pixel [m]
HOUGH_MARGIN_M = 0.1
# a line needs this many ridge pixels [-]; pixels this many times max_angle_deg off it are taken out with it [-]
MIN_LINE_PIXELS = 5
SUPPRESS_ANGLE_FACTOR = 2
# a run's bin is full with at least this many ridge pixels, and this share of a band's worth [-]
FULL_BIN_MIN_PIXELS = 3
FULL_BIN_SHARE = 0.4
# a gap's sides: the ridge pixels this far before and after it [m]
BREAK_SIDE_M = 0.3
# something stands over a gap when the raster holds points over this share of it, and at most this share
# of those lie more than this far under the ridge's top [-, -, m]
COVER_MIN_SEEN = 0.5
COVER_MAX_SEEN_THROUGH = 0.1
COVER_DROP_M = 0.03
# the top line is fitted this many times, each without the pixels farther from it than this many median
# absolute residuals, at least this far [-, -, m]
TOP_LINE_ROUNDS = 2
TOP_LINE_MADS = 2.5
TOP_LINE_BAND_M = 0.02
# the cross-section under a run: points this far across its line [m], at most this many [-], at least this
# many for a radius [-]
PROFILE_HALF_WIDTH_M = 0.4
PROFILE_MAX_POINTS = 4000
PROFILE_MIN_POINTS = 30
# its circle: the centre within this of one this far under the top [m], the radius at most this [m], and
# at least this many profile bins on it [-]
PROFILE_CENTRE_TOLERANCE_M = 0.15
PROFILE_PRIOR_DEPTH_M = 0.10
PROFILE_MAX_RADIUS_M = 0.45
PROFILE_MIN_BINS_ON = 3


@dataclass(frozen=True)
class ScanLog:
    """A log found in the scan: its axis over the visible ridge (same frame as the points)."""

    start_m: np.ndarray  # (3,) axis point where the ridge starts [m]
    end_m: np.ndarray  # (3,) ... and ends [m]
    radius_m: float  # estimated from the top's cross-section [m]
    seen_m: float  # length of ridge actually seen (gaps left out) [m]
    strength_per_m: float  # mean curvature across over its ridge pixels [1/m]

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.end_m[:2] - self.start_m[:2]))

    @property
    def direction(self) -> np.ndarray:
        """Unit 3-D direction start -> end."""
        d = self.end_m - self.start_m
        return d / max(float(np.linalg.norm(d)), 1e-9)

    def moved(self, T: np.ndarray) -> "ScanLog":
        T = np.asarray(T, dtype=float)
        return ScanLog(T[:3, :3] @ self.start_m + T[:3, 3], T[:3, :3] @ self.end_m + T[:3, 3], self.radius_m,
                       self.seen_m, self.strength_per_m)

    def to_dict(self) -> dict:
        return {"start_m": [float(v) for v in self.start_m], "end_m": [float(v) for v in self.end_m],
                "radius_m": self.radius_m, "seen_m": self.seen_m, "strength_per_m": self.strength_per_m}


def _height_raster(P: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Highest point per cell (rows = y), whether a cell has points, and the raster origin (x, y)."""
    lo = P[:, :2].min(0) - 2 * cell
    hi = P[:, :2].max(0) + 2 * cell
    nx, ny = (np.ceil((hi - lo) / cell).astype(np.int64) + 1)
    if nx * ny > MAX_RASTER_CELLS:
        raise FitError(f"the scan spans {hi[0] - lo[0]:.0f} x {hi[1] - lo[1]:.0f} m: too large to look for logs in "
                       f"at {cell * 100:g} cm (crop it to the pile)")
    ix = ((P[:, 0] - lo[0]) / cell).astype(np.int64)
    iy = ((P[:, 1] - lo[1]) / cell).astype(np.int64)
    H = np.full((ny, nx), -np.inf)
    np.maximum.at(H, (iy, ix), P[:, 2])
    return H, np.isfinite(H), lo


def _ridges(H: np.ndarray, have: np.ndarray, cfg: FuseConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ridge strength (curvature across [1/m], 0 off ridges), the across direction [rad] per cell, and
    the heights with empty cells filled from the nearest cell with points."""
    from scipy import ndimage

    _, (jy, jx) = ndimage.distance_transform_edt(~have, return_indices=True)
    Hf = H[jy, jx]
    s = cfg.ridge_scale_m / cfg.cell_m
    c2 = cfg.cell_m ** 2
    hxx = ndimage.gaussian_filter(Hf, s, order=(0, 2)) / c2
    hyy = ndimage.gaussian_filter(Hf, s, order=(2, 0)) / c2
    hxy = ndimage.gaussian_filter(Hf, s, order=(1, 1)) / c2
    half_tr = 0.5 * (hxx + hyy)
    disc = np.sqrt(np.maximum(0.25 * (hxx - hyy) ** 2 + hxy ** 2, 0.0))
    l1, l2 = half_tr - disc, half_tr + disc  # l1 <= l2: across a ridge l1 is strongly negative
    # observed all around (the curvature's window; single empty cells of a sparse cloud do not count): the
    # hole fill is flat, and the edge of the data makes false curvature
    dense = have | ndimage.binary_closing(have, structure=np.ones((CLOSING_CELLS, CLOSING_CELLS), bool))
    seen = ndimage.gaussian_filter(dense.astype(np.float64), s) > SEEN_AROUND_SHARE
    ridge = seen & (l1 < -cfg.min_curvature_per_m) & (np.abs(l2) < cfg.max_anisotropy * np.abs(l1))
    strength = np.where(ridge, -l1, 0.0)
    along = 0.5 * np.arctan2(2 * hxy, hxx - hyy)  # eigenvector of l2: along the ridge
    return strength, along + 0.5 * math.pi, Hf


def find_scan_logs(points: np.ndarray, cfg: FuseConfig | None = None) -> list[ScanLog]:
    """Logs seen in a scan (``points`` (N, 3), any frame with z up), longest-supported first.

    See the module docstring. Each ridge line is split where it is broken for more than
    ``max_gap_m``; runs shorter than ``min_segment_m`` are dropped."""
    cfg = cfg or FuseConfig()
    P = np.asarray(points, dtype=np.float64)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < MIN_SCAN_POINTS:
        return []
    H, have, lo = _height_raster(P, cfg.cell_m)
    px = _RidgePixels(H, have, lo, cfg)
    if px.n < MIN_RIDGE_PIXELS:
        return []
    out: list[ScanLog] = []
    for _ in range(LINE_TRIES_PER_LOG * cfg.max_logs):
        if len(out) >= cfg.max_logs or px.alive.sum() < MIN_RIDGE_PIXELS:
            break
        peak = px.strongest_line()
        if peak is None:
            break
        line = px.take_line(*peak)
        if line is None:
            continue
        for t0, t1, run, seen in px.runs(*line):
            mean_strength = float(np.mean(px.strength[run]))
            if mean_strength < cfg.min_strength_per_m:
                continue
            c, u, _, tt = line
            log = _scan_log_from_run(P, c + px.c0, u, t0, t1, tt[run], px.z_top[run], seen, mean_strength, cfg)
            if log is not None:
                out.append(log)
    out.sort(key=lambda s: -s.seen_m)
    return out


def _ang_diff(a: np.ndarray, b: float) -> np.ndarray:
    """|a - b| for line directions (mod pi) [rad]."""
    return np.abs(np.mod(a - b + 0.5 * math.pi, math.pi) - 0.5 * math.pi)


class _RidgePixels:
    """The ridge pixels of a height raster (about their mean ``c0``), the Hough votes they cast for
    log-top lines, and which of them are still ``alive`` (not yet taken by a line)."""

    N_THETA = 180  # 1 deg line-direction bins
    SPREAD = 3  # each pixel votes for lines within +-3 deg of its own normal
    RUN_BIN_M = 0.05  # bins along a line, for its runs [m]

    def __init__(self, H: np.ndarray, have: np.ndarray, lo: np.ndarray, cfg: FuseConfig):
        from scipy import ndimage

        self.H, self.have, self.lo, self.cfg, self.cell = H, have, lo, cfg, cfg.cell_m
        strength, normal, Hf = _ridges(H, have, cfg)
        ys, xs = np.nonzero(strength > 0)
        self.n = len(xs)
        if self.n < MIN_RIDGE_PIXELS:
            return
        cell = self.cell
        self.strength = strength[ys, xs]
        self.w = np.minimum(self.strength, VOTE_CAP_PIXELS * cfg.min_curvature_per_m * WEAK_RIDGE_CURVATURES)
        X, Y = lo[0] + (xs + 0.5) * cell, lo[1] + (ys + 0.5) * cell
        self.th_p = np.mod(normal[ys, xs], math.pi)
        self.c0 = np.array([X.mean(), Y.mean()])
        self.Xc, self.Yc = X - self.c0[0], Y - self.c0[1]
        self.r_max = float(np.hypot(self.Xc, self.Yc).max()) + HOUGH_MARGIN_M
        self.n_rho = int(2 * self.r_max / cell) + 1
        self.th_bin = np.rint(np.degrees(self.th_p)).astype(np.int64)
        self.alive = np.ones(self.n, dtype=bool)
        self.band_px = max(1, int(round(cfg.band_m / cell)))
        self.max_ang = math.radians(cfg.max_angle_deg)
        self.min_votes = cfg.min_segment_m / cell * cfg.min_curvature_per_m * WEAK_RIDGE_CURVATURES  # a short weak line
        # heights at the ridge pixels: the top line
        self.z_top = ndimage.gaussian_filter(Hf, TOP_SMOOTHING_CELLS)[ys, xs]
        deg = np.radians(np.arange(self.N_THETA))
        self.cos_t, self.sin_t = np.cos(deg), np.sin(deg)

    def accumulate(self) -> np.ndarray:
        """The alive pixels' votes, (direction bin, offset bin), summed over a band's width."""
        from scipy import ndimage

        sp, n_th, n_rho = self.SPREAD, self.N_THETA, self.n_rho
        idx = np.flatnonzero(self.alive)
        tb = np.mod(self.th_bin[idx][:, None] + np.arange(-sp, sp + 1)[None, :], n_th)
        rho = self.Xc[idx][:, None] * self.cos_t[tb] + self.Yc[idx][:, None] * self.sin_t[tb]
        ri = np.clip(np.rint((rho + self.r_max) / self.cell).astype(np.int64), 0, n_rho - 1)
        acc = np.bincount((tb * n_rho + ri).ravel(), weights=np.repeat(self.w[idx], 2 * sp + 1),
                          minlength=n_th * n_rho).reshape(n_th, n_rho)
        # a log's top is a band of ridge pixels: lines through its middle collect the most
        return ndimage.uniform_filter1d(acc, 2 * self.band_px + 1, axis=1, mode="constant")

    def strongest_line(self) -> tuple[int, int] | None:
        """The (direction, offset) bins with the most votes; None when that is less than a short weak line."""
        acc = self.accumulate()
        ti, ri = np.unravel_index(int(np.argmax(acc)), acc.shape)
        return None if acc[ti, ri] * (2 * self.band_px + 1) < self.min_votes else (int(ti), int(ri))

    def take_line(self, ti: int, ri: int):
        """The line through the middle of that peak's band (weighted principal axis) and its pixels
        again: (point c about c0, unit direction u, its pixels' mask, every pixel's place along it);
        its pixels and those it suppresses are no longer alive. None: too few pixels on it."""
        cfg, max_ang = self.cfg, self.max_ang
        th = math.radians(ti)
        n = np.array([math.cos(th), math.sin(th)])
        lat = self.Xc * n[0] + self.Yc * n[1] - (ri * self.cell - self.r_max)
        m = self.alive & (np.abs(lat) < cfg.band_m) & (_ang_diff(self.th_p, th) < max_ang)
        if m.sum() < MIN_LINE_PIXELS:
            self.alive[np.abs(lat) < cfg.band_m] = False
            return None
        pts = np.column_stack([self.Xc[m], self.Yc[m]])
        ww = self.w[m]
        c = (pts * ww[:, None]).sum(0) / ww.sum()
        C = ((pts - c) * ww[:, None]).T @ (pts - c) / ww.sum()
        u = np.linalg.eigh(C)[1][:, 1]
        n = np.array([-u[1], u[0]])
        th2 = math.atan2(n[1], n[0])
        rel = np.column_stack([self.Xc, self.Yc]) - c
        lat, tt = rel @ n, rel @ u
        m = self.alive & (np.abs(lat) < cfg.band_m) & (_ang_diff(self.th_p, th2) < max_ang)
        taken = (self.alive & (np.abs(lat) < cfg.suppress_m)
                 & (_ang_diff(self.th_p, th2) < SUPPRESS_ANGLE_FACTOR * max_ang))
        self.alive &= ~(taken | m)
        return None if m.sum() < MIN_LINE_PIXELS else (c, u, m, tt)

    def runs(self, c: np.ndarray, u: np.ndarray, m: np.ndarray, tt: np.ndarray):
        """The runs along a line, (t0, t1, their pixels, length seen [m]), at least ``min_segment_m``
        long: bins holding a band's worth of ridge pixels (scattered ones do not bridge a gap), broken
        where more than ``max_gap_m`` is empty and nothing lies over the line along the gap."""
        cfg, bw, cell = self.cfg, self.RUN_BIN_M, self.cell
        idx_m = np.flatnonzero(m)
        t_m = tt[idx_m]
        b0 = math.floor(t_m.min() / bw)
        counts = np.bincount(np.floor(t_m / bw).astype(np.int64) - b0)
        full = max(FULL_BIN_MIN_PIXELS, int(FULL_BIN_SHARE * bw / cell * cfg.band_m / cell))
        full_bins = np.flatnonzero(counts >= full)
        if not len(full_bins):
            return
        breaks = np.flatnonzero(np.diff(full_bins) * bw > cfg.max_gap_m)
        breaks = np.asarray([k for k in breaks if self._real_break(c, u, idx_m, t_m, (b0 + full_bins[k] + 1) * bw,
                                                                    (b0 + full_bins[k + 1]) * bw)], dtype=np.int64)
        for s_, e_ in zip(np.r_[0, breaks + 1], np.r_[breaks, len(full_bins) - 1]):
            t0, t1 = (b0 + full_bins[s_]) * bw, (b0 + full_bins[e_] + 1) * bw
            if t1 - t0 >= cfg.min_segment_m:
                yield t0, t1, idx_m[(t_m >= t0) & (t_m < t1)], float(e_ - s_ + 1) * bw

    def _real_break(self, c, u, idx_m, t_m, g0: float, g1: float) -> bool:
        """A gap g0..g1 along the line splits it, unless something lies over the line all along it (logs
        across, at a shallow angle): a gap where the scan sees below the log's top is two logs."""
        near_a = idx_m[(t_m >= g0 - BREAK_SIDE_M) & (t_m < g0)]
        near_b = idx_m[(t_m >= g1) & (t_m < g1 + BREAK_SIDE_M)]
        return (g1 - g0 > self.cfg.max_occluded_gap_m or not len(near_a) or not len(near_b)
                or not _covered(self.H, self.have, self.lo, self.cell, c + self.c0, u, g0, g1,
                                min(float(np.median(self.z_top[near_a])), float(np.median(self.z_top[near_b])))))


def _covered(H: np.ndarray, have: np.ndarray, lo: np.ndarray, cell: float, c: np.ndarray, u: np.ndarray,
             t0: float, t1: float, z_top: float) -> bool:
    """Whether something stands over the line ``c + t u`` (``t0 < t < t1``) all along it: the raster's
    highest points there are nowhere more than ``COVER_DROP_M`` below ``z_top`` (the ridge's top height on either
    side) — the scan never sees the ground through the gap."""
    ts = np.arange(t0, t1, cell)
    xy = c + np.outer(ts, u)
    ix = np.clip(((xy[:, 0] - lo[0]) / cell).astype(np.int64), 0, H.shape[1] - 1)
    iy = np.clip(((xy[:, 1] - lo[1]) / cell).astype(np.int64), 0, H.shape[0] - 1)
    z = np.where(have[iy, ix], H[iy, ix], np.nan)
    z = z[np.isfinite(z)]
    return bool(len(z) >= COVER_MIN_SEEN * len(ts) and np.mean(z < z_top - COVER_DROP_M) < COVER_MAX_SEEN_THROUGH)


def _scan_log_from_run(P: np.ndarray, c: np.ndarray, u: np.ndarray, t0: float, t1: float, t_px: np.ndarray,
                       z_px: np.ndarray, seen: float, strength: float, cfg: FuseConfig) -> ScanLog | None:
    """A :class:`ScanLog` from one ridge run: the top line (robust straight line through the ridge
    pixels' heights), the radius from the scan points' cross-section under it, the axis one radius
    below the top."""
    A = np.column_stack([np.ones(len(t_px)), t_px])
    coef = np.linalg.lstsq(A, z_px, rcond=None)[0]
    for _ in range(TOP_LINE_ROUNDS):  # drop pixels of other things (a log lying across)
        res = z_px - A @ coef
        keep = np.abs(res) < max(TOP_LINE_BAND_M, TOP_LINE_MADS * float(np.median(np.abs(res))))
        if keep.sum() >= MIN_LINE_PIXELS:
            coef = np.linalg.lstsq(A[keep], z_px[keep], rcond=None)[0]
    n = np.array([-u[1], u[0]])
    rel = P[:, :2] - c
    t, s = rel @ u, rel @ n
    near = np.flatnonzero((t > t0) & (t < t1) & (np.abs(s) < PROFILE_HALF_WIDTH_M))
    if len(near) > PROFILE_MAX_POINTS:  # a profile needs a few thousand points at most
        near = near[np.linspace(0, len(near) - 1, PROFILE_MAX_POINTS).astype(np.int64)]
    dz = P[near, 2] - (coef[0] + coef[1] * t[near])
    radius = profile_radius(s[near], dz)
    if radius is None:
        return None
    a2, b2 = c + u * t0, c + u * t1
    z0, z1 = coef[0] + coef[1] * t0 - radius, coef[0] + coef[1] * t1 - radius
    return ScanLog(np.array([a2[0], a2[1], z0]), np.array([b2[0], b2[1], z1]), radius, seen, strength)


def profile_circle(s: np.ndarray, dz: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The half-circle (centre (across, height) [m] in the profile's frame, radius [m]) of the log whose
    cross-section (``s`` across [m], ``dz`` height below the ridge's top line [m]) the scan shows:
    :func:`reconstruct.fitting.profiles._profile_circle`'s search for the upper half-circle that best explains the
    visible profile, its centre within ``PROFILE_CENTRE_TOLERANCE_M`` of one ``PROFILE_PRIOR_DEPTH_M`` under the
    top. ``None`` when the profile explains no circle."""
    if len(s) < PROFILE_MIN_POINTS:
        return None
    try:
        centre, r, n_on = _profile_circle(np.column_stack([s, dz]), np.array([0.0, -PROFILE_PRIOR_DEPTH_M]),
                                          FitConfig(axis_tolerance_m=PROFILE_CENTRE_TOLERANCE_M,
                                                    max_radius_m=PROFILE_MAX_RADIUS_M))
    except FitError:
        return None
    return (centre, float(r)) if n_on >= PROFILE_MIN_BINS_ON else None


def profile_radius(s: np.ndarray, dz: np.ndarray) -> float | None:
    """The radius [m] of :func:`profile_circle` (``None`` when the profile explains no circle)."""
    fit = profile_circle(s, dz)
    return None if fit is None else fit[1]
