"""A fitted log's ends placed from the scan and the survey by their accuracies.

Along a fitted log the scan is walked outwards from its middle (:func:`scan_end_interval`): every 2 cm
bin over the axis is *on* the log's top, *over* it (an occluder), *below* it (the scan sees deeper than
the top: the log is not there) or *unseen*. The log ends between the last bin on it and the first bin
below it, so each end gets an interval: a couple of centimetres where the scan sees the end, longer where
something lies over it, open where the scan stops. The surveyed point is then fused with that interval by
the accuracies (:func:`fuse_end`): a seen end and a point that agree are averaged by inverse variance (a
float point inside the scan becomes as good as a fixed one); a point the scan contradicts by more than
``contradiction_sigma`` is reported and not used (except beyond a seen end where the log may run on
unseen: under others, or as a tip held in the air, ``overhang_gap_m``); an end the scan does not see comes
from the point (``fixed``/``float``), or, with no usable point, from the interval (``inferred``).

Every end is reported with its source (``scan``, ``fixed``, ``float``, ``inferred``), its 1-sigma
uncertainty, and the survey point's residual against the result (:class:`EndEstimate`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from reconstruct.errors import FitError
from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.survey_points import SURVEY_REACH_SIGMAS, SurveyEnd

# the walk looks at the points within this many radii of the top line across [-]
TOP_BAND_RADII = 0.5
# a bin shows something (below or over the top) with at least this many points (one stray point is noise) [-]
MIN_BIN_POINTS = 2
# level ground past an end: the points from one to this many radii across the top line [-]
SHOULDER_OUTER_RADII = 1.5
# an end the pile check moved less than this is where it was [m]
UNMOVED_M = 1e-3
# an interval's standard deviation is its width over this (a uniform distribution's) [-]
UNIFORM_SD_DIVISOR = math.sqrt(12.0)
# an occluded end with no usable point is the middle of its interval when that is at most this many
# end_search_m wide [-]; a log without a survey point may run on unseen this many end_search_m [-]
INTERVAL_MAX_SEARCHES = 2
NO_POINT_REACH_SEARCHES = 2
# past the fitted end, the walk reaches as far as the survey point, SURVEY_REACH_SIGMAS of its sigmas and
# this much more [m], at most this far [m]; only the points this close to the log's line, across, or this
# far along it past its ends, matter [m]
REACH_MARGIN_M = 0.1
MAX_REACH_M = 2.0
LINE_MARGIN_M = 0.05
LINE_REACH_M = 2.5
#: ends placed closer than this are nonsense: the fit's ends are kept [m]
MIN_LOG_LENGTH_M = 0.3

#: how sure a log's axis is across itself when its ends are placed, by how the log was found
SCAN_AXIS_SIGMA_M = 0.005  # fitted to the scan: a few millimetres across (the cylinder fit's RMS / sqrt(n)) [m]
PARTIAL_AXIS_SIGMA_M = 0.04  # seen in part: a few centimetres (at least) [m]


def axis_sigma_m(how: str, lateral_m: float, ends: Sequence[SurveyEnd | None]) -> float:
    """The lateral 1-sigma of a log's axis [m]: fitted to the scan (``how`` "scan"), seen in part
    ("partial": at least its prior's ``lateral_m``), or hidden (its survey points' horizontal sigma,
    else ``lateral_m``)."""
    if how == "scan":
        return SCAN_AXIS_SIGMA_M
    if how == "partial":
        return max(lateral_m, PARTIAL_AXIS_SIGMA_M)
    return max((e.sigma_h_m for e in ends if e is not None), default=lateral_m)


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
    m = (np.abs(s) < TOP_BAND_RADII * r) & (t > lo_t) & (t < hi_t)
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
    below_thr = -max(cfg.below_min_m, cfg.below_radius_share * r)
    # the scan sees deeper than the log's top there (one stray point is noise)
    below = ~on & (count >= MIN_BIN_POINTS) & (top < below_thr)
    start = (0.5 * L if t_from is None else float(t_from))
    k0 = int(np.clip((start - lo_t) // step, 0, nb - 1))
    ks = np.arange(k0, nb) if toward_p1 else np.arange(k0, -1, -1)
    on_k, below_k = on[ks].astype(int), below[ks].astype(int)
    if not on_k.any():
        return EndInterval(None, None, "none")
    # the end is the cut that best separates bins on the log (inside) from bins seen below its top
    # (outside): a stray bin of either kind (a gap seen through at a crossing, another log's top at the
    # same height farther on) does not decide it; bins over it or unseen count for neither
    # (seeing the ground through where the log would be is the stronger evidence: it counts below_weight-fold)
    w_below = cfg.below_weight
    inside = np.cumsum(on_k - w_below * below_k)
    outside = np.cumsum((w_below * below_k - on_k)[::-1])[::-1]
    score = inside + np.r_[outside[1:], 0]
    score[on_k == 0] = np.iinfo(np.int64).min  # the cut is right after a bin on the log
    j = int(np.argmax(score))
    over_k = ((count >= MIN_BIN_POINTS) & (top > cfg.on_band_m))[ks].astype(int)  # something over the log's top
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
    # the walk's farthest bin with points (at least first_off)
    covered = ks[np.flatnonzero(count[ks] >= MIN_BIN_POINTS)[-1]]
    t_cov = lo_t + (covered + (1 if toward_p1 else 0)) * step
    return EndInterval(t_on, t_off, state, gap_under_m=float(-top[first_off] - 2 * r), covered_to_m=float(t_cov))


def _first_below(below: np.ndarray, over: np.ndarray, span: int = 4, min_over: int = 3) -> int | None:
    """The first bin of the walk past the cut (index into ``below``) where the scan sees below the log's
    top, skipping a lone such bin inside a stretch over the log: no other bin below within ``span`` bins
    on either side, and at least ``min_over`` of those ``span`` bins on each side show something over the
    log's top - a gap seen through between logs lying over it, which would otherwise contradict a survey
    point past it and put the end short. Any other bin below, alone or not, is where the scan shows the log
    is not."""
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
    (``r`` to ``SHOULDER_OUTER_RADII`` ``r`` across) lie as high as the top itself (median at least
    ``level_shoulder`` ``r`` over the axis), where beside a log's top the scan sees lower (the log's flanks,
    the ground, a neighbour's flank). A log running down to the ground ends there; its axis extended past
    the end goes into the ground, and where that line's top meets the ground the ground looked like the log's
    top (bins of flat ground past an RTK-fixed end outweighed the bins seen below, the end was placed
    far out and the fixed point called wrong)."""
    out = np.zeros(nb, bool)
    outward = u[2] if toward_p1 else -u[2]
    if outward > -math.sin(math.radians(cfg.descent_min_deg)):
        return out
    past = (t > L) if toward_p1 else (t < 0.0)
    sh = past & (np.abs(s) > r) & (np.abs(s) < SHOULDER_OUTER_RADII * r) & (t > lo_t)
    if not sh.any():
        return out
    bi = np.clip(((t[sh] - lo_t) / step).astype(np.int64), 0, nb - 1)
    for b in np.unique(bi):
        hb = h[sh][bi == b]
        out[b] = len(hb) >= MIN_BIN_POINTS and float(np.median(hb)) >= cfg.level_shoulder * r
    return out


