"""The joint estimator's survey-to-scan matching (issue 37, step 2): one assignment
(:func:`scipy.optimize.linear_sum_assignment`) of surveyed logs to the logs the scan shows, with explicit
costs for a surveyed log the scan shows nothing of (hidden) and a scan log no surveyed log takes (missed).

A pair's cost is the negative log-likelihood of the surveyed log's points on the scan log's axis, each point a
Gaussian (its accuracy, the scan pose's and the axis's) mixed with an outlier component
(:class:`~reconstruct.fitting.joint_config.JointConfig` ``outlier_prior``, ``outlier_spread_m``), so a wrong
point costs a bounded amount instead of being gated by a rule. A point inside the ridge (the ridge running on
past it) costs a mixture of the ridge ending there and the ridge running on onto something in line
(:func:`run_on_nats`). Its zero is a perfect point: the costs of the hidden and missed choices are in the same
units (nats).

The scan pose's error is one offset shared by every point: the assignment is made at the likeliest offset under
its prior (:mod:`reconstruct.fitting.joint_pose`), reported as ``pose_offset_m``.

With the scan's own evidence about its ridges (:mod:`reconstruct.fitting.joint_ridge`, joint revision 15): a
ridge whose radius, within its own sigma, no log has is dearer to take and cheaper to leave unexplained, and a
pair pays for the open ground the surveyed log would lie over, laid on the ridge (:func:`coverage_nats`).
A point is measured against the line through the ridge's chunk profiles (joint revision 16), as sure as that
line predicts the axis where the point lies. The log is laid in the direction the ridge's axis and its survey
points' line support, each by its sigma (:func:`laid_direction`, joint revision 18).

An assignment that makes a different pile (a scan log kept or dropped, a surveyed log hidden instead of seen)
within ``ambiguity_nats`` of the best is a warning naming the log and the points to re-measure (the likelier
pile is placed), or with ``ambiguity_is_error`` an :class:`~reconstruct.fitting.matching.AmbiguousSurveyError`;
one that only changes which ids the same logs get is the same pile. A surveyed log left hidden with fewer than two
points cannot be placed: its point is reported as an outlier and the log is left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.special import log_ndtr

from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_pose import pose_offset, shifted
from reconstruct.fitting.joint_ridge import (ChunkProfile, HeightRaster, RidgeEvidence, RidgeLine, not_one_log_nats,
                                             open_length_m)
from reconstruct.fitting.matching import Match, _ambiguity
from reconstruct.fitting.scan_logs import PROFILE_CENTRE_TOLERANCE_M, PROFILE_PRIOR_DEPTH_M, ScanLog
from reconstruct.fitting.survey_points import SurveyEnd

IMPOSSIBLE = 1e9  # the assignment's cost of a pair that cannot be chosen [nats]
CHI2_CAP = 1e4  # squared normalised distances are capped here before the exponential (underflow) [-]


@dataclass
class JointMatching:
    """The assignment: each surveyed log's match (scan index or None), the scan logs left over, and the
    surveyed logs left out with why (a hidden log of one point: that point is an outlier)."""

    matches: dict[str, Match]
    unmatched: list[int]
    dropped: dict[str, str]
    cost_nats: float
    outliers: dict[str, set[int]]  # per matched log, its points (0: a, 1: b) likelier outliers than its ends
    ambiguous: list[str]  # one line per surveyed log another assignment, making another pile, explains as well
    pose_offset_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) the scan's offset from the
    #   survey the assignment was made at (site frame; added to the survey points) [m]


def point_cost(e: SurveyEnd, log: ScanLog, at_start: bool, cfg: JointConfig, fcfg: FuseConfig,
               outlier_prob: bool = False, line: RidgeLine | None = None, run_on_evidence: float = 0.0) -> float:
    """-log of a survey point's likelihood as end ``at_start`` (else end) of ``log``, relative to a perfect point:
    the robust mixture of its Gaussian (across the axis, vertically, and inside the seen ridge) and the outlier
    (``outlier_prob``: the posterior probability of the outlier component instead). With ``line`` (the ridge's
    chunk line, :class:`~reconstruct.fitting.joint_ridge.RidgeLine`), across and vertically against that line,
    its prediction's variance added (and its density's lower peak paid: a vaguer prediction explains less).
    ``run_on_evidence``: what the ridge's chunks past the point say for its running on onto something else
    [nats] (:func:`run_on_evidence_nats`), taken off the run-on's cost (never below a ridge ending there)."""
    p0, p1 = log.start_m, log.end_m
    d = p1[:2] - p0[:2]
    L = max(float(np.linalg.norm(d)), 1e-6)
    u = d / L
    q = e.position_m
    t = float((q[:2] - p0[:2]) @ u)
    sh = math.sqrt(e.sigma_h_m ** 2 + cfg.pose_sigma_m ** 2 + fcfg.axis_sigma_m ** 2)
    sv = math.sqrt(e.sigma_v_m ** 2 + cfg.pose_sigma_m ** 2 + fcfg.radius_sigma_m ** 2)
    lat_m = float((q[:2] - p0[:2]) @ np.array([-u[1], u[0]]))
    frac = float(np.clip(t / L, 0.0, 1.0))  # past the ridge's ends its height is the end's
    tc = L * frac
    vert_m = float(q[2]) - float(p0[2] + (p1[2] - p0[2]) * frac)
    sh_lat, sv_line, spread = sh, sv, 0.0
    if line is not None and cfg.ridge_chunk_line:
        lat_m -= line.lateral_m(t)
        vert_m -= line.height_m(tc)
        sh_lat = math.sqrt(sh * sh + line.lateral_var_m2(t))
        sv_line = math.sqrt(sv * sv + line.height_var_m2(tc))
        spread = 2.0 * (math.log(sh_lat / sh) + math.log(sv_line / sv))
    lat, vert = lat_m / sh_lat, vert_m / sv_line
    # a log's end is at or past the visible ridge's end: a point well inside the ridge is off its end, or the
    # ridge runs on past it onto something in line
    inside = max(0.0, t) if at_start else max(0.0, L - t)
    inside = max(0.0, min(inside, L) - cfg.ridge_overrun_m)
    # past the ridge's end the log runs on unseen (under others) to the point: the farther, the less likely
    beyond = max(0.0, -t) if at_start else max(0.0, t - L)
    run_on = max(0.0, run_on_nats(inside, sh, cfg) - run_on_evidence) if inside > 0 else 0.0
    chi2 = min(lat * lat + vert * vert + spread + 2.0 * run_on
               + 2.0 * cfg.unseen_nats_per_m * max(0.0, beyond - cfg.ridge_overrun_m), CHI2_CAP)
    eps = cfg.outlier_prior
    z_in, z_out = (1 - eps) * math.exp(-0.5 * chi2), eps * math.exp(-_kappa(sh, sv, cfg))
    return float(z_out / (z_in + z_out)) if outlier_prob else float(-math.log(z_in + z_out))


