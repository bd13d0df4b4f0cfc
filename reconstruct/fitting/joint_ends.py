"""The joint estimator's log ends (issue 37, step 2): each end's position along its log's fitted axis as a
posterior, from every piece of evidence at once, in place of revision 22's end rules
(:mod:`reconstruct.fitting.ends`).

- **The scan along the axis** is a per-bin likelihood. Each 2 cm bin over the axis shows the log's top
  (``on``), the scan sees below where the top would be (``below``: ground or lower logs), something over
  the top (``over``: another log), or nothing (unseen). A bin inside the log and a bin past its end show
  these with different probabilities (:class:`~reconstruct.fitting.joint_config.JointConfig` ``p_*``);
  the log-likelihood of an end at ``e`` sums the log-ratios of the bins between the log's middle and ``e``.
- **The survey point** is a Gaussian about the end (its receiver's accuracy, plus the registered scan
  pose's) mixed with an outlier component uniform over ``outlier_spread_m``: its posterior outlier
  probability, marginalised over the end's position, flags it (``contradicted``); a flagged point does not
  place its end. No gate, no "contradicted" or "not used" rule: one number per point.
- **A weak prior** at the cylinder fit's end (``end_prior_sigma_m``) where nothing else says.

The posterior is evaluated on the bins' grid (exact in 1-D: no Laplace approximation is needed along the
axis); the end is its mode, its ``sigma_along_m`` the posterior's spread about that mode (a two-humped
posterior - the scan says here, a float point there - reports the spread of both). Across the axis an end
lies on the fitted axis, pulled toward an inlying survey point by the two accuracies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from reconstruct.fitting.ends import (MIN_BIN_POINTS, MIN_LOG_LENGTH_M, TOP_BAND_RADII, UNMOVED_M, EndEstimate,
                                      axis_distance, axis_sigma_m, final_end)
from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_view import in_view
from reconstruct.fitting.survey_points import SurveyEnd

UNSEEN, ON, BELOW, OVER = 0, 1, 2, 3  # what a bin along the axis shows
SUBSTEPS = 4  # the posterior's grid is this many times finer than the bins (5 mm for 2 cm bins) [-]
EXTRAPOLATION_SIGMAS = 2.0  # a bin past the fitted axis is on or below its top only beyond this many sigma [-]
LENGTH_MARGIN_M = 1e-3  # ends closer than the shortest log plus this keep the fit's (LogSpec's own length
#                         differs from the ends' distance in the last digits: a log spec refuses it) [m]
MODE_WINDOW_M = 0.05  # an end is the posterior's mean within this of its mode (a mode alone snaps to the grid) [m]
VIEW_MARGIN_PX = 8.0  # a log's top this close to an image's edge is taken as out of view: stereo matches no
#                       point there (the block matcher's window, about this wide) [px]


@dataclass
class JointEndEstimate(EndEstimate):
    """An end placed by the joint estimator: :class:`EndEstimate`, its survey point's posterior outlier
    probability (None: no point) and the sigmas of the pile estimate's prior on its place along the axis,
    toward the log's middle and away from it (:func:`along_sigmas`) [m]."""

    outlier_prob: float | None = None
    sigma_along_in_m: float | None = None
    sigma_along_out_m: float | None = None

    def to_dict(self) -> dict:
        return super().to_dict() | {"outlier_prob": self.outlier_prob, "sigma_along_in_m": self.sigma_along_in_m,
                                    "sigma_along_out_m": self.sigma_along_out_m}