def _before_island(on_k: np.ndarray, j: int, step: float, cfg: FuseConfig) -> int:
    """The walk's last bin on the log (index into the walk), given the cut after bin ``j``: the same,
    unless the run on the log that ends at ``j`` is an island - at most ``island_max_m`` long, past a
    stretch of at least ``island_gap_m`` with no bin on the log (unseen, or something over it). Then the
    log's own top ends before that stretch, and the island, a few points at the height of its top just
    before the scan sees the ground, is a neighbour's flank or edge (an end hidden under a crossing log,
    a few points well past it put the 'seen' end there, past its fixed point). The interval then runs from
    that top's end to where the scan sees below it: occluded."""
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
    but the disagreement is reported: a log fitted on a ridge a decimetre off both its RTK fixed points
    passes the 3-D point test (~15 cm for a fixed point) unwarned otherwise. On 120 fixed
    points of scan-fitted logs of 13 twin reconstructions the offset was 1.8 cm median, 6.2 cm at most;
    this limit is ~8 cm for a fixed point. A log whose axis is the survey's is not tested here."""
    if lateral_sigma_m >= cfg.axis_sigma_m:
        return False
    sg_across = math.sqrt(0.5 * (point.sigma_h_m ** 2 + point.sigma_v_m ** 2))
    limit = cfg.contradiction_sigma * math.sqrt(lat_m ** 2 + sg_across ** 2 + cfg.axis_sigma_m ** 2)
    return axis_distance(point, p0, u) > limit