def laid_direction(ends: tuple[SurveyEnd, SurveyEnd], log: ScanLog, cfg: JointConfig) -> np.ndarray:
    """The unit 2-D direction the surveyed log is laid in on ``log``'s ridge (within 90 deg of its axis): with
    ``laid_survey_direction`` the inverse-variance weighted angle of the ridge's axis (``ridge_direction_sigma_m``
    over its seen length: a ridge seen over nothing says nothing) and the line through the two survey points
    (their sigmas across that line, in quadrature, over their distance; the scan pose's offset is shared and
    cancels); else the ridge's axis itself."""
    p0 = log.start_m[:2]
    u = (log.end_m[:2] - p0) / max(log.length_m, 1e-6)
    d = ends[1].position_m[:2] - ends[0].position_m[:2]
    dist_m = float(np.linalg.norm(d))
    if not cfg.laid_survey_direction or dist_m <= 0.0:
        return u
    s = d / dist_m if float(d @ u) >= 0.0 else -d / dist_m
    across = np.array([-s[1], s[0], 0.0])
    var_survey = ends[0].sigma_along(across) ** 2 + ends[1].sigma_along(across) ** 2  # [m^2] over dist_m^2
    var_ridge = (cfg.ridge_direction_sigma_m / log.seen_m) ** 2 if log.seen_m > 0.0 else math.inf  # [rad^2]
    # the survey's share: 1 / var_survey_rad over the sum of both inverse variances
    share = 1.0 if math.isinf(var_ridge) else dist_m ** 2 * var_ridge / (dist_m ** 2 * var_ridge + var_survey)
    theta = share * math.atan2(u[0] * s[1] - u[1] * s[0], float(u @ s))
    if theta == 0.0:
        return u
    c, sn = math.cos(theta), math.sin(theta)
    return np.array([c * u[0] - sn * u[1], sn * u[0] + c * u[1]])


