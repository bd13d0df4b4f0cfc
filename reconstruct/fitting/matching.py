"""The survey matched to the logs in the scan (:func:`match_survey`), and where each log is then fitted
(:func:`prior_axis`).

Every surveyed log is matched to at most one scan log, minimising the summed squared normalised distances
of its points from the scan log's axis (each point by its own accuracy, plus the scan pose's), with a
point that lies inside the scan log's visible length counted against it. A point farther than
``gate_sigma`` from a scan log cannot be its. A surveyed log matched to none is left to the survey (it may
be hidden under others). A scan log matched to no surveyed log is a log the survey missed: it is
reconstructed from the scan alone. When another matching is nearly as good and would change which logs
exist, the geometry is ambiguous: :class:`AmbiguousSurveyError` names the logs and points to re-measure."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from reconstruct.errors import FitError
from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.scan_logs import ScanLog
from reconstruct.fitting.scan_offset import matching_chi2
from reconstruct.fitting.survey_points import SURVEY_REACH_SIGMAS, SurveyEnd

# a point beyond the gate costs this much more than the gate's chi^2 (so a log with no point on a scan log
# is better matched to none) [-]
OUTLIER_EXTRA_CHI2 = 1.0
# the assignment's cost of a pair that cannot match [-]
NO_MATCH_COST = 1e9
# a scan log on a log's survey line lies above it when its axis is, on average over this many places, a
# radius higher [-]
HEIGHT_SAMPLES = 9
# a matched log's axis is known across to axis_sigma_m and 1/this of pose_sigma_m [-]
POSE_SIGMA_DIVISOR = 2


class AmbiguousSurveyError(FitError):
    """The survey and the scan fit two different piles almost equally well (imprecise points near
    several scan logs): the message names the logs and points to re-measure."""


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
                offset_m: np.ndarray | None = None) -> tuple[float, bool, int]:
    """Summed squared normalised distances of a surveyed log's points from a scan log (+inf when every
    point is beyond the gate), whether its end ``a`` lies at the scan log's end, and how many of its
    points lie beyond the gate (gross errors, if this is its log). With ``offset_m`` (the scan's horizontal
    offset, :mod:`reconstruct.fitting.scan_offset`) the points are taken less that offset and their distance
    across the scan log is priced without the pose's sigma, which the offset stands for."""
    p0, p1 = log.start_m, log.end_m
    d = p1[:2] - p0[:2]
    L = max(float(np.linalg.norm(d)), 1e-6)
    u = d / L
    n = np.array([-u[1], u[0]])
    best = (math.inf, False, 0)
    for rev in (False, True):
        total, outliers, far, precise_out = 0.0, 0, 0, 0
        for k, e in enumerate(ends):
            if e is None:
                continue
            at_start = (k == 0) != rev
            q = e.position_m if offset_m is None else e.position_m - np.append(offset_m, 0.0)
            t = float((q[:2] - p0[:2]) @ u)
            sh = math.hypot(e.sigma_h_m, math.hypot(cfg.pose_sigma_m, cfg.axis_sigma_m))
            sv = math.sqrt(e.sigma_v_m ** 2 + cfg.pose_sigma_m ** 2 + cfg.radius_sigma_m ** 2)
            # with the offset fitted, across the ridge a point is as sure as itself and the ridge's axis there (the
            # axis extended past the ridge less sure by extrapolation_sigma_per_m)
            past = max(0.0, -t, t - L)
            s_across = sh if offset_m is None else math.hypot(
                e.sigma_h_m, math.hypot(cfg.axis_sigma_m, cfg.extrapolation_sigma_per_m * past))
            lat = float((q[:2] - p0[:2]) @ n) / s_across
            z_axis = p0[2] + (p1[2] - p0[2]) * np.clip(t / L, 0.0, 1.0)
            vert = (float(q[2]) - float(z_axis)) / sv
            # a log end is at or beyond the visible ridge: a point well inside it counts against (the ridge
            # may run on a little past the end: smoothing, the end face, a stack's smear)
            inside = max(0.0, t) if at_start else max(0.0, L - t)
            inside = max(0.0, min(inside, L) - cfg.ridge_overrun_m) / math.hypot(sh, cfg.ridge_overrun_m)
            c2 = lat * lat + vert * vert + inside * inside
            if lat * lat + vert * vert <= cfg.gate_sigma ** 2 and inside > cfg.gate_sigma:
                # on the ridge's line, well inside it: the ridge runs on past this end over something abutting
                # it (a stump) - as costly as a wrong point, but not called wrong (a scrap of ridge at the
                # point, the log's other point wrong, is no equal)
                c2 = cfg.gate_sigma ** 2 + OUTLIER_EXTRA_CHI2
            elif lat * lat + vert * vert > cfg.gate_sigma ** 2 or inside > cfg.gate_sigma:
                # not on this scan log: a wrong point, if the log's other point is (costs more than the
                # gate, so a log with no point on a scan log is better matched to none)
                c2 = cfg.gate_sigma ** 2 + OUTLIER_EXTRA_CHI2
                outliers += 1
                precise_out += e.sigma_h_m <= cfg.weak_sigma_m
            elif not -cfg.end_search_m <= t <= L + cfg.end_search_m:
                far += 1  # on the scan log's line, but beyond any walk from it
            total += c2
        if outliers and outliers == sum(e is not None for e in ends):
            total = math.inf
        if outliers and far:
            # a point called wrong, and the other only on the line far past the scan log: a scrap of
            # ridge crossing the surveyed log near one end is no evidence against its other point (else
            # a scrap at right angles to a log of two fixed points takes it)
            total = math.inf
        if cfg.scrap_keeps_precise_points and precise_out and log.seen_m < cfg.min_new_log_m:
            # a precise point called wrong on a scrap of ridge the scan alone would not make a log of: the scrap
            # is no evidence against the point (the log, its points right, is hidden or on another scan log)
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
            if cfg.one_scan_offset:
                # as good only if as good both ways the pose's error is priced: at every point (the widths the
                # matching is found with) and as one offset of the whole scan; the offset clears ties the loose
                # widths make, and never picks another matching (fitted to a few logs, one offset can make a
                # matching shifted by a log look best)
                delta = max(delta, _one_offset_delta(survey, ids, scan_logs, pick, alt_pick, none_cost, cfg))
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


