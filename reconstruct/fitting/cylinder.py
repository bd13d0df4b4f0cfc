"""One log fitted to the scan points around its survey axis: a cylinder (or a truncated cone) through
its visible top (:func:`fit_log`).

RTK noise (1.5 cm horizontal, 2.5 cm vertical, 1 sigma) is larger than the diameter accuracy wanted
(1 cm), so the survey's axis is only the *start* of the fit:

1. the scan points around the survey axis are cut into ``chunk_length_m`` chunks; each chunk's visible
   cross-section profile gets the upper half-circle that explains it best
   (:func:`reconstruct.fitting.profiles._profile_circle`), with its centre within ``axis_tolerance_m`` of
   the survey axis; a line through the chunk centres is the initial axis;
2. a cylinder (or a truncated cone, ``fit_taper``) is fitted to the inliers in 3-D by robust least
   squares (scipy ``least_squares``, soft-L1 loss): axis position and direction, radius and radius slope,
   with a weak prior tying the axis to the survey points, on the points within ``max_angle_deg`` of the
   top (selected by angle, which does not bias the radius);
3. the log's ends are the survey points projected onto the fitted axis (``axis_source="fit"``) or the
   survey's axis itself (``axis_source="gnss"``). The distance between each survey point and the fitted
   axis is reported as that point's residual.

What the survey points are is ``FitConfig.endpoint_ref``: ``"end_centre"`` (default: the rover pole on
the centre of each end face, the points lie ON the axis, as :func:`reconstruct.survey.gnss.simulate_survey`
measures) or ``"top_surface"`` (taken on top of the log at each end: the axis lies one radius below them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from reconstruct.errors import FitError, LogNotSeenError
from reconstruct.fitting.fit_config import FitConfig
from reconstruct.fitting.profiles import _frame, _profile_circle
from reconstruct.fitting.survey_points import MIN_POINT_SIGMA_M, SURVEY_REACH_SIGMAS
from synth.scene.pile import LogSpec


# an end whose sigma is more than this many times gnss_sigma_m is imprecise (an RTK float fix) [-]
IMPRECISE_SIGMA_RATIO = 2
# an imprecise end's axis is the line through two chunk centres that most chunks agree with, from this
# many chunks on [-]; the line through the chunk centres is refitted this many times without the chunks off
# it, at most [-]; its band is at least this many profile_tolerance_m [-]
MIN_CONSENSUS_CHUNKS = 3
INITIAL_AXIS_ROUNDS = 3
CHUNK_LINE_MIN_TOLERANCES = 2
# the 3-D fit: fitted, its top band re-selected and refitted, this many times at most [-]; the scale of
# its parameters (shifts and radius [m], tilts and radius slope [-]) for the solver
FIT_ROUNDS = 2
FIT_PARAMETER_SCALE = 0.01
# a taper is judged from at least this many sections along the log [-]
TAPER_MIN_SECTIONS = 4
# a log's diameters from a fit are kept within these [m]
MIN_LOG_DIAMETER_M = 0.03
MAX_LOG_DIAMETER_M = 1.2
MIN_TOP_DIAMETER_M = 0.02
# a 3-D fit's radius this close to its window's edge is on it (the bound is active) [m]
RADIUS_EDGE_M = 1e-4


@dataclass(frozen=True)
class CylinderFit:
    """One log fitted to the scan (:func:`fit_log`, :func:`fit_radius_on_axis`), pile frame."""

    centre: np.ndarray  # (3,) a point on the fitted axis [m]
    axis: np.ndarray  # (3,) unit axis direction, end a -> end b [-]
    ends: np.ndarray  # (2, 3) ends a, b: the survey points projected on the fitted axis (or the survey's) [m]
    radius_a_m: float  # radius at end a [m]
    radius_b_m: float  # ... at end b [m]
    n_points: int  # scan points on the fitted surface [-]
    rms_m: float  # their RMS distance from it [m]
    coverage: float  # share of 10 cm bins along the log holding such points [-]
    residual_a_m: float  # survey point a -> its projection on the fitted axis [m]
    residual_b_m: float  # ... point b [m]
    end_source: tuple[str, str] = ("gnss", "gnss")  # what placed each end: "gnss" or "scan"
    taper_significance: float = 0.0  # fitted taper over its standard error [-]
    radius_source: str = "fit"  # "fit": the 3-D fit's; "profiles": the cross-section profiles' (the fit
    #                             ended on the edge of FitConfig.radius_window_m about them)
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # indices into the points

    def with_ends(self, ends: np.ndarray) -> "CylinderFit":
        return replace(self, ends=np.asarray(ends, dtype=np.float64))


@dataclass(frozen=True)
class _SearchRegion:
    """Where :func:`fit_log` looks for a log: the survey's axis a -> b, its frame, the scan points near it."""

    a: np.ndarray  # (3,) end a [m]
    b: np.ndarray  # (3,) end b [m]
    length_m: float  # |b - a| [m]
    u0: np.ndarray  # unit survey axis [-]
    e1: np.ndarray  # cross-section frame: horizontal-ish [-]
    e2: np.ndarray  # ... up-ish [-]
    t: np.ndarray  # every point's place along the axis from a [m]
    cand: np.ndarray  # indices of the points near the axis
    sw: np.ndarray  # (len(cand), 2) their cross-section coordinates [m]
    cfg: FitConfig  # the config in use (widened around imprecise ends)
    cfg_r: FitConfig  # ... with the cross-section search tolerance for the endpoint reference
    tol0_m: float  # the configured axis tolerance [m]
    sig_a_m: float  # survey accuracy of end a [m]
    sig_b_m: float  # ... end b [m]
    ext_a_m: float  # how far the search looks past end a (imprecise end) [m]
    ext_b_m: float  # ... past end b [m]
    prior: np.ndarray  # (2,) prior circle centre in the cross-section [m]