@dataclass(frozen=True)
class _Laying:
    """The surveyed log laid on a ridge: along the line ``origin + s * w`` (2-D, ``s`` in metres, the ridge's
    height carried along it), from ``lo`` to ``hi``, the ridge's footprint (its span past ``ridge_overrun_m``,
    its radius across) covering it from ``on_lo`` to ``on_hi``."""

    line: ScanLog
    lo: float
    hi: float
    on_lo: float
    on_hi: float


def _span(a: float, b: float, lo: float, hi: float) -> tuple[float, float]:
    """The s where ``a + b s`` lies in [lo, hi] (empty: lo > hi)."""
    if abs(b) < 1e-12:
        return (-math.inf, math.inf) if lo <= a <= hi else (math.inf, -math.inf)
    s0, s1 = (lo - a) / b, (hi - a) / b
    return min(s0, s1), max(s0, s1)


def _layings(ends: tuple[SurveyEnd, SurveyEnd], log: ScanLog, cfg: JointConfig) -> list[_Laying]:
    """The surveyed log laid in :func:`laid_direction` through the ridge's middle (the ridge is where the scan
    sees it), its surveyed length long, from each of its points' places on that line toward the other's (the
    ridge's middle where they coincide): two layings. Along the ridge's axis (revision 17) ``s`` is the distance
    along the axis from the ridge's start."""
    p0 = log.start_m[:2]
    L = max(log.length_m, 1e-6)
    u = (log.end_m[:2] - p0) / L
    w = laid_direction(ends, log, cfg)
    c, sn = float(w @ u), float(w @ np.array([-u[1], u[0]]))
    origin = p0 + 0.5 * L * (u - w)  # the laid line's s = 0: the ridge's middle at s = L / 2
    slope = (float(log.end_m[2]) - float(log.start_m[2])) / L  # the ridge's rise per metre along its axis
    z0 = float(log.start_m[2]) + slope * 0.5 * L * (1.0 - c)
    line = log if w is u else ScanLog(np.array([origin[0], origin[1], z0]),
                                      np.array([origin[0] + w[0], origin[1] + w[1], z0 + slope * c]),
                                      log.radius_m, log.seen_m, log.strength_per_m)
    # the ridge's footprint on the laid line: its span past ridge_overrun_m along the axis, its radius across
    # (both hold the ridge's middle, s = L / 2, that the line runs through: never empty)
    along = _span(0.5 * L * (1.0 - c), c, -cfg.ridge_overrun_m, L + cfg.ridge_overrun_m)
    across = _span(-0.5 * L * sn, sn, -log.radius_m, log.radius_m)
    on_lo, on_hi = max(along[0], across[0]), min(along[1], across[1])
    length = float(np.linalg.norm(ends[1].position_m[:2] - ends[0].position_m[:2]))
    t = [float((e.position_m[:2] - origin) @ w) for e in ends]
    out = []
    for n in (0, 1):
        toward = t[1 - n] - t[n] if t[1 - n] != t[n] else 0.5 * L - t[n]  # toward the other point (the middle)
        lo, hi = (t[n], t[n] + length) if toward >= 0 else (t[n] - length, t[n])
        out.append(_Laying(line, lo, hi, on_lo, on_hi))
    return out