def _point_test(point: SurveyEnd, pos: np.ndarray, sigma_m: float, cfg: FuseConfig) -> tuple[float, float, bool]:
    """A survey point against an end placed at ``pos`` to ``sigma_m`` (3-D): its distance [m], that in
    units of the combined sigma, and whether that contradicts it (chi with 3 dof, ~3 sigma each)."""
    res = float(np.linalg.norm(point.position_m - pos))
    res_sigma = res / math.sqrt(point.sigma_3d_m ** 2 + sigma_m ** 2)
    return res, res_sigma, res_sigma > cfg.contradiction_sigma * math.sqrt(3.0)


def axis_distance(point: SurveyEnd, p0: np.ndarray, u: np.ndarray) -> float:
    """A survey point's distance from the axis line ``p0 + t u`` [m]."""
    rel = point.position_m - p0
    return float(np.linalg.norm(rel - (rel @ u) * u))


def final_end(e: dict, endpoints: Sequence[np.ndarray]) -> tuple[np.ndarray, float]:
    """The end of the checked log nearest the end estimate ``e`` and how far it lies from it [m]."""
    pos = np.asarray(e["position_m"], dtype=float)
    final = min((np.asarray(q, dtype=float) for q in endpoints), key=lambda q: float(np.linalg.norm(q - pos)))
    return final, float(np.linalg.norm(final - pos))


def after_pile_check(ends: Sequence[dict], endpoints: Sequence[np.ndarray],
                     survey: tuple[SurveyEnd | None, SurveyEnd | None], cfg: FuseConfig | None = None,
                     ) -> list[dict]:
    """Ends a, b (``EndEstimate.to_dict``) as the pile check left their log: each moved to the log's
    final end nearest it (``endpoints``: the log's two ends after the check), its survey point tested
    against that place with the estimate's own sigma (a check that pushed a log off its fixed points is
    a contradiction, never silent), then its sigma grown by the move (the check's correction is not
    in the estimate: a log pushed 6 cm is not known to 1 cm, and is reported weak). Ends the check did
    not move (under ``UNMOVED_M``) come back unchanged."""
    cfg = cfg or FuseConfig()
    out = []
    for e, point in zip(ends, survey):
        final, shift = final_end(e, endpoints)
        if shift < UNMOVED_M:
            out.append(dict(e))
            continue
        e = dict(e, position_m=[float(v) for v in final], check_shift_m=shift)
        if point is not None:
            e["gnss_residual_m"], e["gnss_residual_sigma"], against = _point_test(point, final, e["sigma_m"], cfg)
            e["contradicted"] = bool(e["contradicted"] or against)
            p0, p1 = (np.asarray(q, dtype=float) for q in endpoints)
            e["gnss_axis_distance_m"] = axis_distance(point, p0, (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9))
        e["sigma_m"] = float(math.hypot(e["sigma_m"], shift))
        out.append(e)
    return out


