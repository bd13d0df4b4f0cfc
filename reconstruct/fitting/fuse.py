"""Survey and scan fused by their uncertainties.

An RTK survey of log ends is as good as its points: an RTK-fixed point is good to 1-2 cm, a float
one to decimetres, and some logs are not surveyed at all. The scan sees most logs and most of their
ends to a centimetre or two. This module lets each estimate count by its accuracy:

1. **Logs in the scan** (:func:`find_scan_logs`): the scan seen from above as a height raster; a
   log's top is a ridge (strongly curved across, straight along: the Hessian of the smoothed
   heights), and ridge pixels that line up are one log (a Hough transform over ridge pixels voting
   only near their own direction, so crossing logs stay apart and a log broken by one lying across
   it stays whole). Each found log has a top-view axis, a visible extent, an axis height and a
   radius estimate.
2. **Matching** (:func:`match_survey`): every surveyed log is matched to at most one scan log,
   minimising the summed squared normalised distances of its points from the scan log's axis (each
   point by its own accuracy, plus the scan pose's), with a point that lies inside the scan log's
   visible length counted against it. A point farther than ``gate_sigma`` from a scan log cannot
   be its. A surveyed log matched to none is left to the survey (it may be hidden under others). A
   scan log matched to no surveyed log is a log the survey missed: it is reconstructed from the
   scan alone. When another matching is nearly as good and would change which logs exist, the
   geometry is ambiguous: :class:`AmbiguousSurveyError` names the logs and points to re-measure.
3. **Ends** (:func:`scan_end_interval`, :func:`fuse_end`): along a fitted log the scan is walked
   outwards from its middle: every 2 cm bin over the axis is *on* the log's top, *over* it (an
   occluder), *below* it (the scan sees deeper than the top: the log is not there) or *unseen*.
   The log ends between the last bin on it and the first bin below it, so each end gets an
   interval: a couple of centimetres where the scan sees the end, longer where something lies over
   it, open where the scan stops. The surveyed point is then fused with that interval by the
   accuracies: a seen end and a point that agree are averaged by inverse variance (a float point
   inside the scan becomes as good as a fixed one); a point the scan contradicts by more than
   ``contradiction_sigma`` is reported and not used (except beyond a seen end where the log may run
   on unseen: under others, or as a tip held in the air, ``overhang_gap_m``); an end the scan does not see comes from the
   point (``fixed``/``float``), or, with no usable point, from the interval (``inferred``).

Every end is reported with its source (``scan``, ``fixed``, ``float``, ``inferred``), its 1-sigma
uncertainty, and the survey point's residual against the result (:class:`EndEstimate`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from reconstruct.errors import FitError

END_SOURCES = ("scan", "fixed", "float", "inferred")
END_STATES = ("seen", "occluded", "open", "none")  # what the scan shows of an end


class AmbiguousSurveyError(FitError):
    """The survey and the scan fit two different piles almost equally well (imprecise points near
    several scan logs): the message names the logs and points to re-measure."""


@dataclass(frozen=True)
class FuseConfig:
    """How logs are found in the scan, matched to the survey and their ends placed (units in the
    names/comments)."""

    cell_m: float = 0.01  # top-view raster cell [m]
    ridge_scale_m: float = 0.04  # Gaussian scale of the height curvature [m] (about half a log radius)
    min_curvature_per_m: float = 3.0  # a ridge is curved across by at least this [1/m] (a 16 cm log: ~10)
    max_anisotropy: float = 0.4  # ... and along it by at most this share of that [-]
    band_m: float = 0.06  # ridge pixels this close to a line belong to it [m]
    suppress_m: float = 0.10  # a found log's ridge pixels this close to its axis are taken out [m]
    max_angle_deg: float = 10.0  # a ridge pixel's direction is within this of its line's [deg]
    max_gap_m: float = 0.45  # a ridge broken for this long is still one log (another lies across it) [m]
    max_occluded_gap_m: float = 1.5  # ... and for up to this long where something lies over it all along [m]
    min_segment_m: float = 0.3  # shorter ridge runs are not counted as logs [m]
    min_strength_per_m: float = 6.0  # a line's mean curvature over its ridge pixels, at least [1/m]
    max_logs: int = 40  # lines taken from the scan at most [-]
    min_new_log_m: float = 0.9  # a log the survey missed must show at least this length in the scan [m]
    min_new_log_coverage: float = 0.6  # ... and its fit scan points over this share of it [-]
    pose_sigma_m: float = 0.04  # scan pose uncertainty while matching (added to each point's) [m]
    axis_sigma_m: float = 0.02  # a scan log's axis position from the raster, 1 sigma [m]
    radius_sigma_m: float = 0.03  # its axis height (top less an estimated radius), 1 sigma [m]
    gate_sigma: float = 4.0  # a point this many sigma from a scan log's axis is not on it [-]
    ridge_overrun_m: float = 0.10  # a ridge may run this far past its log's end [m]
    ambiguity_chi2: float = 4.0  # another matching within this summed chi^2 of the best is as good [-]
    end_bin_m: float = 0.02  # bins of the walk along a fitted log [m]
    seen_gap_m: float = 0.08  # an end whose top stops this close to where the scan sees below it is seen (the
    #                           gap is the end face's shadow) [m]
    end_search_m: float = 0.6  # the walk goes at most this far past the prior end [m]
    overhang_gap_m: float = 0.05  # past a seen end the scan sees this far under the log's underside: the tip
    #                               is in the air, and a point beyond it may place the end (_end_along); the
    #                               walk's gap reads the true clearance or less (median 3 cm less), and ends
    #                               resting on the ground read at most 1.6 cm (202 seen ground ends, 16 twin
    #                               scans) [m]
    island_max_m: float = 0.04  # a run on the log this short, past a stretch with none of at least
    island_gap_m: float = 0.20  # this long, is not the log's end (a neighbour's flank at its top's height) [m]
    on_band_m: float = 0.02  # a bin is on the log when points lie this close to its top [m]
    min_on_points: int = 2  # ... at least this many [-]
    scan_end_sigma_m: float = 0.015  # axial accuracy of an end the scan sees (stereo smear, bins) [m]
    contradiction_sigma: float = 3.0  # a point farther than this many sigma from the scan's estimate is
    #                                   contradicted: reported, not used [-]
    weak_sigma_m: float = 0.05  # an end less certain than this is a weak estimate (warned about) [m]
    descent_min_deg: float = 3.0  # past the end of a log descending outward at least this steeply [deg], level
    level_shoulder: float = 0.6  # ground (the scan beside the top this many radii over the axis) is no top [-]
    piece_share: float = 0.5  # a scan log seen over less than this share of its two precise survey points'
    #                           distance is a piece: the points set the log's prior axis [-] ...
    piece_off_m: float = 0.10  # ... when one of those points lies farther than this from the piece's line [m]
    inferred_sigma_m: float = 0.30  # uncertainty of an end known only to lie beyond what the scan sees [m]
    extrapolation_sigma_per_m: float = 0.02  # a fitted axis extended past what the scan shows of its log is
    #                                          less sure across by this per metre [m/m]

    def __post_init__(self) -> None:
        for name in ("cell_m", "ridge_scale_m", "min_curvature_per_m", "band_m", "suppress_m", "max_angle_deg",
                     "max_gap_m", "max_occluded_gap_m", "min_segment_m", "pose_sigma_m", "axis_sigma_m",
                     "radius_sigma_m", "gate_sigma", "ridge_overrun_m",
                     "end_bin_m", "seen_gap_m", "end_search_m", "overhang_gap_m", "on_band_m", "scan_end_sigma_m",
                     "island_max_m", "island_gap_m",
                     "contradiction_sigma", "weak_sigma_m", "inferred_sigma_m", "min_new_log_m",
                     "extrapolation_sigma_per_m", "piece_off_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.max_anisotropy < 1:
            raise ValueError(f"max_anisotropy must be in (0, 1), got {self.max_anisotropy}")
        if not 0 <= self.descent_min_deg < 90 or not self.level_shoulder > 0:
            raise ValueError("descent_min_deg must be in [0, 90) and level_shoulder > 0")
        if not 0 <= self.piece_share <= 1:
            raise ValueError(f"piece_share must be in [0, 1], got {self.piece_share}")
        if not 0 <= self.min_new_log_coverage <= 1:
            raise ValueError(f"min_new_log_coverage must be in [0, 1], got {self.min_new_log_coverage}")
        if self.cell_m > 0.05:
            raise ValueError(f"cell_m must be <= 0.05 m (logs are ~10-40 cm thick), got {self.cell_m}")
        if self.max_logs < 1 or self.min_on_points < 1 or self.ambiguity_chi2 < 0 or self.min_strength_per_m < 0:
            raise ValueError("max_logs and min_on_points must be >= 1, ambiguity_chi2 and min_strength_per_m >= 0")


# -- survey points and their accuracy ---------------------------------------------------------------
#: Typical 1-sigma accuracies (horizontal radial, vertical) [m] when a receiver reports none.
TYPICAL_ACCURACY_M = {"rtk_fixed": (0.015, 0.025), "rtk_float": (0.25, 0.40), "dgnss": (0.5, 1.0),
                      "single": (2.0, 4.0), "none": (10.0, 20.0)}


@dataclass(frozen=True)
class SurveyEnd:
    """One surveyed log end, with its accuracy (per axis)."""

    position_m: np.ndarray  # (3,) in the frame in use [m]
    sigma_h_m: float  # 1 sigma per horizontal axis [m] (the receiver's radial accuracy / sqrt 2)
    sigma_v_m: float  # 1 sigma vertical [m]
    fix: str  # reconstruct.survey.gnss.FIXES

    @property
    def label(self) -> str:
        """``fixed`` or ``float`` (what placed an end taken from this point)."""
        return "fixed" if self.fix == "rtk_fixed" else "float"

    def moved(self, T: np.ndarray) -> "SurveyEnd":
        p = np.asarray(T, dtype=float)[:3, :3] @ self.position_m + np.asarray(T, dtype=float)[:3, 3]
        return SurveyEnd(p, self.sigma_h_m, self.sigma_v_m, self.fix)

    def sigma_along(self, u: np.ndarray) -> float:
        """1-sigma accuracy along the unit direction ``u`` [m]."""
        u = np.asarray(u, dtype=float)
        return float(math.sqrt(self.sigma_h_m ** 2 * (u[0] ** 2 + u[1] ** 2) + self.sigma_v_m ** 2 * u[2] ** 2))

    @property
    def sigma_3d_m(self) -> float:
        return float(math.sqrt(2 * self.sigma_h_m ** 2 + self.sigma_v_m ** 2))


def point_accuracy(p: Any) -> tuple[float, float]:
    """(horizontal radial, vertical) 1-sigma accuracy [m] of a :class:`reconstruct.survey.gnss.GnssPoint`:
    the receiver's estimates, at least the scatter of its averaged epochs; typical values of its fix
    when it reports none (:data:`TYPICAL_ACCURACY_M`)."""
    th, tv = TYPICAL_ACCURACY_M.get(p.fix, TYPICAL_ACCURACY_M["none"])
    h = p.h_acc_m if math.isfinite(p.h_acc_m) else th
    v = p.v_acc_m if math.isfinite(p.v_acc_m) else tv
    return float(max(h, p.spread_h_m, 1e-3)), float(max(v, p.spread_v_m, 1e-3))


# -- logs in the scan -----------------------------------------------------------------------------
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
    if nx * ny > 25_000_000:
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
    dense = have | ndimage.binary_closing(have, structure=np.ones((3, 3), bool))
    seen = ndimage.gaussian_filter(dense.astype(np.float64), s) > 0.9
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
    if len(P) < 100:
        return []
    H, have, lo = _height_raster(P, cfg.cell_m)
    px = _RidgePixels(H, have, lo, cfg)
    if px.n < 10:
        return []
    out: list[ScanLog] = []
    for _ in range(4 * cfg.max_logs):
        if len(out) >= cfg.max_logs or px.alive.sum() < 10:
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
        if self.n < 10:
            return
        cell = self.cell
        self.strength = strength[ys, xs]
        self.w = np.minimum(self.strength, 5 * cfg.min_curvature_per_m * 2)  # a few sharp pixels do not dominate
        X, Y = lo[0] + (xs + 0.5) * cell, lo[1] + (ys + 0.5) * cell
        self.th_p = np.mod(normal[ys, xs], math.pi)
        self.c0 = np.array([X.mean(), Y.mean()])
        self.Xc, self.Yc = X - self.c0[0], Y - self.c0[1]
        self.r_max = float(np.hypot(self.Xc, self.Yc).max()) + 0.1
        self.n_rho = int(2 * self.r_max / cell) + 1
        self.th_bin = np.rint(np.degrees(self.th_p)).astype(np.int64)
        self.alive = np.ones(self.n, dtype=bool)
        self.band_px = max(1, int(round(cfg.band_m / cell)))
        self.max_ang = math.radians(cfg.max_angle_deg)
        self.min_votes = cfg.min_segment_m / cell * cfg.min_curvature_per_m * 2  # a short line of weak ridge pixels
        self.z_top = ndimage.gaussian_filter(Hf, 1.0)[ys, xs]  # heights at the ridge pixels: the top line
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
        if m.sum() < 5:
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
        taken = self.alive & (np.abs(lat) < cfg.suppress_m) & (_ang_diff(self.th_p, th2) < 2 * max_ang)
        self.alive &= ~(taken | m)
        return None if m.sum() < 5 else (c, u, m, tt)

    def runs(self, c: np.ndarray, u: np.ndarray, m: np.ndarray, tt: np.ndarray):
        """The runs along a line, (t0, t1, their pixels, length seen [m]), at least ``min_segment_m``
        long: bins holding a band's worth of ridge pixels (scattered ones do not bridge a gap), broken
        where more than ``max_gap_m`` is empty and nothing lies over the line along the gap."""
        cfg, bw, cell = self.cfg, self.RUN_BIN_M, self.cell
        idx_m = np.flatnonzero(m)
        t_m = tt[idx_m]
        b0 = math.floor(t_m.min() / bw)
        counts = np.bincount(np.floor(t_m / bw).astype(np.int64) - b0)
        full_bins = np.flatnonzero(counts >= max(3, int(0.4 * bw / cell * cfg.band_m / cell)))
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
        near_a = idx_m[(t_m >= g0 - 0.3) & (t_m < g0)]
        near_b = idx_m[(t_m >= g1) & (t_m < g1 + 0.3)]
        return (g1 - g0 > self.cfg.max_occluded_gap_m or not len(near_a) or not len(near_b)
                or not _covered(self.H, self.have, self.lo, self.cell, c + self.c0, u, g0, g1,
                                min(float(np.median(self.z_top[near_a])), float(np.median(self.z_top[near_b])))))


def _covered(H: np.ndarray, have: np.ndarray, lo: np.ndarray, cell: float, c: np.ndarray, u: np.ndarray,
             t0: float, t1: float, z_top: float) -> bool:
    """Whether something stands over the line ``c + t u`` (``t0 < t < t1``) all along it: the raster's
    highest points there are nowhere more than 3 cm below ``z_top`` (the ridge's top height on either
    side) — the scan never sees the ground through the gap."""
    ts = np.arange(t0, t1, cell)
    xy = c + np.outer(ts, u)
    ix = np.clip(((xy[:, 0] - lo[0]) / cell).astype(np.int64), 0, H.shape[1] - 1)
    iy = np.clip(((xy[:, 1] - lo[1]) / cell).astype(np.int64), 0, H.shape[0] - 1)
    z = np.where(have[iy, ix], H[iy, ix], np.nan)
    z = z[np.isfinite(z)]
    return bool(len(z) >= 0.5 * len(ts) and np.mean(z < z_top - 0.03) < 0.1)


def _scan_log_from_run(P: np.ndarray, c: np.ndarray, u: np.ndarray, t0: float, t1: float, t_px: np.ndarray,
                       z_px: np.ndarray, seen: float, strength: float, cfg: FuseConfig) -> ScanLog | None:
    """A :class:`ScanLog` from one ridge run: the top line (robust straight line through the ridge
    pixels' heights), the radius from the scan points' cross-section under it, the axis one radius
    below the top."""
    A = np.column_stack([np.ones(len(t_px)), t_px])
    coef = np.linalg.lstsq(A, z_px, rcond=None)[0]
    for _ in range(2):  # drop pixels of other things (a log lying across)
        res = z_px - A @ coef
        keep = np.abs(res) < max(0.02, 2.5 * float(np.median(np.abs(res))))
        if keep.sum() >= 5:
            coef = np.linalg.lstsq(A[keep], z_px[keep], rcond=None)[0]
    n = np.array([-u[1], u[0]])
    rel = P[:, :2] - c
    t, s = rel @ u, rel @ n
    near = np.flatnonzero((t > t0) & (t < t1) & (np.abs(s) < 0.4))
    if len(near) > 4000:  # a profile needs a few thousand points at most
        near = near[np.linspace(0, len(near) - 1, 4000).astype(np.int64)]
    dz = P[near, 2] - (coef[0] + coef[1] * t[near])
    radius = _profile_radius(s[near], dz)
    if radius is None:
        return None
    a2, b2 = c + u * t0, c + u * t1
    z0, z1 = coef[0] + coef[1] * t0 - radius, coef[0] + coef[1] * t1 - radius
    return ScanLog(np.array([a2[0], a2[1], z0]), np.array([b2[0], b2[1], z1]), radius, seen, strength)


def _profile_radius(s: np.ndarray, dz: np.ndarray) -> float | None:
    """Radius [m] of the log whose cross-section (``s`` across [m], ``dz`` height below the ridge's top
    line [m]) the scan shows: :func:`reconstruct.fitting.fit._profile_circle`'s search for the upper
    half-circle that best explains the visible profile, its centre within 15 cm of one 10 cm under the
    top. ``None`` when the profile explains no circle."""
    from reconstruct.fitting.fit import FitConfig, _profile_circle

    if len(s) < 30:
        return None
    try:
        _, r, n_on = _profile_circle(np.column_stack([s, dz]), np.array([0.0, -0.10]),
                                     FitConfig(axis_tolerance_m=0.15, max_radius_m=0.45))
    except FitError:
        return None
    return float(r) if n_on >= 3 else None


# -- matching the survey to the scan --------------------------------------------------------------
@dataclass
class Match:
    """How one surveyed log was matched to the scan."""

    log_id: str
    scan_index: int | None  # into the scan logs; None: no scan log (hidden, or not in the scan)
    reversed: bool = False  # its end "a" is at the scan log's end (not its start)
    chi2: float = math.nan  # summed squared normalised distances of its points [-]
    alternative: str = ""  # the next best choice and its chi^2, for the report

    def to_dict(self) -> dict:
        return {"scan_log": self.scan_index, "chi2": None if not math.isfinite(self.chi2) else self.chi2,
                "alternative": self.alternative or None}


def _match_cost(ends: tuple[SurveyEnd | None, SurveyEnd | None], log: ScanLog, cfg: FuseConfig,
                ) -> tuple[float, bool, int]:
    """Summed squared normalised distances of a surveyed log's points from a scan log (+inf when every
    point is beyond the gate), whether its end ``a`` lies at the scan log's end, and how many of its
    points lie beyond the gate (gross errors, if this is its log)."""
    p0, p1 = log.start_m, log.end_m
    d = p1[:2] - p0[:2]
    L = max(float(np.linalg.norm(d)), 1e-6)
    u = d / L
    n = np.array([-u[1], u[0]])
    best = (math.inf, False, 0)
    for rev in (False, True):
        total, outliers, far = 0.0, 0, 0
        for k, e in enumerate(ends):
            if e is None:
                continue
            at_start = (k == 0) != rev
            q = e.position_m
            t = float((q[:2] - p0[:2]) @ u)
            sh = math.hypot(e.sigma_h_m, math.hypot(cfg.pose_sigma_m, cfg.axis_sigma_m))
            sv = math.sqrt(e.sigma_v_m ** 2 + cfg.pose_sigma_m ** 2 + cfg.radius_sigma_m ** 2)
            lat = float((q[:2] - p0[:2]) @ n) / sh
            z_axis = p0[2] + (p1[2] - p0[2]) * np.clip(t / L, 0.0, 1.0)
            vert = (float(q[2]) - float(z_axis)) / sv
            # a log end is at or beyond the visible ridge: a point well inside it counts against (the ridge
            # may run on a little past the end: smoothing, the end face, a stack's smear)
            inside = max(0.0, t) if at_start else max(0.0, L - t)
            inside = max(0.0, min(inside, L) - cfg.ridge_overrun_m) / math.hypot(sh, cfg.ridge_overrun_m)
            c2 = lat * lat + vert * vert + inside * inside
            if lat * lat + vert * vert <= cfg.gate_sigma ** 2 and inside > cfg.gate_sigma:
                # on the ridge's line, well inside it: the ridge runs on past this end over something abutting
                # it (twin scan 1100166: 0.76 m past a fixed point, onto a stump) - as costly as a wrong point,
                # but not called wrong (a scrap of ridge at the point, the log's other point wrong, is no equal)
                c2 = cfg.gate_sigma ** 2 + 1.0
            elif lat * lat + vert * vert > cfg.gate_sigma ** 2 or inside > cfg.gate_sigma:
                # not on this scan log: a wrong point, if the log's other point is (costs more than the
                # gate, so a log with no point on a scan log is better matched to none)
                c2 = cfg.gate_sigma ** 2 + 1.0
                outliers += 1
            elif not -cfg.end_search_m <= t <= L + cfg.end_search_m:
                far += 1  # on the scan log's line, but beyond any walk from it
            total += c2
        if outliers and outliers == sum(e is not None for e in ends):
            total = math.inf
        if outliers and far:
            # a point called wrong, and the other only on the line far past the scan log: a scrap of
            # ridge crossing the surveyed log near one end is no evidence against its other point
            # (twin scan 1100084: a 0.40 m scrap at right angles to a log of two fixed points took it)
            total = math.inf
        if total < best[0]:
            best = (total, rev, outliers)
    return best


def match_survey(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], scan_logs: Sequence[ScanLog],
                 cfg: FuseConfig | None = None) -> tuple[dict[str, Match], list[int]]:
    """Match every surveyed log to at most one scan log (see the module docstring). Returns the
    matches by log id and the indices of scan logs no surveyed log took. Raises
    :class:`AmbiguousSurveyError` when another matching nearly as good would change which logs exist."""
    cfg = cfg or FuseConfig()
    ids = list(survey)
    cost, rev, n_out = _match_costs(survey, ids, scan_logs, cfg)
    # a surveyed log may match nothing (hidden, outside the scan): as costly as a point at the gate
    n_pts = np.array([sum(e is not None for e in survey[k]) for k in ids], dtype=float)
    none_cost = cfg.gate_sigma ** 2 * np.maximum(n_pts, 1)
    piles = _Piles(ids, scan_logs, n_out, cfg)
    best, pick = _assign(cost, none_cost)
    for _ in range(len(ids) + 1):  # each switch leaves fewer ridges unexplained: it ends
        switched = None
        alternatives = {}
        for i, k in enumerate(ids):
            if not scan_logs or pick[i] is None:
                continue
            c2 = cost.copy()
            c2[i, pick[i]] = math.inf
            alt, alt_pick = _assign(c2, none_cost)
            delta = alt - best
            alternatives[k] = f"{'nothing' if alt_pick[i] is None else f'scan log {alt_pick[i]}'} (chi2 {delta:+.1f})"
            if alt_pick[i] is None and _on_its_survey_line(scan_logs[pick[i]], survey[k], cfg):
                continue  # "hidden" would count the log twice: the scan shows it on its own fixed points' line
            if alt_pick[i] is None and _hidden_is_the_surer(survey, ids, pick, alt_pick, i):
                continue
            if not piles.as_good(pick, alt_pick, delta):
                continue
            if alt_pick[i] is not None and piles.unexplained(alt_pick) != piles.unexplained(pick):
                # of two scan logs, the one whose choice leaves fewer ridges standing as logs the survey missed
                # (the crew surveys every log: one it missed is the exception, not a tie)
                if piles.unexplained(alt_pick) < piles.unexplained(pick):
                    switched = (alt, alt_pick)
                    break
                continue
            raise _ambiguity(k, survey[k], scan_logs[pick[i]], None if alt_pick[i] is None else scan_logs[alt_pick[i]],
                             delta)
        if switched is None:
            break
        best, pick = switched
    matches = {k: Match(k, j, bool(rev[i, j]) if j is not None else False,
                        float(cost[i, j]) if j is not None else math.nan, alternatives.get(k, ""))
               for i, (k, j) in enumerate(zip(ids, pick))}
    taken = {j for j in pick if j is not None}
    return matches, [j for j in range(len(scan_logs)) if j not in taken]


def _hidden_is_the_surer(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], ids: list[str],
                         pick: list[int | None], alt: list[int | None], i: int) -> bool:
    """Whether of two matchings that differ in which of two logs the scan shows (``pick``: log ``i`` on a
    scan log, another hidden; ``alt``: log ``i`` hidden, that other on it), ``pick`` hides only logs whose
    two points are RTK fixed while log ``i`` has a float one. Two logs lying side by side, the scan showing
    one ridge (twin scans 700074, 700114: 17 cm apart, one 10 cm higher): the hidden log is placed from its
    survey points, so ``pick`` places both logs as well as the survey allows; were ``alt`` the truth,
    ``pick``'s hidden log would lie where the scan shows a log, for the pile check to refuse, and where the
    ridge is both logs end to end (700114), the log on it gets an end its float point contradicts, reported
    weak. So ``pick`` is taken, not an ambiguity."""
    unhidden = [j for j, (a, b) in enumerate(zip(pick, alt)) if a is None and b is not None]
    fixed = lambda k: all(e is not None and e.fix == "rtk_fixed" for e in survey[k])  # noqa: E731
    return bool(unhidden) and all(fixed(ids[j]) for j in unhidden) and not fixed(ids[i])


class _Piles:
    """What a matching (a scan log or None per surveyed log) makes of the pile, to compare two."""

    def __init__(self, ids: list[str], scan_logs: Sequence[ScanLog], n_out: np.ndarray, cfg: FuseConfig) -> None:
        self.ids, self.scan_logs, self.n_out, self.cfg = ids, scan_logs, n_out, cfg
        self.group = _line_groups(scan_logs)

    def content(self, p: list[int | None]) -> tuple[frozenset, frozenset]:
        """The pile: the scan logs matched or long enough to stand alone (pieces of one log count once),
        and the surveyed logs matched to none (placed from their points); two matchings that only swap
        which surveyed log sits on which scan log make the same pile."""
        used = {j for j in p if j is not None}
        used |= {j for j in range(len(self.scan_logs)) if j not in used and self.standalone(j)}
        return frozenset(self.group[j] for j in used), frozenset(self.ids[i] for i, j in enumerate(p) if j is None)

    def standalone(self, j: int) -> bool:
        return self.scan_logs[j].seen_m >= self.cfg.min_new_log_m

    def unexplained(self, p: list[int | None]) -> int:
        """Ridges long enough to stand alone that no surveyed log takes (a piece of a taken log is taken)."""
        taken = {self.group[j] for j in p if j is not None}
        return len({self.group[j] for j in range(len(self.scan_logs)) if self.standalone(j)} - taken)

    def gross_errors(self, p: list[int | None]) -> int:
        """Survey points a matching has to call wrong (beyond the gate of the scan log their log took)."""
        return int(sum(self.n_out[i, j] for i, j in enumerate(p) if j is not None))

    def as_good(self, best: list[int | None], alt: list[int | None], delta: float) -> bool:
        """Whether ``alt`` explains the survey as well as ``best`` and makes another pile. The chi^2
        margin is for noise: an alternative that has to call more survey points wrong (an outlier costs a
        constant, whatever its accuracy) is no equal explanation (twin scan 1100039: both ends of a log
        RTK fixed, "as good" on a 15 cm scrap of ridge with one of them wrong)."""
        return (delta < self.cfg.ambiguity_chi2 and self.content(alt) != self.content(best)
                and self.gross_errors(alt) <= self.gross_errors(best))


def _on_its_survey_line(log: ScanLog, ends: tuple[SurveyEnd | None, SurveyEnd | None], cfg: FuseConfig) -> bool:
    """Whether scan log ``log`` is a piece of the log whose two RTK fixed points are ``ends``: on their
    line in top view (:func:`_is_piece_of`), overlapping the stretch between them by at least
    ``min_segment_m``, and not lying above it (a log resting on top along it would be another log: its
    axis at least a radius higher). Then "that log is hidden and the scan log another" counts one log
    twice (twin scan 1100133: a sloped ridge on a log's fixed line stopped the scan as ambiguous)."""
    if any(e is None or e.fix != "rtk_fixed" for e in ends):
        return False
    a, b = ends[0].position_m, ends[1].position_m
    span = float(np.linalg.norm((b - a)[:2]))
    if span < cfg.min_segment_m:
        return False
    line = ScanLog(a, b, 0.0, span, 0.0)
    if not _is_piece_of(log, line):
        return False
    u = (b - a)[:2] / span
    t0, t1 = sorted(float((p[:2] - a[:2]) @ u) for p in (log.start_m, log.end_m))
    lo, hi = max(t0, 0.0), min(t1, span)
    if hi - lo < cfg.min_segment_m:
        return False
    ts = np.linspace(lo, hi, 9)
    t_log = (ts - t0) / max(t1 - t0, 1e-9)
    start, end = (log.start_m, log.end_m) if float((log.end_m - log.start_m)[:2] @ u) >= 0 else (log.end_m, log.start_m)
    z_log = start[2] + (end[2] - start[2]) * t_log
    z_line = a[2] + (b[2] - a[2]) * ts / span
    return float(np.mean(z_log - z_line)) < log.radius_m


def _match_costs(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], ids: list[str],
                 scan_logs: Sequence[ScanLog], cfg: FuseConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per (surveyed log, scan log): the match's chi^2 (inf: gated out), whether it runs b -> a, and
    how many of its survey points it calls wrong (:func:`_match_cost`)."""
    cost = np.full((len(ids), len(scan_logs)), math.inf)
    rev = np.zeros(cost.shape, dtype=bool)
    n_out = np.zeros(cost.shape, dtype=np.int64)
    for i, k in enumerate(ids):
        for j, log in enumerate(scan_logs):
            cost[i, j], rev[i, j], n_out[i, j] = _match_cost(survey[k], log, cfg)
    return cost, rev, n_out


def _assign(c: np.ndarray, none_cost: np.ndarray) -> tuple[float, list[int | None]]:
    """The cheapest matching of rows (surveyed logs) to columns (scan logs) or to nothing at
    ``none_cost``: its total cost and each row's column (None: nothing)."""
    from scipy.optimize import linear_sum_assignment

    n_s, n_k = c.shape
    big = 1e9
    full = np.full((n_s, n_k + n_s), big)
    full[:, :n_k] = np.where(np.isfinite(c), c, big)
    full[np.arange(n_s), n_k + np.arange(n_s)] = none_cost
    rows, cols = linear_sum_assignment(full)
    pick: list[int | None] = [None] * n_s
    total = 0.0
    for r, col in zip(rows, cols):
        total += float(full[r, col])
        pick[r] = int(col) if col < n_k and full[r, col] < big else None
    return total, pick


def _line_groups(scan_logs: Sequence[ScanLog]) -> list[int]:
    """A group per scan log: pieces of one log (collinear scan logs: a log seen in two pieces with a
    stretch under others between) share one, so a surveyed log on either piece makes the same pile."""
    group = list(range(len(scan_logs)))
    for j in range(len(scan_logs)):
        for j2 in range(j):
            if _same_line(scan_logs[j], scan_logs[j2]):
                old, new = group[j], group[j2]
                group = [new if g == old else g for g in group]
    return group


def _ambiguity(log_id: str, ends: tuple[SurveyEnd | None, SurveyEnd | None], chosen: ScanLog,
               other: ScanLog | None, delta: float) -> AmbiguousSurveyError:
    """The error for a surveyed log that fits ``chosen`` and ``other`` (None: hidden) almost equally
    well, saying what to re-measure."""
    pts = ", ".join(f"{end} ({p.fix}, +-{p.sigma_h_m * math.sqrt(2) * 100:.0f} cm)"
                    for end, p in zip("ab", ends) if p is not None)
    alt = "being hidden under other logs" if other is None else f"the scan's log {_where(other)}"
    if all(p is None or p.fix == "rtk_fixed" for p in ends):
        # fixed points are not made better by measuring them again with a fixed solution
        todo = (f"Check that log {log_id!r}'s points were taken at its end centres (re-measure them), and survey "
                "the neighbouring logs' ends")
    else:
        todo = (f"Re-measure log {log_id!r}'s "
                + " and ".join(f"end {end}" for end, p in zip("ab", ends) if p is not None and p.fix != "rtk_fixed")
                + " with an RTK fixed solution (or survey the neighbouring logs)")
    return AmbiguousSurveyError(
        f"log {log_id!r} fits the scan's log {_where(chosen)} and {alt} almost equally well (chi2 differs by "
        f"{delta:.1f}; its points: {pts}), and the two make different piles. {todo}")


def _where(log: ScanLog) -> str:
    m = 0.5 * (log.start_m + log.end_m)
    return f"at ({m[0]:.2f}, {m[1]:.2f}) m, {log.length_m:.2f} m long"


#: a scan log is a piece of another when it lies this close to its line [m] and this parallel [deg]
PIECE_LATERAL_M = 0.06
PIECE_ANGLE_DEG = 6.0


def _is_piece_of(piece: ScanLog, log: ScanLog, lateral_m: float = PIECE_LATERAL_M,
                 angle_deg: float = PIECE_ANGLE_DEG) -> bool:
    """Whether ``piece`` lies on ``log``'s line (top view): parallel within ``angle_deg`` and both its
    ends within ``lateral_m`` of the line."""
    u = log.direction[:2] / max(float(np.linalg.norm(log.direction[:2])), 1e-9)
    v = piece.direction[:2] / max(float(np.linalg.norm(piece.direction[:2])), 1e-9)
    if abs(float(u @ v)) < math.cos(math.radians(angle_deg)):
        return False
    return all(_off_line_m(log, p) < lateral_m for p in (piece.start_m, piece.end_m))


def _off_line_m(log: ScanLog, p: np.ndarray) -> float:
    """Distance of the point ``p`` from ``log``'s line in top view [m]."""
    u = log.direction[:2] / max(float(np.linalg.norm(log.direction[:2])), 1e-9)
    q = p[:2] - log.start_m[:2]
    return abs(float(u[0] * q[1] - u[1] * q[0]))


def _same_line(a: ScanLog, b: ScanLog) -> bool:
    """Whether two scan logs are pieces of one log: the shorter lies on the longer's line."""
    short, long_ = (a, b) if a.length_m <= b.length_m else (b, a)
    return _is_piece_of(short, long_)


def absorb_pieces(matches: Mapping[str, Match], unmatched: Sequence[int], scan_logs: Sequence[ScanLog],
                  lateral_m: float = PIECE_LATERAL_M, angle_deg: float = PIECE_ANGLE_DEG) -> list[int]:
    """Unmatched scan logs that continue a matched one (collinear: a log seen in two pieces with a
    long stretch under others between) are dropped from ``unmatched``. Returns the rest."""
    matched = [scan_logs[m.scan_index] for m in matches.values() if m.scan_index is not None]
    return [j for j in unmatched
            if not any(_is_piece_of(scan_logs[j], log, lateral_m, angle_deg) for log in matched)]


# -- priors for the fit ---------------------------------------------------------------------------
def prior_axis(ends: tuple[SurveyEnd | None, SurveyEnd | None], log: ScanLog | None, reversed_: bool,
               cfg: FuseConfig | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Where to fit a log: (end a, end b, lateral 1-sigma [m]). On the scan log's axis when matched:
    each end where its survey point projects, or the ridge's end when the point is missing or less
    certain than the ridge's extent; from the survey points alone when unmatched."""
    cfg = cfg or FuseConfig()
    if log is None:
        a, b = ends
        if a is None or b is None:
            raise ValueError("an unmatched surveyed log needs both ends")
        return a.position_m.copy(), b.position_m.copy(), max(a.sigma_3d_m, b.sigma_3d_m)
    if a_piece_of_a_surveyed_log(ends, log, cfg):
        a, b = ends
        return a.position_m.copy(), b.position_m.copy(), max(a.sigma_3d_m, b.sigma_3d_m)
    p0, p1 = (log.end_m, log.start_m) if reversed_ else (log.start_m, log.end_m)
    d = p1 - p0
    L = max(float(np.linalg.norm(d)), 1e-6)
    u = d / L
    out = []
    for k, (e, ridge_end) in enumerate(zip(ends, (p0, p1))):
        if e is None or e.sigma_h_m > cfg.end_search_m / 3:
            out.append(ridge_end.copy())
            continue
        t = float((e.position_m - p0) @ u)
        # the survey point's place along the axis; an imprecise one reaches at most end_search_m past the ridge
        if e.sigma_h_m > cfg.weak_sigma_m:
            t = max(t, -cfg.end_search_m) if k == 0 else min(t, L + cfg.end_search_m)
        out.append(p0 + u * t)
    return out[0], out[1], math.hypot(cfg.axis_sigma_m, cfg.pose_sigma_m / 2)


def a_piece_of_a_surveyed_log(ends: tuple[SurveyEnd | None, SurveyEnd | None], log: ScanLog, cfg: FuseConfig) -> bool:
    """Whether the scan log a surveyed log matched is a piece of it, too short to set its axis (the log is
    then seen only in part: :func:`reconstruct.fitting.fit.fit_pile` ``in_part``): both survey points
    precise (to ``weak_sigma_m``), the ridge seen over less than ``piece_share`` of the distance between
    them, and one of them farther than ``piece_off_m`` from the ridge's line (a piece in line with the
    points fits the log as well as ever, often better than the points: its log is fitted as before; on the
    200-scan bench, taking every piece as the log seen in part cost 1-4 cm on 20 logs). Two RTK-fixed
    points 2.7 m apart set the line to ~0.5 deg; a 35 cm ridge, its axis known to 2 cm at each end, to
    ~6 deg, off by 20-40 cm at the far end (real-test scan 700414: a log under others, a piece of it seen by
    its butt, fitted 9 deg off and 41 cm off its other, fixed, point)."""
    a, b = ends
    if a is None or b is None or max(a.sigma_h_m, b.sigma_h_m) > cfg.weak_sigma_m:
        return False
    if log.seen_m >= cfg.piece_share * float(np.linalg.norm(b.position_m - a.position_m)):
        return False
    return max(_off_line_m(log, a.position_m), _off_line_m(log, b.position_m)) > cfg.piece_off_m


# -- ends ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class EndInterval:
    """What the scan shows about where a log ends, along its axis (metres from its end a)."""

    last_on_m: float | None  # the last bin on the log's top (None: the scan shows none of it)
    first_off_m: float | None  # the first bin past it where the scan sees below the top (None: never)
    state: str  # END_STATES: "seen" (a short interval), "occluded" (something over it), "open", "none"
    gap_under_m: float | None = None  # how far below the log's underside the scan sees there (first_off) [m]
    covered_to_m: float | None = None  # the farthest bin of the walk (outward) with scan points in it [m]


def scan_end_interval(points: np.ndarray, p0: np.ndarray, p1: np.ndarray, radius_m: float, toward_p1: bool,
                      reach_m: float, cfg: FuseConfig | None = None, t_from: float | None = None,
                      on_mask: np.ndarray | None = None) -> EndInterval:
    """Walk along the log axis ``p0`` -> ``p1`` from its middle (or ``t_from`` [m from p0]) toward
    ``p1`` (``toward_p1``) or ``p0``, up to ``reach_m`` past that end, and find where the log ends
    (see the module docstring). ``points``: scan points (N, 3), same frame (without those on other
    logs: a neighbour's top where it touches this log's end is not this log). ``on_mask`` (per point):
    which points may show the log's top (default all); the others still show where the scan sees below
    it (a neighbour's surface near this log's end, a few cm off its own fit, is not this log's top, but
    seen lower than that top it shows the log is not there)."""
    cfg = cfg or FuseConfig()
    P = np.asarray(points, dtype=np.float64)
    d = np.asarray(p1, float) - np.asarray(p0, float)
    L = float(np.linalg.norm(d))
    u = d / max(L, 1e-9)
    rel = P - p0
    t = rel @ u
    perp = rel - np.outer(t, u)
    up = np.array([0.0, 0.0, 1.0]) - u[2] * u
    up /= max(float(np.linalg.norm(up)), 1e-9)
    side = np.cross(u, up)
    s = perp @ side
    r = float(radius_m)
    lo_t, hi_t = -reach_m, L + reach_m
    t_all, s_all, h_all = t, s, perp @ up
    m = (np.abs(s) < 0.5 * r) & (t > lo_t) & (t < hi_t)
    may_be_on = np.ones(int(m.sum()), bool) if on_mask is None else np.asarray(on_mask, bool)[m]
    t, s, h = t[m], s[m], (perp[m] @ up)
    expected = np.sqrt(np.clip(r * r - s * s, 0.0, None))  # the top's height over the axis there
    e = h - expected
    step = cfg.end_bin_m
    nb = int(math.ceil((hi_t - lo_t) / step))
    bi = np.clip(((t - lo_t) / step).astype(np.int64), 0, nb - 1)
    on = np.bincount(bi, weights=((np.abs(e) < cfg.on_band_m) & may_be_on).astype(float),
                     minlength=nb) >= cfg.min_on_points
    on &= ~_level_ground_past_the_end(t_all, s_all, h_all, r, L, u, toward_p1, lo_t, step, nb, cfg)
    top = np.full(nb, -np.inf)
    np.maximum.at(top, bi, e)
    count = np.bincount(bi, minlength=nb)
    below_thr = -max(0.03, 0.5 * r)
    # the scan sees deeper than the log's top there (two points at least: one stray point is noise)
    below = ~on & (count >= 2) & (top < below_thr)
    start = (0.5 * L if t_from is None else float(t_from))
    k0 = int(np.clip((start - lo_t) // step, 0, nb - 1))
    ks = np.arange(k0, nb) if toward_p1 else np.arange(k0, -1, -1)
    on_k, below_k = on[ks].astype(int), below[ks].astype(int)
    if not on_k.any():
        return EndInterval(None, None, "none")
    # the end is the cut that best separates bins on the log (inside) from bins seen below its top
    # (outside): a stray bin of either kind (a gap seen through at a crossing, another log's top at the
    # same height farther on) does not decide it; bins over it or unseen count for neither
    # (seeing the ground through where the log would be is the stronger evidence: it counts threefold)
    w_below = 3
    inside = np.cumsum(on_k - w_below * below_k)
    outside = np.cumsum((w_below * below_k - on_k)[::-1])[::-1]
    score = inside + np.r_[outside[1:], 0]
    score[on_k == 0] = np.iinfo(np.int64).min  # the cut is right after a bin on the log
    j = int(np.argmax(score))
    over_k = ((count >= 2) & (top > cfg.on_band_m))[ks].astype(int)  # something over the log's top
    beyond = _first_below(below_k[j + 1:], over_k[j + 1:])
    first_off = None if beyond is None else int(ks[j + 1 + beyond])
    last_on = int(ks[_before_island(on_k, j, step, cfg)])

    # the last bin on the log ends it at its middle (stereo smears a top a centimetre past its end); the
    # first bin below begins where it begins
    t_on = lo_t + (last_on + 0.5) * step
    if first_off is None:
        return EndInterval(t_on, None, "open")
    t_off = lo_t + (first_off + (0 if toward_p1 else 1)) * step
    state = "seen" if abs(t_off - t_on) <= cfg.seen_gap_m + 1e-9 else "occluded"
    covered = ks[np.flatnonzero(count[ks] >= 2)[-1]]  # the walk's farthest bin with points (at least first_off)
    t_cov = lo_t + (covered + (1 if toward_p1 else 0)) * step
    return EndInterval(t_on, t_off, state, gap_under_m=float(-top[first_off] - 2 * r), covered_to_m=float(t_cov))


def _first_below(below: np.ndarray, over: np.ndarray, span: int = 4, min_over: int = 3) -> int | None:
    """The first bin of the walk past the cut (index into ``below``) where the scan sees below the log's
    top, skipping a lone such bin inside a stretch over the log: no other bin below within ``span`` bins
    on either side, and at least ``min_over`` of those ``span`` bins on each side show something over the
    log's top - a gap seen through between logs lying over it (twin scan 1100028, fixed survey: a log under
    a crossing one for 80 cm to its fixed point, one bin seen through 19 cm into that stretch, the ground
    seen right past the point; that bin contradicted the point and the end was put 72 cm short). Any other
    bin below, alone or not, is where the scan shows the log is not."""
    n = len(below)
    for i in np.flatnonzero(below):
        lo, hi = below[max(i - span, 0):i], below[i + 1:i + 1 + span]
        o_lo, o_hi = over[max(i - span, 0):i], over[i + 1:i + 1 + span]
        lone = not lo.any() and not hi.any() and i + span < n
        if not (lone and o_lo.sum() >= min_over and o_hi.sum() >= min_over):
            return int(i)
    return None


def _level_ground_past_the_end(t: np.ndarray, s: np.ndarray, h: np.ndarray, r: float, L: float, u: np.ndarray,
                               toward_p1: bool, lo_t: float, step: float, nb: int, cfg: FuseConfig) -> np.ndarray:
    """Per walk bin: past the fitted end of a log whose axis descends outward (more than
    ``descent_min_deg``), the scan shows level ground, not a log's top: the points beside the top's band
    (``r`` to 1.5 ``r`` across) lie as high as the top itself (median at least ``level_shoulder`` ``r``
    over the axis), where beside a log's top the scan sees lower (the log's flanks, the ground, a
    neighbour's flank). A log running down to the ground ends there; its axis extended past the end
    goes into the ground, and where that line's top meets the ground the ground looked like the log's
    top (real-test scan 700414: 10 bins of flat ground 45-60 cm past an RTK-fixed end outweighed 3
    bins seen below, and the end was placed 59 cm out, the fixed point called wrong)."""
    out = np.zeros(nb, bool)
    outward = u[2] if toward_p1 else -u[2]
    if outward > -math.sin(math.radians(cfg.descent_min_deg)):
        return out
    past = (t > L) if toward_p1 else (t < 0.0)
    sh = past & (np.abs(s) > r) & (np.abs(s) < 1.5 * r) & (t > lo_t)
    if not sh.any():
        return out
    bi = np.clip(((t[sh] - lo_t) / step).astype(np.int64), 0, nb - 1)
    for b in np.unique(bi):
        hb = h[sh][bi == b]
        out[b] = len(hb) >= 2 and float(np.median(hb)) >= cfg.level_shoulder * r
    return out


def _before_island(on_k: np.ndarray, j: int, step: float, cfg: FuseConfig) -> int:
    """The walk's last bin on the log (index into the walk), given the cut after bin ``j``: the same,
    unless the run on the log that ends at ``j`` is an island - at most ``island_max_m`` long, past a
    stretch of at least ``island_gap_m`` with no bin on the log (unseen, or something over it). Then the
    log's own top ends before that stretch, and the island, a few points at the height of its top just
    before the scan sees the ground, is a neighbour's flank or edge (twin scan 1100052 log 2: its end
    hidden under a crossing log, six points 31 cm on put the 'seen' end there, past its fixed point and
    the truth). The interval then runs from that top's end to where the scan sees below it: occluded."""
    start = j
    while start > 0 and on_k[start - 1]:
        start -= 1
    if (j - start + 1) * step > cfg.island_max_m + 1e-9:
        return j
    prev = start - 1
    while prev >= 0 and not on_k[prev]:
        prev -= 1
    if prev < 0 or (start - 1 - prev) * step < cfg.island_gap_m - 1e-9:
        return j
    return prev


def seen_end(interval: EndInterval) -> float:
    """Where a seen end lies along the axis [m from p0]: the middle of the last bin on the log's top.
    Stereo smears a top about half a bin past its end, so that middle, not the bin's outer edge, is
    where the end is (on 166 seen ends of 20 twin scans: +1.3 mm outward in median, sd 8.8 mm; the
    bin's outer edge toward the first bin below it: +9.3 mm)."""
    return float(interval.last_on_m)


@dataclass
class EndEstimate:
    """One log end as placed: where, how sure, from what, and what the survey point said."""

    position_m: np.ndarray  # (3,) [m]
    sigma_m: float  # 1-sigma 3-D uncertainty [m]
    sigma_along_m: float  # ... along the log axis [m]
    source: str  # END_SOURCES
    scan: str  # END_STATES: what the scan showed of the end
    gnss_fix: str | None = None  # the survey point's fix (None: no point)
    gnss_residual_m: float | None = None  # survey point -> placed end [m]
    gnss_residual_sigma: float | None = None  # ... in units of the combined 1-sigma [-]
    contradicted: bool = False  # the scan contradicts the survey point: not used
    gnss_axis_distance_m: float | None = None  # survey point -> the placed log's axis line [m]
    gnss_position_m: np.ndarray | None = None  # the survey point (3,), in the frame of ``position_m`` [m]
    gnss_sigma_m: float | None = None  # ... its 1-sigma 3-D accuracy [m]

    def weak(self, cfg: FuseConfig | None = None) -> bool:
        """A weak estimate: less certain than ``weak_sigma_m``, or placed against its survey point."""
        cfg = cfg or FuseConfig()
        return self.sigma_m > cfg.weak_sigma_m or self.contradicted

    def to_dict(self) -> dict:
        return {"position_m": [float(v) for v in self.position_m], "sigma_m": self.sigma_m,
                "sigma_along_m": self.sigma_along_m, "source": self.source, "scan": self.scan,
                "gnss_fix": self.gnss_fix, "gnss_residual_m": self.gnss_residual_m,
                "gnss_residual_sigma": self.gnss_residual_sigma, "contradicted": self.contradicted,
                "gnss_axis_distance_m": self.gnss_axis_distance_m,
                "gnss_position_m": None if self.gnss_position_m is None else [float(v) for v in self.gnss_position_m],
                "gnss_sigma_m": self.gnss_sigma_m}


def fuse_end(p0: np.ndarray, u: np.ndarray, interval: EndInterval, at_start: bool, survey: SurveyEnd | None,
             lateral_sigma_m: float, cfg: FuseConfig | None = None, seen_whole: bool = True) -> EndEstimate:
    """Place one end on the axis ``p0 + t u`` (t [m] from ``p0``; the end is at the low-t side when
    ``at_start``) from the scan's interval and the survey point (see the module docstring).
    ``lateral_sigma_m``: how well the axis itself is known across [m]. ``seen_whole``: the scan shows
    the log whole (fit "scan"); for a log it shows only in part, a seen end that a survey point beyond
    it contradicts only bounds the end from inside (the log may run on under others where the scan
    sees something lower: a log bending down under a crossing one)."""
    cfg = cfg or FuseConfig()
    u = np.asarray(u, dtype=float)
    t_g = sg = None
    if survey is not None:
        t_g = float((survey.position_m - p0) @ u)
        sg = survey.sigma_along(u)
    if interval.last_on_m is None:  # the scan shows nothing of this log's top: where its survey point lies along it
        if survey is None:
            raise FitError("an end with neither scan points nor a survey point cannot be placed")
        t, sa, source, contradicted, past = t_g, sg, survey.label, False, 0.0
    else:
        on_axis = survey is not None and _on_axis(survey, p0, u, t_g, interval, lateral_sigma_m, cfg)
        t, sa, source, contradicted = _end_along(interval, -1.0 if at_start else 1.0, survey, t_g, sg, seen_whole, cfg,
                                                 on_axis)
        past = abs(t - interval.last_on_m)
    pos, lat = _end_across(np.asarray(p0, float) + u * t, u, past, survey, contradicted, lateral_sigma_m, cfg)
    sigma = math.sqrt(sa ** 2 + 2 * lat ** 2)
    est = EndEstimate(pos, float(sigma), float(sa), source, interval.state, None if survey is None else survey.fix,
                      contradicted=contradicted)
    if survey is not None:
        est.gnss_position_m, est.gnss_sigma_m = np.asarray(survey.position_m, dtype=float), survey.sigma_3d_m
        est.gnss_residual_m, est.gnss_residual_sigma, against = _point_test(survey, pos, sigma, cfg)
        est.contradicted = est.contradicted or against or _off_the_fitted_axis(survey, p0, u, lat, lateral_sigma_m, cfg)
    return est


def _off_the_fitted_axis(point: SurveyEnd, p0: np.ndarray, u: np.ndarray, lat_m: float, lateral_sigma_m: float,
                         cfg: FuseConfig) -> bool:
    """Whether a survey point lies farther across a log's scan-fitted axis than ``contradiction_sigma``
    of the two (the point's across accuracy; the axis's, ``lat_m`` at that end, and where the scan puts
    axes, ``axis_sigma_m``). The end stays on the fitted axis (a fitted axis is the better of the two),
    but the disagreement is reported: twin scan 700085 fitted a log on a ridge 9-14 cm off both its RTK
    fixed points, and the 3-D point test (~15 cm for a fixed point) called neither wrong. On 120 fixed
    points of scan-fitted logs of 13 twin reconstructions the offset was 1.8 cm median, 6.2 cm at most;
    this limit is ~8 cm for a fixed point. A log whose axis is the survey's is not tested here."""
    if lateral_sigma_m >= cfg.axis_sigma_m:
        return False
    sg_across = math.sqrt(0.5 * (point.sigma_h_m ** 2 + point.sigma_v_m ** 2))
    limit = cfg.contradiction_sigma * math.sqrt(lat_m ** 2 + sg_across ** 2 + cfg.axis_sigma_m ** 2)
    return _axis_distance(point, p0, u) > limit


def _point_test(point: SurveyEnd, pos: np.ndarray, sigma_m: float, cfg: FuseConfig) -> tuple[float, float, bool]:
    """A survey point against an end placed at ``pos`` to ``sigma_m`` (3-D): its distance [m], that in
    units of the combined sigma, and whether that contradicts it (chi with 3 dof, ~3 sigma each)."""
    res = float(np.linalg.norm(point.position_m - pos))
    res_sigma = res / math.sqrt(point.sigma_3d_m ** 2 + sigma_m ** 2)
    return res, res_sigma, res_sigma > cfg.contradiction_sigma * math.sqrt(3.0)


def _axis_distance(point: SurveyEnd, p0: np.ndarray, u: np.ndarray) -> float:
    """A survey point's distance from the axis line ``p0 + t u`` [m]."""
    rel = point.position_m - p0
    return float(np.linalg.norm(rel - (rel @ u) * u))


def after_pile_check(ends: Sequence[dict], endpoints: Sequence[np.ndarray],
                     survey: tuple[SurveyEnd | None, SurveyEnd | None], cfg: FuseConfig | None = None,
                     ) -> list[dict]:
    """Ends a, b (``EndEstimate.to_dict``) as the pile check left their log: each moved to the log's
    final end nearest it (``endpoints``: the log's two ends after the check), its survey point tested
    against that place with the estimate's own sigma (a check that pushed a log off its fixed points is
    a contradiction, never silent), then its sigma grown by the move (the check's correction is not
    in the estimate: a log pushed 6 cm is not known to 1 cm, and is reported weak). Ends the check did
    not move (under 1 mm) come back unchanged."""
    cfg = cfg or FuseConfig()
    out = []
    for e, point in zip(ends, survey):
        pos = np.asarray(e["position_m"], dtype=float)
        final = min((np.asarray(q, dtype=float) for q in endpoints), key=lambda q: float(np.linalg.norm(q - pos)))
        shift = float(np.linalg.norm(final - pos))
        if shift < 1e-3:
            out.append(dict(e))
            continue
        e = dict(e, position_m=[float(v) for v in final], check_shift_m=shift)
        if point is not None:
            e["gnss_residual_m"], e["gnss_residual_sigma"], against = _point_test(point, final, e["sigma_m"], cfg)
            e["contradicted"] = bool(e["contradicted"] or against)
            p0, p1 = (np.asarray(q, dtype=float) for q in endpoints)
            e["gnss_axis_distance_m"] = _axis_distance(point, p0, (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9))
        e["sigma_m"] = float(math.hypot(e["sigma_m"], shift))
        out.append(e)
    return out


def _on_axis(point: SurveyEnd, p0: np.ndarray, u: np.ndarray, t_g: float, interval: EndInterval,
             lateral_sigma_m: float, cfg: FuseConfig) -> bool:
    """Whether a survey point lies on the fitted axis line (within ``contradiction_sigma`` of its own
    3-D accuracy and of the axis's across, that growing past what the scan shows of the log)."""
    past = 0.0 if interval.last_on_m is None else abs(t_g - interval.last_on_m)
    lat = lateral_sigma_m + cfg.extrapolation_sigma_per_m * past
    return _axis_distance(point, p0, u) <= cfg.contradiction_sigma * math.hypot(point.sigma_3d_m, lat)


def _end_along(interval: EndInterval, sign: float, survey: SurveyEnd | None, t_g: float | None, sg: float | None,
               seen_whole: bool, cfg: FuseConfig, on_axis: bool = False) -> tuple[float, float, str, bool]:
    """Where an end the scan shows something of lies along the axis: (t [m], its sigma [m], its
    source, whether the survey point is contradicted). ``sign``: outward along t. ``on_axis``: the
    survey point lies on the fitted axis line (:func:`_on_axis`)."""
    lo, hi = interval.last_on_m, interval.first_off_m
    seen = interval.state == "seen"
    ss = cfg.scan_end_sigma_m
    if seen and survey is not None:
        # a seen end that a point beyond it contradicts only bounds the end from inside where the log may
        # run on unseen: under others (a log the scan shows in part), or as a tip held in the air, where
        # the cameras see the ground under it from the side and stereo loses its thin end (twin scan
        # 1100085: the top stopped 15 cm short of a fixed point and of the truth, ground 40 cm below)
        t_s = seen_end(interval)
        beyond = sign * (t_g - t_s)
        # ... a precise point as far as the walk goes, any point past what the scan covers (no points there
        # to say otherwise)
        past_cover = interval.covered_to_m is not None and sign * (t_g - interval.covered_to_m) > 0
        tip = _overhang(interval, cfg) and ((sg <= cfg.weak_sigma_m and beyond <= cfg.end_search_m) or past_cover)
        # ... and a precise point on the axis line past all the scan covers: the log runs on where the scan
        # has no points (twin scan 1100189: a top seen 1.55 m long, two bins 3 cm under it, then nothing; a
        # fixed point 97 cm on, 3 cm off the axis line, where the truth's end was)
        unseen_on = past_cover and on_axis and sg <= cfg.weak_sigma_m
        if abs(t_g - t_s) / math.hypot(ss, sg) > cfg.contradiction_sigma and beyond > 0 and (
                not seen_whole or tip or unseen_on):
            seen, hi = False, None
    if not seen_whole and survey is not None and sg <= ss and interval.state != "seen":
        # a log the scan shows only in part: its axis is the survey's and its radius a guess from a piece of
        # its top, so where the scan seems to see past its top (or on it) beyond a covered end is no match
        # for a point at least as precise as a seen end (twin scan 1100028: a radius 5 cm too large made the
        # true top look 'below' it; two RTK fixed points were dropped for ends 41-48 cm off)
        return t_g, sg, survey.label, False
    if seen:  # the top stops at lo; the scan sees below it a little farther out (hi)
        t_s = seen_end(interval)
        if survey is None:
            return t_s, ss, "scan", False
        if abs(t_g - t_s) / math.hypot(ss, sg) > cfg.contradiction_sigma:
            return t_s, ss, "scan", True
        wg, ws = 1.0 / sg ** 2, 1.0 / ss ** 2
        return (wg * t_g + ws * t_s) / (wg + ws), 1.0 / math.sqrt(wg + ws), ("scan" if ss <= sg else survey.label), False
    # the end lies past the last bin on the log (lo; the scan's own end of the log, to ss), and short of
    # hi when the scan sees below the top there (something lay over the end)
    inner = sign * lo
    outer = math.inf if hi is None else sign * hi
    width = None if hi is None else abs(hi - lo)
    tol = None if survey is None else cfg.contradiction_sigma * math.hypot(sg, ss)
    if survey is not None and inner - tol <= sign * t_g <= outer + tol:
        # a point more precise than the scan's bounds stands; a less precise one is kept within them
        t = t_g if sg <= ss else sign * float(np.clip(sign * t_g, inner, outer))
        sa = max(min(sg, width / math.sqrt(12.0)) if width is not None else sg, min(sg, ss))
        return t, sa, survey.label, False
    if width is not None and width <= 2 * cfg.end_search_m:
        return 0.5 * (lo + hi), max(width / math.sqrt(12.0), ss), "inferred", survey is not None
    return lo, cfg.inferred_sigma_m, "inferred", survey is not None


def _overhang(interval: EndInterval, cfg: FuseConfig) -> bool:
    """Whether a seen end is a tip in the air: the scan sees the ground past it more than
    ``overhang_gap_m`` under the log's underside."""
    return interval.gap_under_m is not None and interval.gap_under_m > cfg.overhang_gap_m


def _end_across(pos: np.ndarray, u: np.ndarray, past_m: float, survey: SurveyEnd | None, contradicted: bool,
                lateral_sigma_m: float, cfg: FuseConfig) -> tuple[np.ndarray, float]:
    """An end's place across the axis and its sigma there [m]: the fitted axis (less sure the farther,
    ``past_m``, the end lies past what the scan shows of the log); for a log the scan shows only in part
    or not at all, also the survey point, each by its accuracy (an axis fitted to the scan is better
    than any survey point: measured, pulling it toward fixed points by their accuracy cost 0.017 in
    median mask IoU on test_end_to_end_generated_pile); a point farther across than
    ``contradiction_sigma`` of the two sigmas places the end itself (the extrapolated axis is off)."""
    lat = lateral_sigma_m + cfg.extrapolation_sigma_per_m * past_m
    if survey is not None and not contradicted and lateral_sigma_m >= cfg.axis_sigma_m:
        off = survey.position_m - pos
        off -= (off @ u) * u  # the point's offset from the axis, across it
        sg_across = math.sqrt(0.5 * (survey.sigma_h_m ** 2 + survey.sigma_v_m ** 2))
        if float(np.linalg.norm(off)) > cfg.contradiction_sigma * math.hypot(lat, sg_across):
            # the two disagree beyond noise: the extrapolated axis of a log the scan shows in part is the
            # one that is off (a point is a direct measurement of the end), so the point places it
            return pos + off, sg_across
        w = lat ** 2 / (lat ** 2 + sg_across ** 2)
        pos = pos + w * off
        lat = math.sqrt(1.0 / (1.0 / lat ** 2 + 1.0 / sg_across ** 2))
    return pos, lat


def place_log_ends(points: np.ndarray, spec: Any, how: str, survey: tuple[SurveyEnd | None, SurveyEnd | None],
                   swapped: bool, lateral_sigma_m: float, cfg: FuseConfig | None = None,
                   on_mask: np.ndarray | None = None) -> tuple[Any, tuple[EndEstimate, EndEstimate]]:
    """A fitted log (:class:`synth.scene.pile.LogSpec` ``spec``, placed ``how``: "scan", "partial" or
    "hidden") with both ends placed by :func:`fuse_end`, and the two estimates in survey order
    (end a, end b; ``swapped``: end b is the butt). ``points``: the scan points that may lie on it;
    ``on_mask``: which of them may show its top (:func:`scan_end_interval`).
    ``lateral_sigma_m``: how well its axis is known across [m]."""
    from synth.scene.pile import LogSpec

    cfg = cfg or FuseConfig()
    butt, top = spec.endpoints_m()
    pa, pb = (top, butt) if swapped else (butt, top)
    L = float(np.linalg.norm(pb - pa))
    u = (pb - pa) / max(L, 1e-9)
    r = 0.5 * spec.mean_diameter_m
    # only the points over the log's line (as far as any walk can reach past its ends) matter
    P = np.asarray(points, dtype=np.float64)
    d2 = (pb - pa)[:2]
    t2 = (P[:, :2] - pa[:2]) @ d2 / max(float(d2 @ d2), 1e-12)
    across = np.abs((P[:, :2] - pa[:2]) @ np.array([-d2[1], d2[0]])) / max(float(np.linalg.norm(d2)), 1e-12)
    reach_t = 2.5 / max(float(np.linalg.norm(d2)), 1e-6)
    over = (across < r + 0.05) & (t2 > -reach_t) & (t2 < 1.0 + reach_t)
    points = P[over]
    on_mask = None if on_mask is None else np.asarray(on_mask, bool)[over]
    ests = []
    for k, e in enumerate(survey):
        # past the fitted end, as far as the survey point (and three of its sigmas) or, with none, a log
        # may run on unseen under others
        if e is None:
            reach = 2 * cfg.end_search_m
        else:
            t_g = float((e.position_m - pa) @ u)
            beyond = -t_g if k == 0 else t_g - L
            reach = float(np.clip(beyond + 3 * e.sigma_along(u) + 0.1, cfg.end_search_m, 2.0))
        if how == "hidden":
            iv = EndInterval(None, None, "none")
        else:
            iv = scan_end_interval(points, pa, pb, r, toward_p1=(k == 1), reach_m=reach, cfg=cfg, on_mask=on_mask)
        ests.append(fuse_end(pa, u, iv, k == 0, e, lateral_sigma_m, cfg, seen_whole=(how == "scan")))
    a, b = ests
    for est, e in zip(ests, survey):
        if e is not None:
            est.gnss_axis_distance_m = _axis_distance(e, pa, u)
    if float(np.linalg.norm(b.position_m - a.position_m)) < 0.3:  # nonsense: keep the fit's ends
        return spec, (a, b)
    new_butt, new_top = (b.position_m, a.position_m) if swapped else (a.position_m, b.position_m)
    return LogSpec.from_endpoints(new_butt, new_top, spec.diameter_m, spec.top_diameter_m, spec.colour), (a, b)