def _one_offset_delta(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], ids: list[str],
                      scan_logs: Sequence[ScanLog], pick: list[int | None], alt: list[int | None],
                      none_cost: np.ndarray, cfg: FuseConfig) -> float:
    """How much worse ``alt`` explains the survey than ``pick``, each with its own offset of the whole scan
    (:func:`reconstruct.fitting.scan_offset.matching_chi2`) [chi^2]."""
    wrong = cfg.gate_sigma ** 2 + OUTLIER_EXTRA_CHI2
    return (matching_chi2(survey, ids, scan_logs, alt, none_cost, cfg, _match_cost, wrong)
            - matching_chi2(survey, ids, scan_logs, pick, none_cost, cfg, _match_cost, wrong))


def _hidden_is_the_surer(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], ids: list[str],
                         pick: list[int | None], alt: list[int | None], i: int) -> bool:
    """Whether of two matchings that differ in which of two logs the scan shows (``pick``: log ``i`` on a
    scan log, another hidden; ``alt``: log ``i`` hidden, that other on it), ``pick`` hides only logs whose
    two points are RTK fixed while log ``i`` has a float one. Two logs lying side by side, the scan showing
    one ridge (a hand apart, one a little higher): the hidden log is placed from its
    survey points, so ``pick`` places both logs as well as the survey allows; were ``alt`` the truth,
    ``pick``'s hidden log would lie where the scan shows a log, for the pile check to refuse, and where the
    ridge is both logs end to end, the log on it gets an end its float point contradicts, reported
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
        constant, whatever its accuracy) is no equal explanation (a log with both ends RTK fixed is not "as
        good" on a scrap of ridge with one of them wrong)."""
        return (delta < self.cfg.ambiguity_chi2 and self.content(alt) != self.content(best)
                and self.gross_errors(alt) <= self.gross_errors(best))