def _on_axis(point: SurveyEnd, p0: np.ndarray, u: np.ndarray, t_g: float, interval: EndInterval,
             lateral_sigma_m: float, cfg: FuseConfig) -> bool:
    """Whether a survey point lies on the fitted axis line (within ``contradiction_sigma`` of its own
    3-D accuracy and of the axis's across, that growing past what the scan shows of the log)."""
    past = 0.0 if interval.last_on_m is None else abs(t_g - interval.last_on_m)
    lat = lateral_sigma_m + cfg.extrapolation_sigma_per_m * past
    return axis_distance(point, p0, u) <= cfg.contradiction_sigma * math.hypot(point.sigma_3d_m, lat)


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
        # the cameras see the ground under it from the side and stereo loses its thin end (the top seen
        # stops short of a fixed point and of the truth)
        t_s = seen_end(interval)
        beyond = sign * (t_g - t_s)
        # ... a precise point as far as the walk goes, any point past what the scan covers (no points there
        # to say otherwise)
        past_cover = interval.covered_to_m is not None and sign * (t_g - interval.covered_to_m) > 0
        tip = _overhang(interval, cfg) and ((sg <= cfg.weak_sigma_m and beyond <= cfg.end_search_m) or past_cover)
        # ... and a precise point on the axis line past all the scan covers: the log runs on where the scan
        # has no points
        unseen_on = past_cover and on_axis and sg <= cfg.weak_sigma_m
        if abs(t_g - t_s) / math.hypot(ss, sg) > cfg.contradiction_sigma and beyond > 0 and (
                not seen_whole or tip or unseen_on):
            seen, hi = False, None
    if not seen_whole and survey is not None and sg <= ss and interval.state != "seen":
        # a log the scan shows only in part: its axis is the survey's and its radius a guess from a piece of
        # its top, so where the scan seems to see past its top (or on it) beyond a covered end is no match
        # for a point at least as precise as a seen end (a radius guessed too large makes the true top look
        # 'below' it, and RTK fixed points were dropped for ends decimetres off)
        return t_g, sg, survey.label, False
    if seen:  # the top stops at lo; the scan sees below it a little farther out (hi)
        t_s = seen_end(interval)
        if survey is None:
            return t_s, ss, "scan", False
        if abs(t_g - t_s) / math.hypot(ss, sg) > cfg.contradiction_sigma:
            return t_s, ss, "scan", True
        wg, ws = 1.0 / sg ** 2, 1.0 / ss ** 2
        return ((wg * t_g + ws * t_s) / (wg + ws), 1.0 / math.sqrt(wg + ws), ("scan" if ss <= sg else survey.label),
                False)
    # the end lies past the last bin on the log (lo; the scan's own end of the log, to ss), and short of
    # hi when the scan sees below the top there (something lay over the end)
    inner = sign * lo
    outer = math.inf if hi is None else sign * hi
    width = None if hi is None else abs(hi - lo)
    tol = None if survey is None else cfg.contradiction_sigma * math.hypot(sg, ss)
    if survey is not None and inner - tol <= sign * t_g <= outer + tol:
        # a point more precise than the scan's bounds stands; a less precise one is kept within them
        t = t_g if sg <= ss else sign * float(np.clip(sign * t_g, inner, outer))
        sa = max(min(sg, width / UNIFORM_SD_DIVISOR) if width is not None else sg, min(sg, ss))
        return t, sa, survey.label, False
    if width is not None and width <= INTERVAL_MAX_SEARCHES * cfg.end_search_m:
        return 0.5 * (lo + hi), max(width / UNIFORM_SD_DIVISOR, ss), "inferred", survey is not None
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
    reach_t = LINE_REACH_M / max(float(np.linalg.norm(d2)), 1e-6)
    over = (across < r + LINE_MARGIN_M) & (t2 > -reach_t) & (t2 < 1.0 + reach_t)
    points = P[over]
    on_mask = None if on_mask is None else np.asarray(on_mask, bool)[over]
    ests = []
    for k, e in enumerate(survey):
        # past the fitted end, as far as the survey point (and some of its sigmas) or, with none, a log
        # may run on unseen under others
        if e is None:
            reach = NO_POINT_REACH_SEARCHES * cfg.end_search_m
        else:
            t_g = float((e.position_m - pa) @ u)
            beyond = -t_g if k == 0 else t_g - L
            reach = float(np.clip(beyond + SURVEY_REACH_SIGMAS * e.sigma_along(u) + REACH_MARGIN_M, cfg.end_search_m,
                                  MAX_REACH_M))
        if how == "hidden":
            iv = EndInterval(None, None, "none")
        else:
            iv = scan_end_interval(points, pa, pb, r, toward_p1=(k == 1), reach_m=reach, cfg=cfg, on_mask=on_mask)
        ests.append(fuse_end(pa, u, iv, k == 0, e, lateral_sigma_m, cfg, seen_whole=(how == "scan")))
    a, b = ests
    for est, e in zip(ests, survey):
        if e is not None:
            est.gnss_axis_distance_m = axis_distance(e, pa, u)
    if float(np.linalg.norm(b.position_m - a.position_m)) < MIN_LOG_LENGTH_M:  # nonsense: keep the fit's ends
        return spec, (a, b)
    new_butt, new_top = (b.position_m, a.position_m) if swapped else (a.position_m, b.position_m)
    return LogSpec.from_endpoints(new_butt, new_top, spec.diameter_m, spec.top_diameter_m, spec.colour), (a, b)
