"""Logs the scan shows only in part, or not at all.

A log seen only in part (its fits stray from its survey axis, or lie inside a neighbour) gets a circle
through its visible top arc whose centre stays within two ``gnss_sigma_m`` of the survey's axis (a shift
and a tilt; :func:`fit_radius_on_axis`). A log with no scan points on it but scan points standing over it
(:func:`_covered_by_others`) lies hidden under others: it is placed on its survey axis, as thick as the
gap between the ground and the logs over it (:func:`_sandwiched_log`), or as the pile's typical log
(:func:`_survey_log`)."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from reconstruct.errors import FitError, LogNotSeenError
from reconstruct.fitting.cylinder import CylinderFit
from reconstruct.fitting.ends import MIN_LOG_LENGTH_M
from reconstruct.fitting.fit_config import FitConfig
from reconstruct.fitting.geometry import _along_across, _underside_z
from reconstruct.fitting.profiles import _frame
from synth.scene.pile import LogSpec

# the nearest surface seen from above: this percentile of the top points' distances from the survey axis [%]
TOP_PERCENTILE = 25
# the top arc: points from this far inside that surface to this far beyond it (a log lying on this one is a
# whole diameter farther) [m]
ARC_INSIDE_M = 0.03
ARC_BEYOND_M = 0.06
# the arc's centre stays within this many gnss_sigma_m of the survey's axis (a shift and a tilt) [-]
PARTIAL_AXIS_SIGMAS = 2
# the ground under a hidden log's end: this low percentile of at least this many scan points near it [%, -]
GROUND_PERCENTILE = 10
MIN_END_GROUND_POINTS = 10
# a hidden log's gap to the logs over it is sampled this often along its axis [m]
GAP_SAMPLE_STEP_M = 0.05
# a hidden log between the ground and the logs over it agrees with the surveyed heights within this many
# gnss_sigma_m [-]
HEIGHT_AGREEMENT_SIGMAS = 3
# scan points over a survey axis are counted in bins this long [m]
COVER_BIN_M = 0.1
# the arc's circle starts this far inside its radius bounds (as shares of them) [-]
START_ABOVE_MIN, START_BELOW_MAX = 1.01, 0.99


def fit_radius_on_axis(points: np.ndarray, end_a: Any, end_b: Any, cfg: FitConfig | None = None,
                       log_id: str = "log") -> CylinderFit:
    """Radius of a log whose axis is taken from its GNSS points, from the scan points on its
    visible top (within ``max_angle_deg`` of straight up): for a log lying mostly under another,
    whose free fit would wander onto the upper one. Returns a :class:`CylinderFit` (the ends are
    the GNSS points). Raises :class:`FitError` naming ``log_id`` when too few points show it."""
    cfg = cfg or FitConfig()
    a, b = np.asarray(end_a, dtype=np.float64), np.asarray(end_b, dtype=np.float64)
    L = float(np.linalg.norm(b - a))
    if L < cfg.min_survey_length_m:
        raise FitError(f"log {log_id!r}: its two GNSS points are only {L * 100:.1f} cm apart")
    u = (b - a) / L
    P = np.asarray(points, dtype=np.float64)
    rel = P - a
    t = rel @ u
    q = rel - np.outer(t, u)
    r = np.linalg.norm(q, axis=1)
    e1, e2 = _frame(u)  # e2: up-ish, perpendicular to the axis
    ang = np.arctan2(np.abs(q @ e1), q @ e2)
    on = ((t > cfg.end_margin_m) & (t < L - cfg.end_margin_m) & (r > cfg.min_radius_m)
          & (r < cfg.max_radius_m) & (ang < math.radians(cfg.max_angle_deg)))
    if on.sum() < cfg.min_points:
        raise LogNotSeenError(f"log {log_id!r}: only {int(on.sum())} scan points show its top near its GNSS axis; "
                              "the log is hidden under others or outside the scanned area")
    # the nearest surface seen from above: the lower quartile of the distances (points beyond are
    # whatever lies on or beside it)
    rad = float(np.percentile(r[on], TOP_PERCENTILE))
    # the survey's axis is a few cm off (RTK noise), which spreads the top's distances by as
    # much: a circle through the top arc, its centre within two sigma of the axis (a shift and a
    # tilt), finds the radius unbiased. Points a few cm beyond the nearest surface are on it
    # still; a log lying on this one is a whole diameter farther
    from scipy.optimize import least_squares

    arc = np.flatnonzero(on & (r > rad - ARC_INSIDE_M) & (r < rad + ARC_BEYOND_M))
    q1, q2, tau = q[arc] @ e1, q[arc] @ e2, t[arc] / L - 0.5
    lim = PARTIAL_AXIS_SIGMAS * cfg.gnss_sigma_m

    def off_circle(x):
        return np.hypot(q1 - x[0] - x[2] * tau, q2 - x[1] - x[3] * tau) - x[4]

    r0 = float(np.clip(rad, cfg.min_radius_m * START_ABOVE_MIN, cfg.max_radius_m * START_BELOW_MAX))
    x = least_squares(off_circle, [0.0, 0.0, 0.0, 0.0, r0],
                      bounds=([-lim, -lim, -lim, -lim, cfg.min_radius_m], [lim, lim, lim, lim, cfg.max_radius_m]),
                      loss="soft_l1", f_scale=cfg.partial_loss_scale_m).x
    a = a + (x[0] - x[2] / 2) * e1 + (x[1] - x[3] / 2) * e2
    b = b + (x[0] + x[2] / 2) * e1 + (x[1] + x[3] / 2) * e2
    rad = float(x[4])
    res = np.abs(off_circle(x))
    sel = arc[res < cfg.inlier_band_m]
    tt = t[sel]
    nb = max(1, int(round(L / cfg.coverage_bin_m)))
    hist, _ = np.histogram(tt, bins=nb, range=(0.0, L))
    rms = float(np.sqrt(np.mean(res[res < cfg.inlier_band_m] ** 2))) if sel.size else math.nan
    return CylinderFit(centre=0.5 * (a + b), axis=(b - a) / np.linalg.norm(b - a), ends=np.stack([a, b]),
                       radius_a_m=rad, radius_b_m=rad, n_points=int(sel.size), rms_m=rms,
                       coverage=float(np.mean(hist > 0)), residual_a_m=0.0, residual_b_m=0.0, inliers=sel)


def _survey_log(end_a: Any, end_b: Any, diameter_m: float, cfg: FitConfig, log_id: str = "?") -> LogSpec:
    """A log from its GNSS points alone, of ``diameter_m`` (the axis one radius under
    ``top_surface`` points); :class:`FitError` naming ``log_id`` when its ends (the survey points as
    matching and end placement left them) lie closer together than the shortest log the pile model holds."""
    a, b = np.asarray(end_a, dtype=float), np.asarray(end_b, dtype=float)
    if float(np.linalg.norm(b - a)) < MIN_LOG_LENGTH_M:
        raise FitError(f"log {log_id!r} is not seen in the scan, and the ends its GNSS points were placed at lie "
                       f"{float(np.linalg.norm(b - a)):.2f} m apart: shorter than any log ({MIN_LOG_LENGTH_M} m). Its "
                       f"points do not fit the scan (one may not be at its end or carry another log's id): re-measure "
                       f"both ends of {log_id!r}")
    if cfg.endpoint_ref == "top_surface":
        a, b = a - [0.0, 0.0, diameter_m / 2], b - [0.0, 0.0, diameter_m / 2]
    return LogSpec.from_endpoints(a, b, diameter_m)


def _sandwiched_log(P: np.ndarray, end_a: Any, end_b: Any, over: Sequence[LogSpec], cfg: FitConfig,
                    ground_radius_m: float = 0.4) -> LogSpec | None:
    """A hidden log lying on the ground under logs ``over``: its radius is half the gap between
    the ground (the low ``GROUND_PERCENTILE`` of the scan points within ``ground_radius_m`` of each GNSS end) and
    the lowest underside over its axis; its axis one radius above the ground, under the GNSS
    points. ``None`` when nothing lies over it or the result disagrees with the surveyed heights
    by more than three ``gnss_sigma_m`` (then the survey's heights stand) or when its points lie
    closer together across the ground than the shortest log (:func:`_survey_log` then refuses them)."""
    a, b = np.asarray(end_a, dtype=float), np.asarray(end_b, dtype=float)
    if float(np.linalg.norm(b[:2] - a[:2])) < MIN_LOG_LENGTH_M:  # no log lies that short: the survey's axis decides
        return None
    ground = []
    for e in (a, b):
        near = np.linalg.norm(P[:, :2] - e[:2], axis=1) < ground_radius_m
        if near.sum() < MIN_END_GROUND_POINTS:
            return None
        ground.append(float(np.percentile(P[near, 2], GROUND_PERCENTILE)))
    t = np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(b[:2] - a[:2]) / GAP_SAMPLE_STEP_M) + 1))
    xy = a[:2] + np.outer(t, b[:2] - a[:2])
    gap = _underside_z(over, xy) - (ground[0] + t * (ground[1] - ground[0]))
    gap = gap[np.isfinite(gap)]
    if not gap.size or float(gap.min()) < 2 * cfg.min_radius_m:
        return None
    r = float(min(gap.min() / 2, cfg.max_radius_m))
    if cfg.endpoint_ref == "top_surface":
        z_a, z_b = a[2] - r, b[2] - r
    else:
        z_a, z_b = a[2], b[2]
    limit = HEIGHT_AGREEMENT_SIGMAS * cfg.gnss_sigma_m
    if abs(ground[0] + r - z_a) > limit or abs(ground[1] + r - z_b) > limit:
        return None
    return LogSpec.from_endpoints((a[0], a[1], ground[0] + r), (b[0], b[1], ground[1] + r), 2 * r)


def _covered_by_others(P: np.ndarray, end_a: Any, end_b: Any, cfg: FitConfig, lateral_m: float = 0.10,
                       above_m: float = 0.05, share: float = 0.5) -> bool:
    """Whether scan points stand over the GNSS axis ``end_a`` → ``end_b`` (within ``lateral_m``
    of it seen from above, ``above_m`` or more over it) along at least ``share`` of its length
    (10 cm bins): something lies on the log. Else a log without points on it is not in the scan."""
    a, b = np.asarray(end_a, dtype=float), np.asarray(end_b, dtype=float)
    t, lat = _along_across(P[:, :2], a, b)
    over = (t > 0.0) & (t < 1.0) & (lat < lateral_m) & (P[:, 2] > a[2] + t * (b[2] - a[2]) + above_m)
    nb = max(1, int(round(float(np.linalg.norm(b[:2] - a[:2])) / COVER_BIN_M)))
    hist, _ = np.histogram(t[over], bins=nb, range=(0.0, 1.0))
    return bool((hist > 0).mean() >= share)