def _on_its_survey_line(log: ScanLog, ends: tuple[SurveyEnd | None, SurveyEnd | None], cfg: FuseConfig) -> bool:
    """Whether scan log ``log`` is a piece of the log whose two RTK fixed points are ``ends``: on their
    line in top view (:func:`_is_piece_of`), overlapping the stretch between them by at least
    ``min_segment_m``, and not lying above it (a log resting on top along it would be another log: its
    axis at least a radius higher). Then "that log is hidden and the scan log another" counts one log
    twice (a sloped ridge on a log's fixed line would stop the scan as ambiguous)."""
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
    ts = np.linspace(lo, hi, HEIGHT_SAMPLES)
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
    big = NO_MATCH_COST
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
               cfg: FuseConfig | None = None, over_scan_share: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Where to fit a log: (end a, end b, lateral 1-sigma [m]). On the scan log's axis when matched:
    each end where its survey point projects, or the ridge's end when the point is missing or less
    certain than the ridge's extent; from the survey points alone when unmatched or a piece of the log
    (:func:`a_piece_of_a_surveyed_log`, ``over_scan_share`` as there)."""
    cfg = cfg or FuseConfig()
    if log is None:
        a, b = ends
        if a is None or b is None:
            raise ValueError("an unmatched surveyed log needs both ends")
        return a.position_m.copy(), b.position_m.copy(), max(a.sigma_3d_m, b.sigma_3d_m)
    if a_piece_of_a_surveyed_log(ends, log, cfg, over_scan_share):
        a, b = ends
        return a.position_m.copy(), b.position_m.copy(), max(a.sigma_3d_m, b.sigma_3d_m)
    p0, p1 = (log.end_m, log.start_m) if reversed_ else (log.start_m, log.end_m)
    d = p1 - p0
    L = max(float(np.linalg.norm(d)), 1e-6)
    u = d / L
    out = []
    for k, (e, ridge_end) in enumerate(zip(ends, (p0, p1))):
        if e is None or e.sigma_h_m > cfg.end_search_m / SURVEY_REACH_SIGMAS:
            out.append(ridge_end.copy())
            continue
        t = float((e.position_m - p0) @ u)
        # the survey point's place along the axis; an imprecise one reaches at most end_search_m past the ridge
        if e.sigma_h_m > cfg.weak_sigma_m:
            t = max(t, -cfg.end_search_m) if k == 0 else min(t, L + cfg.end_search_m)
        out.append(p0 + u * t)
    return out[0], out[1], math.hypot(cfg.axis_sigma_m, cfg.pose_sigma_m / POSE_SIGMA_DIVISOR)


def a_piece_of_a_surveyed_log(ends: tuple[SurveyEnd | None, SurveyEnd | None], log: ScanLog, cfg: FuseConfig,
                              over_scan_share: float = 1.0) -> bool:
    """Whether the scan log a surveyed log matched is a piece of it, too short to set its axis (the log is
    then seen only in part: :func:`reconstruct.fitting.fit.fit_pile` ``in_part``): both survey points
    precise (to ``weak_sigma_m``), the ridge seen over less than ``piece_share`` of the distance between
    them, and one of them farther than ``piece_off_m`` from the ridge's line (a piece in line with the
    points fits the log as well as ever, often better than the points: its log is fitted as before; on the
    200-scan bench, taking every piece as the log seen in part cost 1-4 cm on 20 logs). Two RTK-fixed
    points 2.7 m apart set the line to ~0.5 deg; a 35 cm ridge, its axis known to 2 cm at each end, to
    ~6 deg, off by 20-40 cm at the far end (a log under others, a piece of it seen by its butt, is fitted
    degrees off and decimetres off its other, fixed, point). The share is of the part of that distance the
    scan could show: ``over_scan_share`` of the survey axis lies over the scanned area
    (:class:`reconstruct.fitting.coverage.Coverage`); a log that runs out of the scan is not hidden beyond it."""
    a, b = ends
    if a is None or b is None or max(a.sigma_h_m, b.sigma_h_m) > cfg.weak_sigma_m:
        return False
    if not 0.0 <= over_scan_share <= 1.0:
        raise ValueError(f"over_scan_share must be in [0, 1], got {over_scan_share}")
    if log.seen_m >= cfg.piece_share * over_scan_share * float(np.linalg.norm(b.position_m - a.position_m)):
        return False
    return max(_off_line_m(log, a.position_m), _off_line_m(log, b.position_m)) > cfg.piece_off_m