def laid_nats(ends: tuple[SurveyEnd | None, SurveyEnd | None], log: ScanLog, raster: HeightRaster | None,
              cfg: JointConfig) -> float:
    """What the surveyed log placed on ``log``'s ridge costs along its length [nats], whichever of its two
    layings (:func:`_layings`, in :func:`laid_direction`) is cheaper: the open ground under it off the ridge's
    footprint, ``coverage_nats_per_m`` a metre, and (with ``laid_unseen``) the rest of its run off it that no
    point of it reaches, ``unseen_nats_per_m`` a metre (a point past the ridge's end pays for the
    run to it in its own cost, :func:`point_cost`), with ``laid_length_sigma`` priced over the surveyed
    length's error (:func:`unseen_run_nats`). Both are outside the points' outlier mixture: a point far
    off the ridge (an outlier) still says the log is that long, so a log on a short scrap pays for the length
    the scan does not show it (open ground, or nothing). 0 for a log of one point."""
    if ends[0] is None or ends[1] is None or not (cfg.laid_unseen or (cfg.ridge_coverage and raster is not None)):
        return 0.0
    reached = _points_past_m(ends, log, cfg.ridge_overrun_m) if cfg.laid_unseen else 0.0
    sigma_m = _length_sigma_m(ends, log, cfg) if cfg.laid_unseen else 0.0
    best = math.inf
    for lay in _layings(ends, log, cfg):
        lo, hi = lay.lo, lay.hi
        open_m = 0.0
        if cfg.ridge_coverage and raster is not None:
            open_m = (open_length_m(lay.line, lo, min(hi, lay.on_lo), raster, cfg)
                      + open_length_m(lay.line, max(lo, lay.on_hi), hi, raster, cfg))
        cost = cfg.coverage_nats_per_m * open_m
        if cfg.laid_unseen:
            past = max(0.0, min(hi, lay.on_lo) - lo) + max(0.0, hi - max(lo, lay.on_hi))
            cost += unseen_run_nats(past - open_m - reached, sigma_m, cfg.unseen_nats_per_m)
        best = min(best, cost)
    return best


def _length_sigma_m(ends: tuple[SurveyEnd, SurveyEnd], log: ScanLog, cfg: JointConfig) -> float:
    """The surveyed length's 1 sigma along ``log``'s axis [m] (``laid_length_sigma``; else 0, the length as
    exact): the two points' sigmas along it combined. The scan pose's error is shared by both points and
    cancels in their distance."""
    if not cfg.laid_length_sigma:
        return 0.0
    d = log.end_m[:2] - log.start_m[:2]
    u = np.array([d[0], d[1], 0.0]) / max(float(np.linalg.norm(d)), 1e-6)
    return math.hypot(ends[0].sigma_along(u), ends[1].sigma_along(u))


def unseen_run_nats(unseen_m: float, sigma_m: float, rate_per_m: float) -> float:
    """What a laid log's unseen run of ``unseen_m`` costs at ``rate_per_m`` [nats] when the log's length is
    uncertain by ``sigma_m`` (its true length the surveyed one less e, e ~ N(0, sigma_m^2)): -log E[exp(-rate *
    max(0, unseen_m - e))], relative to a run of 0 (a pair whose points reach its laid ends, where an error in
    the length moves the points with it and no run is unseen whatever it is). In closed form,
    E[...] = P(e >= x) + exp(-rate x + rate^2 sigma^2 / 2) Phi((x - rate sigma^2) / sigma). Exactly
    ``rate_per_m * unseen_m`` at ``sigma_m`` 0, never more, 0 for no run, and as the length grows vague it
    tends to 0 (the log may as well be shorter)."""
    if unseen_m <= 0.0:
        return 0.0
    if sigma_m <= 0.0:
        return rate_per_m * unseen_m

    def log_mean(x: float) -> float:
        """log E[exp(-rate max(0, x - e))]."""
        return float(np.logaddexp(log_ndtr(-x / sigma_m), -rate_per_m * x + 0.5 * (rate_per_m * sigma_m) ** 2
                                  + log_ndtr((x - rate_per_m * sigma_m ** 2) / sigma_m)))

    return max(0.0, log_mean(0.0) - log_mean(unseen_m))