@dataclass(frozen=True)
class _Cylinder:
    """The least-squares cylinder of :func:`fit_log` (parameters about the axis midpoint)."""

    x: np.ndarray  # [shift e1, shift e2, tilt e1, tilt e2, radius, radius slope]
    sel: np.ndarray  # indices of the points on its surface
    centre: np.ndarray  # (3,) [m]
    u: np.ndarray  # (3,) unit axis [-]
    res: np.ndarray  # the selected points' distances from its surface [m]
    radius_source: str = "fit"  # "fit", or "profiles" where the fit ended on the radius window's edge


def _search_region(points: np.ndarray, end_a: Any, end_b: Any, cfg: FitConfig, log_id: str,
                   sigma_a_m: float | None, sigma_b_m: float | None) -> tuple[np.ndarray, _SearchRegion]:
    """The points (as float64) and where to look for the log among them."""
    a, b = np.asarray(end_a, dtype=np.float64), np.asarray(end_b, dtype=np.float64)
    L = float(np.linalg.norm(b - a))
    if L < cfg.min_survey_length_m:
        raise FitError(f"log {log_id!r}: its two GNSS points are only {L * 100:.1f} cm apart; "
                       "check that they are the two ends of one log")
    u0 = (b - a) / L
    e1, e2 = _frame(u0)
    P = np.asarray(points, dtype=np.float64)
    rel = P - a
    t = rel @ u0
    q = rel - np.outer(t, u0)
    sig_a = (cfg.gnss_sigma_m if sigma_a_m is None or not np.isfinite(sigma_a_m)
             else max(float(sigma_a_m), MIN_POINT_SIGMA_M))
    sig_b = (cfg.gnss_sigma_m if sigma_b_m is None or not np.isfinite(sigma_b_m)
             else max(float(sigma_b_m), MIN_POINT_SIGMA_M))
    tol0 = cfg.axis_tolerance_m
    # imprecise ends: search wider, shorter chunks
    if cfg.widen_search and max(sig_a, sig_b) * SURVEY_REACH_SIGMAS > tol0:
        cfg = replace(cfg, axis_tolerance_m=min(cfg.widened_tolerance_max_m, SURVEY_REACH_SIGMAS * max(sig_a, sig_b)),
                      chunk_length_m=min(cfg.chunk_length_m, cfg.widened_chunk_length_m))
    # look past an imprecise end (its position along the axis then comes from the scan)
    imprecise = IMPRECISE_SIGMA_RATIO * cfg.gnss_sigma_m
    ext_a = min(SURVEY_REACH_SIGMAS * sig_a, cfg.widened_reach_max_m) if cfg.widen_search and sig_a > imprecise else 0.0
    ext_b = min(SURVEY_REACH_SIGMAS * sig_b, cfg.widened_reach_max_m) if cfg.widen_search and sig_b > imprecise else 0.0
    near = (t > cfg.end_margin_m - ext_a) & (t < L - cfg.end_margin_m + ext_b)
    near &= np.einsum("ij,ij->i", q, q) < (cfg.max_radius_m + cfg.axis_tolerance_m) ** 2
    cand = np.flatnonzero(near)
    if cand.size < cfg.min_points:
        raise FitError(
            f"log {log_id!r}: only {cand.size} scan points within "
            f"{cfg.max_radius_m + cfg.axis_tolerance_m:.2f} m of the axis between its GNSS points "
            f"a={np.round(a, 2).tolist()} and b={np.round(b, 2).tolist()} (pile frame, m); the log "
            "is outside the scanned area, or its endpoints are wrong (wrong log id, swapped points)"
        )
    sw = np.stack([q[cand] @ e1, q[cand] @ e2], axis=1)
    # prior circle centre in the cross-section: on the axis, or one radius below (top_surface)
    prior = np.zeros(2)
    if cfg.endpoint_ref == "top_surface":
        prior = np.array([0.0, -0.5 * (cfg.min_radius_m + cfg.max_radius_m)])
        tol = cfg.axis_tolerance_m + 0.5 * (cfg.max_radius_m - cfg.min_radius_m)
        cfg_r = replace(cfg, axis_tolerance_m=tol)
    else:
        cfg_r = cfg
    return P, _SearchRegion(a, b, L, u0, e1, e2, t, cand, sw, cfg, cfg_r, tol0, sig_a, sig_b, ext_a, ext_b, prior)