def bin_states(points: np.ndarray, pa: np.ndarray, u: np.ndarray, radius_m: float, lo_m: float, n_bins: int,
               fcfg: FuseConfig, on_mask: np.ndarray | None = None, fitted_m: float | None = None,
               views: list | None = None) -> np.ndarray:
    """What each bin of ``fcfg.end_bin_m`` along the axis ``pa + t u`` (t from ``lo_m``) shows
    (:data:`ON`, :data:`BELOW`, :data:`OVER` or :data:`UNSEEN`), from the scan ``points`` within half a
    radius of the axis's vertical plane; ``on_mask``: which points may show this log's top (those near
    another log only show where the scan sees below it). ``fitted_m``: the axis was fitted over t in
    [0, fitted_m]; past that its height is less sure (``extrapolation_sigma_per_m``), and a bin is on the top
    or below it only beyond twice that uncertainty (a log fitted over 60 cm and extended 2 m has its top
    there to +-8 cm: its own top read as 'below' threw out correct fixed points). ``views`` (the scan's pairs,
    :mod:`reconstruct.fitting.joint_view`): a bin whose top no pair has inside both its images reads
    'below' or 'over' no more (the ground seen under a raised log past the images' edge is no evidence that
    the log ends there); None: every bin as its points say."""
    P = np.asarray(points, dtype=np.float64)
    rel = P - pa
    t = rel @ u
    perp = rel - np.outer(t, u)
    up = np.array([0.0, 0.0, 1.0]) - u[2] * u
    up /= max(float(np.linalg.norm(up)), 1e-9)
    s, h = perp @ np.cross(u, up), perp @ up
    r = float(radius_m)
    k = np.floor((t - lo_m) / fcfg.end_bin_m).astype(np.int64)
    m = (np.abs(s) < TOP_BAND_RADII * r) & (k >= 0) & (k < n_bins)
    may = np.ones(int(m.sum()), bool) if on_mask is None else np.asarray(on_mask, bool)[m]
    e = h[m] - np.sqrt(np.clip(r * r - s[m] ** 2, 0.0, None))  # height over the top there
    k = k[m]
    c = lo_m + fcfg.end_bin_m * (np.arange(n_bins) + 0.5)
    past = np.zeros(n_bins) if fitted_m is None else np.maximum(0.0, np.maximum(-c, c - fitted_m))
    slack = EXTRAPOLATION_SIGMAS * fcfg.extrapolation_sigma_per_m * past  # per bin [m]
    on = np.bincount(k, weights=((np.abs(e) < fcfg.on_band_m + slack[k]) & may).astype(float),
                     minlength=n_bins) >= fcfg.min_on_points
    top = np.full(n_bins, -np.inf)
    np.maximum.at(top, k, e)
    seen = np.bincount(k, minlength=n_bins) >= MIN_BIN_POINTS
    below = ~on & seen & (top < -max(fcfg.below_min_m, fcfg.below_radius_share * r) - slack)
    over = ~on & ~below & seen & (top > fcfg.on_band_m)
    if views is not None:  # what the scan could not have seen of the top says nothing of where the log ends
        visible = in_view(views, pa + np.outer(c, u) + r * up, VIEW_MARGIN_PX)
        below, over = below & visible, over & visible
    return np.select([on, below, over], [ON, BELOW, OVER], UNSEEN)


def _state_probs(cfg: JointConfig) -> tuple[np.ndarray, np.ndarray]:
    """What a bin shows (UNSEEN, ON, BELOW, OVER) inside the log and past its end: the ``p_*`` shares."""
    inside = np.array([0.0, cfg.p_on_inside, cfg.p_below_inside, cfg.p_over_inside])
    outside = np.array([0.0, cfg.p_on_outside, cfg.p_below_outside, cfg.p_over_outside])
    inside[UNSEEN], outside[UNSEEN] = 1 - inside.sum(), 1 - outside.sum()
    return inside, outside


def _bin_llr(states: np.ndarray, cfg: JointConfig) -> np.ndarray:
    """Per bin, bins independent: log p(what it shows | inside the log) - log p(... | past its end). A bin
    with no scan points says nothing (0)."""
    table = np.array([0.0, math.log(cfg.p_on_inside / cfg.p_on_outside),
                      math.log(cfg.p_below_inside / cfg.p_below_outside),
                      math.log(cfg.p_over_inside / cfg.p_over_outside)])
    return table[states]