def _points_past_m(ends: tuple[SurveyEnd, SurveyEnd], log: ScanLog, overrun_m: float) -> float:
    """How far past the ridge's ends (beyond ``overrun_m``) the log's points lie, together [m]: the run they
    pay for themselves."""
    p0 = log.start_m[:2]
    L = max(log.length_m, 1e-6)
    u = (log.end_m[:2] - p0) / L
    t = [float((e.position_m[:2] - p0) @ u) for e in ends]
    return sum(max(0.0, -x - overrun_m) + max(0.0, x - L - overrun_m) for x in t)


def coverage_nats(ends: tuple[SurveyEnd | None, SurveyEnd | None], log: ScanLog, raster: HeightRaster | None,
                  cfg: JointConfig) -> float:
    """The open ground alone (:func:`laid_nats` without the unseen run) [nats]."""
    return laid_nats(ends, log, raster, replace(cfg, laid_unseen=False))


def run_on_evidence_nats(e: SurveyEnd, other: SurveyEnd, log: ScanLog, at_start: bool,
                         chunks: Sequence[ChunkProfile], cfg: JointConfig, fcfg: FuseConfig) -> float:
    """What the ridge's chunks past survey point ``e`` (end ``at_start`` of ``log``; more than
    ``ridge_overrun_m`` past it, inside the ridge) say for the ridge running on onto something else rather than
    the log running on [nats]: per chunk, the log-likelihood ratio of its circle's centre anywhere in the
    profile's centre search (uniform over its window) against its lying on the line through the log's two points
    (a Gaussian of ``e``'s sigmas, the search window's share of it renormalised - a log's circle is only found
    inside the window - mixed with ``outlier_prior`` of the uniform: a chunk fitted astray), summed. Positive
    where the chunks leave the log's line, negative where they follow it, about 0 where the points' sigmas are
    wider than the window (float points draw no line a chunk can test)."""
    if not cfg.run_on_chunks or not chunks:
        return 0.0
    p0, p1 = log.start_m, log.end_m
    L = max(log.length_m, 1e-6)
    u = (p1[:2] - p0[:2]) / L
    nrm = np.array([-u[1], u[0]])
    (te, le), (to, lo) = [(float((q.position_m[:2] - p0[:2]) @ u), float((q.position_m[:2] - p0[:2]) @ nrm))
                          for q in (e, other)]
    if abs(to - te) < cfg.ridge_overrun_m:
        return 0.0
    ze, zo = float(e.position_m[2]), float(other.position_m[2])
    floor2 = cfg.ridge_line_sigma_floor_m ** 2
    s_lat = math.sqrt(e.sigma_h_m ** 2 + cfg.pose_sigma_m ** 2 + fcfg.axis_sigma_m ** 2 + floor2)
    s_z = math.sqrt(e.sigma_v_m ** 2 + cfg.pose_sigma_m ** 2 + fcfg.radius_sigma_m ** 2 + floor2)
    tol = PROFILE_CENTRE_TOLERANCE_M
    h_mid = log.radius_m - PROFILE_PRIOR_DEPTH_M  # the search window's middle in height about the run's axis
    log_uniform = -2.0 * math.log(2.0 * tol)
    eps = cfg.outlier_prior
    total = 0.0
    for c in chunks:
        if (c.t_m > te - cfg.ridge_overrun_m) if at_start else (c.t_m < te + cfg.ridge_overrun_m):
            continue
        f = (c.t_m - te) / (to - te)
        mu_lat = le + (lo - le) * f
        mu_h = ze + (zo - ze) * f - float(p0[2] + (p1[2] - p0[2]) * c.t_m / L)
        share = _window_share(mu_lat, s_lat, -tol, tol) * _window_share(mu_h, s_z, h_mid - tol, h_mid + tol)
        chi2 = min(((c.lateral_m - mu_lat) / s_lat) ** 2 + ((c.height_m - mu_h) / s_z) ** 2, CHI2_CAP)
        gauss = math.exp(-0.5 * chi2) / (2 * math.pi * s_lat * s_z * max(share, 1e-12))
        total += log_uniform - math.log((1 - eps) * gauss + eps * math.exp(log_uniform))
    return total