def _chunk_circles(s: _SearchRegion, log_id: str) -> np.ndarray:
    """Half-circle profiles in axial chunks (the survey's axis direction is off by up to a few cm over
    the length, which would smear one cross-section of the whole log): rows of (place along the axis
    about its middle [m], centre e1 [m], centre e2 [m], radius [m], weight [1/m^2])."""
    cfg, cfg_r, L = s.cfg, s.cfg_r, s.length_m
    tc = s.t[s.cand]
    n_chunks = max(1, int((L - 2 * cfg.end_margin_m) // cfg.chunk_length_m))
    edges = np.linspace(cfg.end_margin_m, L - cfg.end_margin_m, n_chunks + 1)
    chunk = []
    for k in range(n_chunks):
        m = (tc >= edges[k]) & (tc < edges[k + 1])
        if m.sum() < cfg.chunk_min_points:
            continue
        # the search around the GNSS axis is as wide as the axis is uncertain THERE: tight near a
        # precise end, wide near an imprecise one
        f = 0.5 * (edges[k] + edges[k + 1]) / L
        tol_k = float(np.clip(SURVEY_REACH_SIGMAS * (s.sig_a_m + (s.sig_b_m - s.sig_a_m) * f), s.tol0_m,
                              cfg.axis_tolerance_m))
        try:
            c2, rk, n_on = _profile_circle(s.sw[m], s.prior, replace(cfg_r, axis_tolerance_m=tol_k + (
                cfg_r.axis_tolerance_m - cfg.axis_tolerance_m)))
        except FitError:
            continue
        if n_on >= cfg.chunk_min_circle_bins:
            chunk.append((0.5 * (edges[k] + edges[k + 1]) - L / 2, c2[0], c2[1], rk, n_on / tol_k ** 2))
    if not chunk:
        raise FitError(f"log {log_id!r}: no cylinder of radius {cfg.min_radius_m}-{cfg.max_radius_m} m "
                       "near its GNSS axis fits the scan; the log is hidden, outside the scanned area, "
                       "or its endpoints are wrong")
    return np.asarray(chunk, dtype=np.float64)


def _initial_axis(ch: np.ndarray, s: _SearchRegion) -> np.ndarray:
    """A line through the chunk centres (robust where an end is imprecise): the cylinder's start
    parameters [shift e1, shift e2, tilt e1, tilt e2, radius, radius slope]."""
    cfg = s.cfg
    band = max(cfg.chunk_line_band_m, CHUNK_LINE_MIN_TOLERANCES * cfg.profile_tolerance_m)
    keep = np.ones(len(ch), bool)
    if len(ch) >= MIN_CONSENSUS_CHUNKS and max(s.sig_a_m, s.sig_b_m) > IMPRECISE_SIGMA_RATIO * cfg.gnss_sigma_m:
        # an imprecise (RTK float) end: the line through two chunk centres that most chunks
        # (weighted) agree with, so chunks that latched onto a neighbour or the ground near the
        # imprecise end do not bend the axis
        best_score = -1.0
        for i in range(len(ch)):
            for j in range(i + 1, len(ch)):
                dt_ = ch[j, 0] - ch[i, 0]
                if abs(dt_) < cfg.chunk_line_min_span_m:
                    continue
                slope = (ch[j, 1:3] - ch[i, 1:3]) / dt_
                pred = ch[i, 1:3][None, :] + np.outer(ch[:, 0] - ch[i, 0], slope)
                ok = np.linalg.norm(ch[:, 1:3] - pred, axis=1) < band
                score = float(ch[ok, 4].sum())
                if score > best_score:
                    best_score, keep = score, ok
    coef = np.zeros((2, 2))  # [s0, s1], [w0, w1]
    for _ in range(INITIAL_AXIS_ROUNDS):
        if keep.sum() >= 2 and np.ptp(ch[keep, 0]) > cfg.chunk_line_min_span_m:
            A = np.column_stack([np.ones(keep.sum()), ch[keep, 0]])
            wts = np.sqrt(ch[keep, 4])
            for j, col in enumerate((1, 2)):
                coef[j], *_ = np.linalg.lstsq(A * wts[:, None], ch[keep, col] * wts, rcond=None)
        else:
            coef[:, 0] = np.median(ch[keep, 1:3], axis=0)
            coef[:, 1] = 0.0
        pred = coef[:, 0][None, :] + np.outer(ch[:, 0], coef[:, 1])
        dev = np.linalg.norm(ch[:, 1:3] - pred, axis=1)
        new_keep = dev < band
        if new_keep.sum() == 0 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    r0 = float(np.median(ch[keep, 3])) if keep.any() else float(np.median(ch[:, 3]))
    return np.array([coef[0, 0], coef[1, 0], coef[0, 1], coef[1, 1], r0, 0.0])


class _CylinderModel:
    """The cylinder of :func:`_fit_cylinder` about the survey axis' midpoint: parameters
    [shift e1, shift e2, tilt e1, tilt e2, radius, radius slope], the points on its visible top, and
    its residuals (distances from the surface, then the weak ties of its ends to the survey)."""

    def __init__(self, P: np.ndarray, s: _SearchRegion):
        self.s, self.cfg, self.L = s, s.cfg, s.length_m
        self.mid = s.a + s.u0 * (s.length_m / 2)
        self.prior_mid = np.array([s.prior[0], s.prior[1]])
        self.P, self.Pc = P, P[s.cand]
        cfg = s.cfg
        self.w_a, self.w_b = cfg.loss_scale_m / s.sig_a_m, cfg.loss_scale_m / s.sig_b_m
        self.vertical = cfg.top_surface_vertical_prior_weight if cfg.endpoint_ref == "top_surface" else 1.0

    def axis(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = self.s
        u = s.u0 + x[2] * s.e1 + x[3] * s.e2
        return x[0] * s.e1 + x[1] * s.e2, u / np.linalg.norm(u)

    def select(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Candidates on the visible top of cylinder ``x``, away from its flanks."""
        cfg = self.cfg
        c, u = self.axis(x)
        f1, f2 = _frame(u)
        d = self.Pc - (self.mid + c)
        tt = d @ u
        perp = d - np.outer(tt, u)
        rad = np.linalg.norm(perp, axis=1)
        # select by the angle from the top (tangential: unlike a cut on the lateral offset it
        # does not correlate with the radial noise, so it does not bias the radius)
        ang = np.arctan2(np.abs(perp @ f1), perp @ f2)
        ok = (np.abs(rad - (x[4] + x[5] * tt)) < cfg.inlier_band_m) & (ang < math.radians(cfg.max_angle_deg))
        out = self.s.cand[ok]
        if out.size > cfg.max_points_per_log:
            out = rng.choice(out, cfg.max_points_per_log, replace=False)
        return out

    def residuals(self, x: np.ndarray, Pm: np.ndarray) -> np.ndarray:
        c, u = self.axis(x)
        d = Pm - c
        tt = d @ u
        rad = np.linalg.norm(d - np.outer(tt, u), axis=1)
        # weak prior: the GNSS axis (ends at +-L/2) within each end's sigma; tilt priors at the ends
        h, pm, wa, wb = self.L / 2, self.prior_mid, self.w_a, self.w_b
        end_off = np.array([wb * (x[0] - pm[0] + x[2] * h), wb * (x[1] - pm[1] + x[3] * h),
                            wa * (x[0] - pm[0] - x[2] * h), wa * (x[1] - pm[1] - x[3] * h)])
        end_off[[1, 3]] *= self.vertical
        return np.concatenate([rad - (x[4] + x[5] * tt), end_off])

    def jacobian(self, x: np.ndarray, Pm: np.ndarray) -> np.ndarray:
        """d residuals / d x, analytically (the residuals are distances from a cylinder's surface)."""
        s = self.s
        v = s.u0 + x[2] * s.e1 + x[3] * s.e2
        nv = float(np.linalg.norm(v))
        u = v / nv
        d = Pm - (x[0] * s.e1 + x[1] * s.e2)
        tt = d @ u
        perp = d - np.outer(tt, u)
        rad = np.maximum(np.linalg.norm(perp, axis=1), 1e-12)
        p1, p2 = perp @ s.e1, perp @ s.e2
        J = np.zeros((len(Pm) + 4, 6))
        J[:-4, 0] = -p1 / rad + x[5] * float(u @ s.e1)
        J[:-4, 1] = -p2 / rad + x[5] * float(u @ s.e2)
        J[:-4, 2] = -(tt / rad + x[5]) * p1 / nv
        J[:-4, 3] = -(tt / rad + x[5]) * p2 / nv
        J[:-4, 4] = -1.0
        J[:-4, 5] = -tt
        h, wa, wb = self.L / 2, self.w_a, self.w_b
        J[-4, [0, 2]] = wb, wb * h
        J[-3, [1, 3]] = wb, wb * h
        J[-2, [0, 2]] = wa, -wa * h
        J[-1, [1, 3]] = wa, -wa * h
        J[[-3, -1]] *= self.vertical
        return J

    def solve(self, x0: np.ndarray, sel: np.ndarray, r_lo: float, r_hi: float,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Fit with the radius in [r_lo, r_hi], re-select the band around the fitted surface, refit."""
        from scipy.optimize import least_squares

        cfg = self.cfg
        slope = cfg.max_taper_per_m if cfg.fit_taper else 1e-9
        bounds = ([-np.inf] * 4 + [r_lo, -slope], [np.inf] * 4 + [r_hi, slope])
        x = x0
        for _ in range(FIT_ROUNDS):
            x = least_squares(self.residuals, x0, jac=self.jacobian, args=(self.P[sel] - self.mid,), loss="soft_l1",
                              f_scale=cfg.loss_scale_m, tr_solver="lsmr", bounds=bounds,
                              x_scale=[FIT_PARAMETER_SCALE] * 6,
                              max_nfev=cfg.max_fit_evaluations).x
            new_sel = self.select(x, rng)
            if new_sel.size < cfg.min_points:
                break
            sel, x0 = new_sel, x
        return x, sel


def _fit_cylinder(P: np.ndarray, s: _SearchRegion, x_init: np.ndarray, rng: np.random.Generator,
                  log_id: str) -> _Cylinder:
    """The cylinder (soft-L1 least squares, analytic Jacobian) through the points on its visible top,
    weakly tied to the survey's axis by each end's accuracy; the top band re-selected and refitted once.

    The radius stays within ``radius_window_m`` of the chunk profiles' (they see the flanks and the
    ground; the top arc alone hardly fixes the curvature). A fit that ends ON that window's edge
    disagrees with the profiles by more than the window, and the radius it gives is the edge, set by
    the profiles' 2.5 mm grid, not by the scan (a 20 cm log came out 18 or 19 cm by which grid step
    the profiles took). When the profiles' radius explains the top points about as well
    (``radius_profile_max_rms_rise``: the top arc cannot tell the two apart, as on stereo scans), the
    radius is the profiles' and only the axis is fitted; otherwise the top arc rules it out, and the
    edge stands."""
    cfg = s.cfg
    m = _CylinderModel(P, s)
    sel = m.select(x_init, rng)
    if sel.size < cfg.min_points:
        raise LogNotSeenError(f"log {log_id!r}: only {sel.size} scan points lie on a cylinder around its "
                              "GNSS axis; the log is hidden or outside the scanned area")
    r_prof = float(np.clip(x_init[4], cfg.min_radius_m + 1e-6, cfg.max_radius_m - 1e-6))
    r_lo = max(cfg.min_radius_m, r_prof - cfg.radius_window_m)
    r_hi = min(cfg.max_radius_m, r_prof + cfg.radius_window_m)
    x, sel_x = m.solve(np.r_[x_init[:4], r_prof, x_init[5]], sel, r_lo, r_hi, rng)
    on_edge = (x[4] - r_lo < RADIUS_EDGE_M and r_lo > cfg.min_radius_m) or \
        (r_hi - x[4] < RADIUS_EDGE_M and r_hi < cfg.max_radius_m)
    radius_source = "fit"
    if on_edge:
        xp, sel_p = m.solve(np.r_[x[:4], r_prof, 0.0], sel, r_prof - 1e-7, r_prof + 1e-7, rng)
        both = np.union1d(sel_x, sel_p)
        rms_fit, rms_prof = (float(np.sqrt(np.mean(m.residuals(v, P[both] - m.mid)[:-4] ** 2))) for v in (x, xp))
        if rms_prof <= rms_fit * (1.0 + cfg.radius_profile_max_rms_rise):
            x, sel_x, radius_source = xp, sel_p, "profiles"
    c, u = m.axis(x)
    Pm = P[sel_x] - m.mid
    return _Cylinder(x, sel_x, m.mid + c, u, m.residuals(x, Pm)[: len(sel_x)], radius_source)


def _end_radii(cyl: _Cylinder, tt_sel: np.ndarray, ta: float, tb: float, coverage: float, L: float,
               cfg: FitConfig) -> tuple[float, float, float]:
    """Radius at ends a and b, and the taper's significance: a taper is kept only when the radii of
    ``taper_section_m`` sections along the log (mean surface residual + fitted radius) change linearly
    by more than ``taper_min_significance`` standard errors of their own scatter (stereo errors are
    correlated over a section, so the scatter between sections, not between points, measures it)."""
    x = cyl.x
    if not cfg.fit_taper:
        return float(x[4]), float(x[4]), 0.0
    r_a = float(x[4] + x[5] * ta)
    r_b = float(x[4] + x[5] * tb)
    sec = np.floor((tt_sel + L / 2) / cfg.taper_section_m).astype(np.int64)
    ts, rs = [], []
    for k in np.unique(sec):
        m = sec == k
        if m.sum() >= cfg.taper_section_min_points:
            ts.append(float(np.mean(tt_sel[m])))
            rs.append(float(np.mean(x[4] + x[5] * tt_sel[m] + cyl.res[m])))
    taper_sig = 0.0
    if len(ts) >= TAPER_MIN_SECTIONS:
        A = np.column_stack([np.ones(len(ts)), ts])
        coef_r, *_ = np.linalg.lstsq(A, np.asarray(rs), rcond=None)
        resid = np.asarray(rs) - A @ coef_r
        dof = max(len(ts) - 2, 1)
        s2 = float(resid @ resid) / dof
        try:
            se = math.sqrt(max(s2 * np.linalg.inv(A.T @ A)[1, 1], 1e-12))
        except np.linalg.LinAlgError:
            se = math.inf
        taper_sig = abs(coef_r[1]) / se
    if taper_sig < cfg.taper_min_significance or coverage < cfg.taper_min_coverage:
        r_a = r_b = float(x[4] + x[5] * np.mean(tt_sel))
    return r_a, r_b, taper_sig


def fit_log(points: np.ndarray, end_a: Any, end_b: Any, cfg: FitConfig | None = None,
            log_id: str = "log", rng: np.random.Generator | None = None,
            sigma_a_m: float | None = None, sigma_b_m: float | None = None) -> CylinderFit:
    """Fit one log to scan points (pile frame) around its GNSS axis ``end_a`` → ``end_b``.

    ``sigma_a_m``/``sigma_b_m``: 1-sigma accuracy of each GNSS point (default
    ``cfg.gnss_sigma_m``). An imprecise point (an RTK float fix) widens the search around the
    axis, weakens the prior, and its end is taken from the scan (the extent of the log's points
    along the fitted axis) when the scan shows it better than the point does.

    Steps: :func:`_search_region` (the points near the survey's axis), :func:`_chunk_circles`
    (cross-section circles along it), :func:`_initial_axis` (a line through their centres),
    :func:`_fit_cylinder` (least squares on the visible top), :func:`_end_radii` (taper), then the ends.
    Raises :class:`FitError` naming ``log_id`` when the scan does not cover the log.
    """
    cfg = cfg or FitConfig()
    rng = rng or np.random.default_rng(cfg.seed)
    P, s = _search_region(points, end_a, end_b, cfg, log_id, sigma_a_m, sigma_b_m)
    cfg, a, b, L = s.cfg, s.a, s.b, s.length_m
    ch = _chunk_circles(s, log_id)
    cyl = _fit_cylinder(P, s, _initial_axis(ch, s), rng, log_id)
    centre, u, sel = cyl.centre, cyl.u, cyl.sel
    rms = float(np.sqrt(np.mean(cyl.res ** 2)))
    tt_sel = (P[sel] - centre) @ u
    # coverage in coverage_bin_m bins over the length
    nb = max(1, int(round(L / cfg.coverage_bin_m)))
    hist, _ = np.histogram(tt_sel, bins=nb, range=(-L / 2, L / 2))
    coverage = float(np.mean(hist > 0))
    # radius at the ends (GNSS a at t = -L/2 about the fitted centre)
    ta = float((a - centre) @ u)
    tb = float((b - centre) @ u)
    r_a, r_b, taper_sig = _end_radii(cyl, tt_sel, ta, tb, coverage, L, cfg)
    proj_a, proj_b = centre + ta * u, centre + tb * u
    res_a, res_b = float(np.linalg.norm(a - proj_a)), float(np.linalg.norm(b - proj_b))
    end_source = ["gnss", "gnss"]
    if s.ext_a_m or s.ext_b_m:  # an imprecise end: where the scan shows the log end, if it does
        t_in = (P[sel] - centre) @ u
        lo_q, hi_q = cfg.scan_end_percentile, 100.0 - cfg.scan_end_percentile
        if s.ext_a_m and t_in.size:
            t_lo = float(np.percentile(t_in, lo_q))
            if abs(t_lo - ta) < SURVEY_REACH_SIGMAS * s.sig_a_m:
                proj_a, end_source[0] = centre + t_lo * u, "scan"
        if s.ext_b_m and t_in.size:
            t_hi = float(np.percentile(t_in, hi_q))
            if abs(t_hi - tb) < SURVEY_REACH_SIGMAS * s.sig_b_m:
                proj_b, end_source[1] = centre + t_hi * u, "scan"
    if cfg.axis_source == "fit":
        ends = np.stack([proj_a, proj_b])
    elif cfg.endpoint_ref == "top_surface":
        r_mean = 0.5 * (r_a + r_b)
        ends = np.stack([a, b]) - r_mean * s.e2
    else:
        ends = np.stack([a, b])
    return CylinderFit(centre=centre, axis=u, ends=ends, radius_a_m=max(r_a, cfg.min_radius_m),
                       radius_b_m=max(r_b, cfg.min_radius_m), n_points=int(sel.size), rms_m=rms, coverage=coverage,
                       residual_a_m=res_a, residual_b_m=res_b, end_source=tuple(end_source),
                       taper_significance=taper_sig, radius_source=cyl.radius_source, inliers=sel)


def log_spec_from_fit(f: CylinderFit, cfg: FitConfig) -> tuple[LogSpec, bool]:
    """A :class:`LogSpec` from :func:`fit_log`'s result (butt = the thicker end) and whether
    end ``b`` became the butt."""
    ra, rb = f.radius_a_m, f.radius_b_m
    ends = f.ends
    taper = cfg.fit_taper and abs(ra - rb) * 2 >= cfg.taper_min_m
    swapped = bool(taper and rb > ra)
    if taper:
        d_butt, d_top = 2 * max(ra, rb), 2 * min(ra, rb)
    else:
        d_butt, d_top = ra + rb, None
    butt, top = (ends[1], ends[0]) if swapped else (ends[0], ends[1])
    d_butt = float(np.clip(d_butt, MIN_LOG_DIAMETER_M, MAX_LOG_DIAMETER_M))
    if d_top is not None:
        d_top = float(np.clip(d_top, MIN_TOP_DIAMETER_M, d_butt))
    return LogSpec.from_endpoints(butt, top, d_butt, d_top), swapped