def _persistence(cfg: JointConfig, bin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per state (UNSEEN, ON, BELOW, OVER), the chance it goes on to the next bin, inside the log and past
    its end: ``1 - bin_m / run`` of its mean run (``run_*_m``)."""
    def rho(run_m: float) -> float:
        return max(0.0, 1.0 - bin_m / run_m)

    inside = np.array([0.0, rho(cfg.run_on_inside_m), rho(cfg.run_below_inside_m), rho(cfg.run_over_inside_m)])
    outside = np.array([0.0, rho(cfg.run_on_outside_m), rho(cfg.run_outside_m), rho(cfg.run_outside_m)])
    return inside, outside


def edge_log_likelihood(states_out: np.ndarray, cfg: JointConfig, bin_m: float) -> np.ndarray:
    """The log-likelihood (up to a constant) of the log ending at each bin edge, ``states_out`` ordered
    outward from the log's middle (edge m: bins before m inside, from m on past the end; m = 0 ... n).

    Independent bins (``cfg.contiguity`` off): the sum of :func:`_bin_llr` inside. With contiguity, what a
    bin shows is a first-order Markov chain inside the log and another past its end: a state goes on to the
    next bin with its chance (:func:`_persistence`: inside, the top runs the log's length, a gap under it
    is a bin or two, a log across it its width; past the end, the ground, a neighbour's top or flank run
    ``run_outside_m``), else the next bin is drawn afresh from the ``p_*`` shares; the first bin past the end
    is drawn afresh (the log's end is where what the scan sees changes). So a neighbour's top in line past a
    gap counts where it starts, not once per bin, and an end inside a run of one state costs what a run
    broken there would. Unseen bins say nothing and do not break a run."""
    if not cfg.contiguity:
        return np.r_[0.0, np.cumsum(_bin_llr(states_out, cfg))]
    p_in, p_out = _state_probs(cfg)
    rho_in, rho_out = _persistence(cfg, bin_m)
    n = len(states_out)
    prev = np.full(n, -1)  # the last seen state before each bin (-1: none)
    last = -1
    for i, s in enumerate(states_out):
        prev[i] = last
        if s != UNSEEN:
            last = s
    seen = states_out != UNSEEN
    stay = (states_out == prev) & (prev >= 0)
    fresh = prev < 0
    p = np.maximum(prev, 0)
    t_in = np.where(fresh, p_in[states_out], rho_in[p] * stay + (1 - rho_in[p]) * p_in[states_out])
    t_out = np.where(fresh, p_out[states_out], rho_out[p] * stay + (1 - rho_out[p]) * p_out[states_out])
    llr = np.where(seen, np.log(t_in) - np.log(t_out), 0.0)
    boundary = np.where(seen, np.log(p_out[states_out]) - np.log(t_out), 0.0)  # the first bin past the end
    return np.r_[0.0, np.cumsum(llr)] + np.r_[boundary, 0.0]


@dataclass(frozen=True)
class _Axis:
    """A log's fitted axis: end a at ``pa``, unit direction ``u`` toward end b, length ``L`` [m]."""

    pa: np.ndarray
    u: np.ndarray
    L: float


def _point_terms(point: SurveyEnd, axis: _Axis, lateral_sigma_m: float, cfg: JointConfig):
    """A survey point against the axis: its place along it [m], its sigma along [m], and the log-density of
    its offset across the axis (horizontal and vertical, each by its accuracy) if it is this end's point."""
    rel = point.position_m - axis.pa
    t_g = float(rel @ axis.u)
    d = rel - t_g * axis.u
    sh = math.sqrt(point.sigma_h_m ** 2 + cfg.pose_sigma_m ** 2 + lateral_sigma_m ** 2)
    sv = math.sqrt(point.sigma_v_m ** 2 + cfg.pose_sigma_m ** 2 + lateral_sigma_m ** 2)
    dh, dv = float(np.linalg.norm(d[:2])), float(d[2])
    log_lat = (-0.5 * (dh / sh) ** 2 - math.log(2 * math.pi * sh * sh)
               - 0.5 * (dv / sv) ** 2 - 0.5 * math.log(2 * math.pi * sv * sv))
    s_al = math.sqrt(point.sigma_along(axis.u) ** 2 + cfg.pose_sigma_m ** 2)
    return t_g, s_al, log_lat


def _grid(axis: _Axis, k: int, point: SurveyEnd | None, cfg: JointConfig, fcfg: FuseConfig) -> tuple[float, int]:
    """The grid for end ``k`` (0: a, 1: b): its first bin edge [m along the axis] and its bin count, from the
    log's middle outward past the prior end by ``search_m``, and past the survey point's place along it."""
    mid, step = 0.5 * axis.L, fcfg.end_bin_m
    far = (-cfg.search_m) if k == 0 else axis.L + cfg.search_m
    if point is not None:
        t_g = float((point.position_m - axis.pa) @ axis.u)
        far = min(far, t_g - cfg.search_m / 2) if k == 0 else max(far, t_g + cfg.search_m / 2)
    lo, hi = (far, mid) if k == 0 else (mid, far)
    n = max(int(math.ceil((hi - lo) / step)), 1)
    return (hi - n * step if k == 0 else lo), n


def end_posterior(states: np.ndarray, lo_m: float, k: int, axis: _Axis, point: SurveyEnd | None,
                  lateral_sigma_m: float, cfg: JointConfig, fcfg: FuseConfig) -> dict:
    """The posterior of end ``k``'s place along the axis over the bin edges of ``states`` (bins from
    ``lo_m``, covering the log's half toward that end): its mode ``t_m``, ``sigma_along_m``, the scan's own
    mode and spread (``t_scan_m``, ``sigma_scan_m``) and the point's posterior outlier probability."""
    step = fcfg.end_bin_m
    n = len(states)
    # bins between the middle and an end at edge j are inside: for end b those before j, for end a those after
    # (outward: the bins reversed); an end inside a bin takes its share of it (linear between the edges, on a
    # grid SUBSTEPS times finer)
    log_edges = (edge_log_likelihood(states, cfg, step) if k == 1 else
                 edge_log_likelihood(states[::-1], cfg, step)[::-1])
    edges = lo_m + (step / SUBSTEPS) * np.arange(n * SUBSTEPS + 1)
    inward = cfg.top_smear_m if k == 1 else -cfg.top_smear_m
    log_scan = np.interp(edges + inward, lo_m + step * np.arange(n + 1), log_edges)
    step = step / SUBSTEPS
    t_prior = 0.0 if k == 0 else axis.L
    log_w = log_scan - 0.5 * ((edges - t_prior) / cfg.end_prior_sigma_m) ** 2
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    j_scan = int(np.argmax(w))
    sig_scan = float(math.sqrt(float(w @ (edges - edges[j_scan]) ** 2)))
    out = {"t_scan_m": float(edges[j_scan]), "sigma_scan_m": sig_scan, "outlier_prob": None,
           "seen_any": bool((states == ON).any())}
    post = inlier = w  # inlier: the posterior given that the point (if kept) is right, for the along prior
    if point is not None:
        t_g, s_al, log_lat = _point_terms(point, axis, lateral_sigma_m, cfg)
        log_in = log_lat - 0.5 * ((t_g - edges) / s_al) ** 2 - 0.5 * math.log(2 * math.pi * s_al * s_al)
        log_out = -3.0 * math.log(cfg.outlier_spread_m)
        eps = cfg.outlier_prior
        shift = max(float(log_in.max()), log_out)
        z_in = (1 - eps) * float(w @ np.exp(log_in - shift))
        z_out = eps * math.exp(log_out - shift)
        p_out = z_out / (z_in + z_out)
        out["outlier_prob"] = float(p_out)
        if p_out <= cfg.outlier_flag_prob:
            mix = w * ((1 - eps) * np.exp(log_in - shift) + eps * math.exp(log_out - shift))
            post = mix / mix.sum()
            inlier = w * np.exp(log_in - shift)
            inlier = inlier / inlier.sum()
        out["t_point_m"], out["sigma_point_m"] = t_g, s_al
    j = int(np.argmax(post))
    near = np.abs(edges - edges[j]) <= MODE_WINDOW_M
    t_end = float(post[near] @ edges[near] / post[near].sum())
    spread = float(math.sqrt(float(post @ (edges - t_end) ** 2)))
    out["t_m"] = t_end
    out["sigma_along_m"] = max(spread, cfg.min_end_sigma_m, step / math.sqrt(12.0))
    out["sigma_along_in_m"], out["sigma_along_out_m"] = along_sigmas(inlier, edges, t_end, k, cfg)
    return out


def along_sigmas(post: np.ndarray, edges: np.ndarray, t_end: float, k: int, cfg: JointConfig) -> tuple[float, float]:
    """The sigmas of the pile estimate's Gaussian prior on end ``k``'s place along the axis (0: end a, at low
    t; 1: end b), toward the log's middle and away from it [m]: on each side, the distance from the end
    ``t_end`` to where the posterior ``post`` (over ``edges``) falls z^2 / 2 nats under its mode, over z
    (``along_interval_sigmas``) - the Gaussian that costs what the end's own posterior costs at the refusal's
    line. ``post`` is the posterior given that a kept survey point is right (the end was placed so: its
    outlier component, a floor a few nats under the mode, would make every interval reach the grid's edge).
    For a Gaussian posterior these are its sigma; a seen end's exponential flanks, a one-sided end (the scan
    bounds it on one side only) and a second hump past a valley deeper than the line are kept as they are
    there, where a Gaussian of the posterior's whole spread would let the bodies move an end across the
    valley, through bins that show the log's top, for almost nothing. An interval that reaches the grid's
    edge is that wide at least (the grid spans the log's half and ``search_m`` past the end)."""
    floor = cfg.min_end_sigma_m
    with np.errstate(divide="ignore"):
        lp = np.log(post)
    j = int(np.argmax(lp))
    keep = lp >= lp[j] - 0.5 * cfg.along_interval_sigmas ** 2
    lo = hi = j
    while lo > 0 and keep[lo - 1]:
        lo -= 1
    while hi < len(lp) - 1 and keep[hi + 1]:
        hi += 1
    below, above = max(t_end - float(edges[lo]), 0.0), max(float(edges[hi]) - t_end, 0.0)
    inward, outward = (above, below) if k == 0 else (below, above)
    return max(inward / cfg.along_interval_sigmas, floor), max(outward / cfg.along_interval_sigmas, floor)


def _scan_state(states: np.ndarray, lo_m: float, k: int, t_end: float, fcfg: FuseConfig) -> str:
    """What the scan shows of an end at ``t_end``: "seen" (the scan sees below within ``seen_gap_m`` past it),
    "occluded" (something over the log or below it farther on), "open" (the scan stops), "none" (no top)."""
    if not (states == ON).any():
        return "none"
    c = lo_m + fcfg.end_bin_m * (np.arange(len(states)) + 0.5)
    past = (c - t_end) if k == 1 else (t_end - c)
    beyond = states[past > 0]
    near_below = (states == BELOW) & (past > 0) & (past <= fcfg.seen_gap_m + fcfg.end_bin_m)
    if near_below.any():
        return "seen"
    return "occluded" if ((beyond == BELOW) | (beyond == OVER)).any() else "open"


def place_joint_ends(points: np.ndarray, spec: Any, how: str, survey: tuple[SurveyEnd | None, SurveyEnd | None],
                     swapped: bool, lateral_sigma_m: float, cfg: JointConfig, fcfg: FuseConfig,
                     on_mask: np.ndarray | None = None, views: list | None = None
                     ) -> tuple[Any, tuple[JointEndEstimate, JointEndEstimate]]:
    """A fitted log (``spec``, placed ``how``: "scan", "partial" or "hidden") with both ends at their
    posterior modes (:func:`end_posterior`), and the two estimates in survey order (end a, end b;
    ``swapped``: end b is the butt): :func:`reconstruct.fitting.ends.place_log_ends`'s contract.
    ``views``: the scan's pairs, with ``cfg.view_test`` (:func:`bin_states`)."""
    from synth.scene.pile import LogSpec

    butt, top = spec.endpoints_m()
    pa, pb = (top, butt) if swapped else (butt, top)
    L = float(np.linalg.norm(pb - pa))
    axis = _Axis(np.asarray(pa, float), (pb - pa) / max(L, 1e-9), L)
    r = 0.5 * spec.mean_diameter_m
    ests = []
    for k, point in enumerate(survey):
        lo, n = _grid(axis, k, point, cfg, fcfg)
        states = (np.zeros(n, np.int64) if how == "hidden" else
                  bin_states(points, axis.pa, axis.u, r, lo, n, fcfg, on_mask=on_mask, fitted_m=L,
                             views=views if cfg.view_test else None))
        post = end_posterior(states, lo, k, axis, point, lateral_sigma_m, cfg, fcfg)
        ests.append(_estimate(post, states, lo, k, axis, point, lateral_sigma_m, cfg, fcfg))
    a, b = ests
    if float(np.linalg.norm(b.position_m - a.position_m)) < MIN_LOG_LENGTH_M + LENGTH_MARGIN_M:  # nonsense: keep
        return spec, (a, b)                                                                         # the fit's ends
    new_butt, new_top = (b.position_m, a.position_m) if swapped else (a.position_m, b.position_m)
    return LogSpec.from_endpoints(new_butt, new_top, spec.diameter_m, spec.top_diameter_m, spec.colour), (a, b)


def _estimate(post: dict, states: np.ndarray, lo: float, k: int, axis: _Axis, point: SurveyEnd | None,
              lateral_sigma_m: float, cfg: JointConfig, fcfg: FuseConfig) -> JointEndEstimate:
    """An end's estimate from its posterior: on the axis at the mode (an inlying point's pull across it is
    the pile estimate's), its sigma across both accuracies combined; its source is what knew it best."""
    pos = axis.pa + post["t_m"] * axis.u
    lat = max(lateral_sigma_m, cfg.axis_lateral_sigma_m)
    inlier = point is not None and post["outlier_prob"] <= cfg.outlier_flag_prob
    if inlier:  # the point's pull across the axis is made with the pile's (reconstruct.fitting.joint_settle)
        s_pt = math.sqrt(point.sigma_h_m ** 2 + cfg.pose_sigma_m ** 2)
        lat = math.sqrt(1.0 / (1.0 / lat ** 2 + 1.0 / s_pt ** 2))
    s_al = post["sigma_along_m"]
    if inlier and post["sigma_point_m"] < post["sigma_scan_m"]:
        source = point.label
    elif post["seen_any"]:
        source = "scan"
    else:
        source = "inferred"
    est = JointEndEstimate(position_m=pos, sigma_m=float(math.sqrt(s_al ** 2 + 2 * lat ** 2)), sigma_along_m=s_al,
                           source=source, scan=_scan_state(states, lo, k, post["t_m"], fcfg),
                           outlier_prob=post["outlier_prob"], sigma_along_in_m=post["sigma_along_in_m"],
                           sigma_along_out_m=post["sigma_along_out_m"])
    if point is not None:
        res = float(np.linalg.norm(point.position_m - pos))
        est.gnss_fix, est.gnss_residual_m = point.fix, res
        est.gnss_residual_sigma = res / math.sqrt(point.sigma_3d_m ** 2 + est.sigma_m ** 2)
        est.contradicted = not inlier
        est.gnss_axis_distance_m = axis_distance(point, axis.pa, axis.u)
        est.gnss_position_m, est.gnss_sigma_m = point.position_m.copy(), point.sigma_3d_m
    return est


def outlier_probability(point: SurveyEnd, pos: np.ndarray, sigma_m: float, cfg: JointConfig) -> float:
    """The posterior outlier probability of a survey point against an end placed at ``pos`` to ``sigma_m``
    (3-D, isotropic): the mixture of :mod:`this module <reconstruct.fitting.joint_ends>` with the end fixed."""
    s2 = point.sigma_3d_m ** 2 / 3 + sigma_m ** 2 / 3 + cfg.pose_sigma_m ** 2
    d2 = float(np.sum((point.position_m - pos) ** 2))
    log_in = math.log(1 - cfg.outlier_prior) - 0.5 * d2 / s2 - 1.5 * math.log(2 * math.pi * s2)
    log_out = math.log(cfg.outlier_prior) - 3.0 * math.log(cfg.outlier_spread_m)
    return float(1.0 / (1.0 + math.exp(min(log_in - log_out, 700.0))))


def joint_after_check(ends: Sequence[dict], endpoints: Sequence[np.ndarray],
                      survey: tuple[SurveyEnd | None, SurveyEnd | None], cfg: JointConfig) -> list[dict]:
    """Ends a, b as the pile check left their log: each moved to the log's final end nearest it, its sigma
    grown by the move, its point's outlier probability taken again there (a check that pushed a log off its
    fixed points flags them, never silently). Ends the check did not move come back unchanged."""
    out = []
    for e, point in zip(ends, survey):
        final, shift = final_end(e, endpoints)
        if shift < UNMOVED_M:
            out.append(dict(e))
            continue
        e = dict(e, position_m=[float(v) for v in final], check_shift_m=shift, sigma_m=float(math.hypot(e["sigma_m"], shift)))
        if point is not None:
            p_out = outlier_probability(point, final, e["sigma_m"], cfg)
            res = float(np.linalg.norm(point.position_m - final))
            e.update(gnss_residual_m=res, gnss_residual_sigma=res / math.sqrt(point.sigma_3d_m ** 2 + e["sigma_m"] ** 2),
                     outlier_prob=p_out, contradicted=bool(e["contradicted"] or p_out > cfg.outlier_flag_prob))
            p0, p1 = (np.asarray(q, dtype=float) for q in endpoints)
            e["gnss_axis_distance_m"] = axis_distance(point, p0, (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9))
        out.append(e)
    return out


class JointEndPlacer:
    """``fit_pile``'s ``place_ends`` for the joint estimator: :func:`place_joint_ends` with the log's axis as
    sure across as how it was fitted (a scan-fitted axis to millimetres, a log seen in part to centimetres,
    a hidden one to its points)."""

    def __init__(self, survey_ends: dict, lateral: dict[str, float], cfg: JointConfig, fcfg: FuseConfig,
                 views: list | None = None) -> None:
        self.survey_ends, self.lateral, self.cfg, self.fcfg = survey_ends, lateral, cfg, fcfg
        self.views = views  # the scan's pairs in the pile frame (joint_view.scan_views; None: not known)

    def __call__(self, log_id: str, spec, how: str, points: np.ndarray, swapped: bool, on_mask: np.ndarray):
        from reconstruct.errors import FitError

        ends_k = self.survey_ends.get(log_id, (None, None))
        sig = axis_sigma_m(how, self.lateral[log_id], ends_k)
        try:
            return place_joint_ends(points, spec, how, ends_k, swapped, sig, self.cfg, self.fcfg, on_mask=on_mask,
                                    views=self.views)
        except FitError as exc:
            raise FitError(f"log {log_id!r}: {exc}") from exc


def dropped_point_lines(dropped: dict[str, str], survey: dict) -> list[str]:
    """``contradicted_points`` lines for the survey points of logs the joint matching left out."""
    return [f"{k} end {end} ({p.fix}): {why}; check or re-measure it"
            for k, why in dropped.items() for end, p in zip("ab", survey.get(k, (None, None))) if p is not None]