def _window_share(mu_m: float, sigma_m: float, lo_m: float, hi_m: float) -> float:
    """The share of a Gaussian (``mu_m``, ``sigma_m``) between ``lo_m`` and ``hi_m``."""
    k = 1.0 / (sigma_m * math.sqrt(2.0))
    return 0.5 * (math.erf((hi_m - mu_m) * k) - math.erf((lo_m - mu_m) * k))


def run_on_nats(inside_m: float, sigma_m: float, cfg: JointConfig) -> float:
    """-log-likelihood [nats] of the scan's ridge running ``inside_m`` past a log's end (beyond
    ``ridge_overrun_m``), relative to a ridge ending at it: the ridge ends at the log's end (a Gaussian of the
    point's ``sigma_m``), or, with prior ``ridge_run_on_prior``, runs on onto something in line for an
    exponential distance of mean ``ridge_run_on_mean_m``. Without run-ons, the Gaussian alone (revision 13)."""
    gauss = 0.5 * (inside_m / sigma_m) ** 2
    if not cfg.ridge_run_on:
        return gauss
    q, lam = cfg.ridge_run_on_prior, cfg.ridge_run_on_mean_m
    ratio = q / (1.0 - q) * math.sqrt(2.0 * math.pi) * sigma_m / lam  # run-on density over the Gaussian's peak
    run_on = -math.log(ratio) + inside_m / lam
    lo = min(gauss, run_on)
    return lo - math.log1p(math.exp(-abs(gauss - run_on)))


def _kappa(sh: float, sv: float, cfg: JointConfig) -> float:
    """How many nats a perfect point (sigmas ``sh`` across, ``sv`` vertically) is likelier than the outlier
    component: the Gaussian's peak density against the outlier's uniform one (at least 0)."""
    return max(-1.5 * math.log(2 * math.pi) - math.log(sh * sh * sv) + 3.0 * math.log(cfg.outlier_spread_m), 0.0)


def outlier_cost(e: SurveyEnd, cfg: JointConfig, fcfg: FuseConfig) -> float:
    """-log-likelihood of a survey point as an outlier, relative to a perfect point (the cost of leaving out
    a surveyed log that is the end of no log in the scan)."""
    sh = math.sqrt(e.sigma_h_m ** 2 + cfg.pose_sigma_m ** 2 + fcfg.axis_sigma_m ** 2)
    sv = math.sqrt(e.sigma_v_m ** 2 + cfg.pose_sigma_m ** 2 + fcfg.radius_sigma_m ** 2)
    return -math.log(cfg.outlier_prior) + _kappa(sh, sv, cfg)


def point_costs(ends: tuple[SurveyEnd | None, SurveyEnd | None], log: ScanLog, rev: bool, cfg: JointConfig,
                fcfg: FuseConfig, outlier_prob: bool = False, line: RidgeLine | None = None,
                chunks: Sequence[ChunkProfile] = ()) -> dict[int, float]:
    """Each surveyed point's :func:`point_cost` on ``log`` (its end a at the scan log's end with ``rev``), by
    its index (0: a, 1: b), with the log's other terms decided as :func:`pair_cost` decides them. The chunks'
    evidence past a point (:func:`run_on_evidence_nats`) tests them against the line through the log's two
    points: it counts as much as the other point is not an outlier there (an outlying point draws no line)."""
    out = {}
    for k, e in enumerate(ends):
        if e is None:
            continue
        at_start = (k == 0) != rev
        other = ends[1 - k]
        ev = 0.0 if other is None else run_on_evidence_nats(e, other, log, at_start, chunks, cfg, fcfg)
        if ev:  # the log's line is through the other point only as far as that point is believed on this ridge
            ev *= 1.0 - point_cost(other, log, not at_start, cfg, fcfg, True, line)
        out[k] = point_cost(e, log, at_start, cfg, fcfg, outlier_prob, line, ev)
    return out


def pair_cost(ends: tuple[SurveyEnd | None, SurveyEnd | None], log: ScanLog, cfg: JointConfig,
              fcfg: FuseConfig, radius_sigma_m: float | None = None,
              raster: HeightRaster | None = None, line: RidgeLine | None = None,
              chunks: Sequence[ChunkProfile] = ()) -> tuple[float, bool]:
    """A surveyed log's cost on a scan log (both orientations; the cheaper) and whether its end a lies at the
    scan log's end; with ``radius_sigma_m`` (the scan log's radius sigma), plus what its radius says against its
    being one log (:func:`~reconstruct.fitting.joint_ridge.not_one_log_nats`); with ``raster``, plus the open
    ground the log would lie over (:func:`laid_nats`, with its unseen run); with ``line`` and ``chunks``, its
    points against the ridge's chunk line and the chunks past them (:func:`point_cost`)."""
    best = (math.inf, False)
    for rev in (False, True):
        if all(p > cfg.outlier_flag_prob for p in point_costs(ends, log, rev, cfg, fcfg, True, line, chunks).values()):
            continue  # every point of it an outlier: this is not its log
        c = sum(point_costs(ends, log, rev, cfg, fcfg, False, line, chunks).values())
        if c < best[0]:
            best = (c, rev)
    if math.isinf(best[0]):
        return best
    return best[0] + laid_nats(ends, log, raster, cfg) + _radius_nats(log, radius_sigma_m, cfg), best[1]


def _radius_nats(log: ScanLog, radius_sigma_m: float | None, cfg: JointConfig) -> float:
    """What the scan log's radius says against its being one log [nats] (0 without its sigma or the term)."""
    if radius_sigma_m is None or not cfg.ridge_radius_evidence:
        return 0.0
    return not_one_log_nats(log.radius_m, radius_sigma_m, cfg)


def _solve(cost: np.ndarray, hidden: np.ndarray, missed: np.ndarray) -> tuple[float, list[int | None]]:
    """The cheapest assignment of rows (surveyed logs) to scan logs or hidden, scan logs left over costing
    ``missed``: the square problem with a hidden column per surveyed log and a missed row per scan log."""
    n, m = cost.shape
    big = np.full((n + m, m + n), IMPOSSIBLE)
    big[:n, :m] = np.minimum(cost, IMPOSSIBLE)
    big[np.arange(n), m + np.arange(n)] = hidden
    big[n + np.arange(m), np.arange(m)] = missed
    big[n:, m:] = 0.0
    rows, cols = linear_sum_assignment(big)
    pick: list[int | None] = [None] * n
    for r, c in zip(rows, cols):
        if r < n:
            pick[r] = int(c) if c < m else None
    return float(big[rows, cols].sum()), pick


def _costs(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], scan_logs: Sequence[ScanLog],
           cfg: JointConfig, fcfg: FuseConfig, evidence: RidgeEvidence | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every surveyed log's cost on every scan log, and whether its end a lies at the scan log's end."""
    ids = list(survey)
    cost = np.full((len(ids), len(scan_logs)), math.inf)
    rev = np.zeros(cost.shape, bool)
    raster = None if evidence is None else evidence.raster
    for i, k in enumerate(ids):
        for j, log in enumerate(scan_logs):
            if evidence is None:
                cost[i, j], rev[i, j] = pair_cost(survey[k], log, cfg, fcfg)
            else:
                cost[i, j], rev[i, j] = pair_cost(survey[k], log, cfg, fcfg, evidence.radius_sigma_m[j], raster,
                                                  evidence.line(j), evidence.chunks_of(j))
    return cost, rev


def missed_costs(scan_logs: Sequence[ScanLog], cfg: JointConfig, evidence: RidgeEvidence | None = None) -> np.ndarray:
    """What leaving each scan log unexplained costs: ``missed_nats_per_m`` per metre seen, less what its radius
    says against its being one log (a scrap or a flank need no surveyed log), at least 0 [nats]."""
    return np.array([max(0.0, cfg.missed_nats_per_m * log.seen_m - _radius_nats(
        log, None if evidence is None else evidence.radius_sigma_m[j], cfg)) for j, log in enumerate(scan_logs)])


def joint_match(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], scan_logs: Sequence[ScanLog],
                cfg: JointConfig | None = None, fcfg: FuseConfig | None = None,
                evidence: RidgeEvidence | None = None) -> JointMatching:
    """Match every surveyed log to at most one scan log by one assignment (see the module docstring); with
    ``evidence`` (:func:`~reconstruct.fitting.joint_ridge.ridge_evidence`), the ridges' radii and the open ground
    past them are in the costs."""
    cfg, fcfg = cfg or JointConfig(), fcfg or FuseConfig()
    ids = list(survey)
    n, m = len(ids), len(scan_logs)
    # a log of two points may be hidden under others; one of one point cannot be placed: it is left out, its
    # point an outlier
    hidden = np.array([cfg.hidden_cost if sum(e is not None for e in survey[k]) >= 2 else
                       sum(outlier_cost(e, cfg, fcfg) for e in survey[k] if e is not None) for k in ids])
    missed = missed_costs(scan_logs, cfg, evidence)
    offset = np.zeros(3)
    if cfg.match_pose_offset and n and m:
        offset = pose_offset(lambda d: _solve(*_costs(shifted(survey, d), scan_logs, cfg, fcfg, evidence)[:1], hidden,
                                              missed)[0], fcfg.pose_sigma_m, cfg)
        survey = shifted(survey, offset)
    cost, rev = _costs(survey, scan_logs, cfg, fcfg, evidence)
    best, pick = _solve(cost, hidden, missed)
    taken = frozenset(j for j in pick if j is not None)

    def pile(p: list[int | None]) -> tuple[frozenset, frozenset]:
        """What an assignment makes: the scan logs in the pile (taken, or long enough to stand as logs the
        survey missed) and the surveyed logs placed hidden; ids aside."""
        used = {j for j in p if j is not None}
        return (frozenset(j for j in range(m) if j in used or scan_logs[j].seen_m >= fcfg.min_new_log_m),
                frozenset(k for k, j in zip(ids, p) if j is None))

    alternatives, ambiguous = {}, []
    for i, k in enumerate(ids):
        if pick[i] is None:
            continue
        c2 = cost.copy()
        c2[i, pick[i]] = math.inf
        alt, alt_pick = _solve(c2, hidden, missed)
        delta = alt - best
        alternatives[k] = f"{'nothing' if alt_pick[i] is None else f'scan log {alt_pick[i]}'} (+{delta:.1f} nats)"
        if delta < cfg.ambiguity_nats and pile(alt_pick) != pile(pick):
            err = _ambiguity(k, survey[k], scan_logs[pick[i]], None if alt_pick[i] is None else scan_logs[alt_pick[i]],
                             delta)
            if cfg.ambiguity_is_error:
                raise err
            ambiguous.append(str(err).replace("chi2 differs by", "nats apart:") + " (the likelier is placed)")
    matches, dropped, outliers = {}, {}, {}
    for i, (k, j) in enumerate(zip(ids, pick)):
        if j is None and sum(e is not None for e in survey[k]) < 2:
            dropped[k] = "one survey point and no log in the scan that it is the end of: the point is an outlier"
            continue
        matches[k] = Match(k, j, bool(rev[i, j]) if j is not None else False,
                           float(cost[i, j]) if j is not None else math.nan, alternatives.get(k, ""))
        if j is not None:
            line, chunks = (None, ()) if evidence is None else (evidence.line(j), evidence.chunks_of(j))
            p_out = point_costs(survey[k], scan_logs[j], bool(rev[i, j]), cfg, fcfg, True, line, chunks)
            outliers[k] = {n for n, p in p_out.items() if p > cfg.outlier_flag_prob}
    return JointMatching(matches, [j for j in range(m) if j not in taken], dropped, best, outliers, ambiguous,
                         offset)
