"""The joint estimator's pile check (issue 37, step 2): every log's pose correction estimated at once from
what holds it where it is and from the other bodies, in place of revision 22's roll → thin → move → re-test
(:mod:`reconstruct.fitting.separation`, :mod:`reconstruct.fitting.clearance`).

Each log's state is its placed axis with its two ends moved across it, horizontally (``c``) and up (``h``),
and (``JointConfig.along_ends``) along it (``l``): six numbers per log (a shift, a height, a small yaw and
pitch, and each end's place along the log, so its length). One ``scipy.optimize.least_squares`` weighs:

- **the scan**: a Gaussian on each end's correction, its sigma the fit's uncertainty (for a log fitted to its
  points its own, from the points on its surface: :mod:`reconstruct.fitting.joint_scan_sigma`; its
  placement's for one seen in part or hidden);
- **each end's place along the log**: a Gaussian about where the end model put it, one sigma toward the
  log's middle and one away, from that end's own posterior (:func:`reconstruct.fitting.joint_ends.along_sigmas`:
  an end the scan sees, or an RTK fixed point holds, to a centimetre or two; a hidden end on a float point by
  that point's accuracy), so a contact shortens a log where its end evidence is weak and cannot where it is
  strong;
- **its survey points** (those its end posteriors kept): each point's offset across the moved axis, by its
  receiver's accuracy and the scan pose's, through a soft-L1 loss (a wrong point the posteriors missed pulls
  by a bounded force, not by its distance squared);
- **non-interpenetration**: for every pair of bodies whose round cross-sections overlap by more than the
  twin's prism allows (:mod:`reconstruct.fitting.joint_contact`), the excess depth over ``contact_sigma_m``;
  zero when apart;
- **each obstacle's own evidence** (``JointConfig.obstacle_states``, joint revision 13): a stump or rock may
  shift and shrink by a Gaussian of its own scan sigma (:mod:`reconstruct.fitting.joint_obstacles`), so a log
  pressed into an obstacle the scan made too big shares the move with it; a log's refusal cost then counts
  the obstacles it touches too;
- **each log's own radius** (``JointConfig.radius_states``): a log may thin (or thicken) by a Gaussian of its
  scan radius sigma, its top kept (:mod:`reconstruct.fitting.joint_radius`), so a log fitted too thick in a
  packed pile is thinned within its uncertainty; its radius prior is part of its evidence cost.

Without the bodies the estimate is where the scan and the survey put each log (the survey's pull across the
axis is made here, not by the end placer). A log whose evidence costs more than ``refuse_sigma`` squared more
at the estimate than there has to move farther than what holds it allows: that is the refusal
(:class:`SeparationError`, naming the log and what it ran into), not a fixed distance. The twin then checks the
estimate with each touching log at its best roll (:func:`reconstruct.fitting.separation.best_roll`); a contact
it still finds is allowed less overlap and the estimate is made again."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from reconstruct.errors import SeparationError
from reconstruct.fitting.clearance import Cleared
from reconstruct.fitting.ends import MIN_LOG_LENGTH_M
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_contact import Bodies, Segment, Term
from reconstruct.fitting.joint_obstacles import (N_STATES, moved_obstacles, obstacle_notes, obstacle_sigmas,
                                                 offset_depths)
from reconstruct.fitting.joint_radius import changed_radius, radius_notes, radius_segment, resized_log
from reconstruct.fitting.joint_rescue import settle_or_rescue
from reconstruct.fitting.separation import SEPARATION_MARGIN_M, best_roll
from synth.scene.pile import LogSpec, PileSpec, quat_from_x_axis

UP = np.array([0.0, 0.0, 1.0])
#: a log moved less than this by the bodies is not reported as moved [m]
REPORT_MOVE_M = 1e-3


@dataclass(frozen=True)
class SurveyPull:
    """A kept survey point of a log: where it lies across the log's placed axis at ``s`` (its share of the
    way from the butt to the top), horizontally and vertically [m], and the sigmas of those [m]."""

    s: float
    across_m: float
    up_m: float
    sigma_across_m: float
    sigma_up_m: float


@dataclass(frozen=True)
class AlongPrior:
    """The prior on one end's place along its log, about where the end model put it: its sigma toward the
    log's middle (the log shorter) and away from it [m]."""

    inward_m: float
    outward_m: float

    @property
    def scale_m(self) -> float:
        """The unit of the end's along variable (the two sigmas' geometric mean) [m]."""
        return math.sqrt(self.inward_m * self.outward_m)


@dataclass(frozen=True)
class LogEvidence:
    """What holds a log where it was placed: the sigmas of its ends' correction across its axis and in
    height [m] (the scan's, or its placement's), one for both ends or (butt, top), its kept survey points and,
    with the ends' places along the log in the estimate, their priors (butt, top); and the sigma of its radius
    [m] (None: ``JointConfig.sigma_radius_prior_m``; used only with ``JointConfig.radius_states``)."""

    sigma_across_m: float | tuple[float, float]
    sigma_up_m: float | tuple[float, float]
    pulls: tuple[SurveyPull, ...] = ()
    along: tuple[AlongPrior, AlongPrior] | None = None
    sigma_radius_m: float | None = None

    def scales(self) -> list[float]:
        """The sigmas of the four corrections (across at the butt, at the top, up at the butt, at the top) [m]."""
        ca, cb = _pair(self.sigma_across_m)
        ha, hb = _pair(self.sigma_up_m)
        return [ca, cb, ha, hb]

    def text(self) -> str:
        """Its scan sigmas in words (the larger end's), for a refusal."""
        words = (f"+-{max(_pair(self.sigma_across_m)) * 100:.1f} cm across, "
                 f"+-{max(_pair(self.sigma_up_m)) * 100:.1f} cm up")
        if self.along is not None:
            words += (f", its ends +-{self.along[0].inward_m * 100:.1f} / +-{self.along[1].inward_m * 100:.1f} cm "
                      "along toward its middle")
        return words


def _pair(v: float | tuple[float, float]) -> tuple[float, float]:
    return (float(v), float(v)) if np.isscalar(v) else (float(v[0]), float(v[1]))


def survey_pull(log: LogSpec, point: np.ndarray, sigma_across_m: float, sigma_up_m: float) -> SurveyPull:
    """A survey point against ``log``'s placed axis (butt to top)."""
    butt, top = log.endpoints_m()
    d = top - butt
    s = float((point - butt) @ d / float(d @ d))
    off = point - (butt + s * d)
    n = _across(d)
    return SurveyPull(s, float(off @ n), float(off[2]), sigma_across_m, sigma_up_m)


def _across(d: np.ndarray) -> np.ndarray:
    """The horizontal unit vector across an axis of direction ``d``."""
    n = np.array([-d[1], d[0], 0.0])
    return n / max(float(np.linalg.norm(n)), 1e-9)


def _robust(r: np.ndarray, scale: float) -> np.ndarray:
    """A residual whose square is the soft-L1 cost 2 f^2 (sqrt(1 + (r / f)^2) - 1) of ``scale`` f, its sign
    kept: r itself within f, growing as sqrt(2 f r) past it."""
    return np.sign(r) * scale * np.sqrt(2.0 * (np.sqrt(1.0 + (r / scale) ** 2) - 1.0))


class _Problem:
    """The least-squares problem: variables are each log's end corrections in units of their sigmas - four
    (across and up at the butt and the top), or six with the ends' places along the log (``along``: every
    log's evidence has them) - then, with ``obstacle_sigmas`` (one per obstacle, stumps first), each
    obstacle's shift in x and y and the erosion of its surface in units of its sigma
    (:mod:`reconstruct.fitting.joint_obstacles`), then with ``cfg.radius_states`` each log's radius change in
    units of its radius sigma (:mod:`reconstruct.fitting.joint_radius`)."""

    def __init__(self, pile: PileSpec, evidence: Sequence[LogEvidence], cfg: JointConfig,
                 obstacle_sigmas: Sequence[float] | None = None) -> None:
        self.pile, self.evidence, self.cfg = pile, list(evidence), cfg
        self.base = [log.endpoints_m() for log in pile.logs]
        self.across = [_across(b - a) for a, b in self.base]
        self.lengths = [float(np.linalg.norm(b - a)) for a, b in self.base]
        self.axes = [(b - a) / max(L, 1e-9) for (a, b), L in zip(self.base, self.lengths)]
        self.radii = [(log.diameter_m / 2, log.top_d_m / 2) for log in pile.logs]
        self.along = bool(self.evidence) and all(e.along is not None for e in self.evidence)
        self.width = 6 if self.along else 4
        self.scale = np.concatenate([e.scales() + ([p.scale_m for p in e.along] if self.along else [])
                                     for e in self.evidence])
        self.bodies = Bodies(pile, flat_stumps=cfg.flat_stumps)
        self.obstacle_sigmas = None if obstacle_sigmas is None else np.asarray(obstacle_sigmas, dtype=float)
        if self.obstacle_sigmas is not None:
            if len(self.obstacle_sigmas) != self.bodies.n_obstacles:
                raise ValueError(f"{len(self.obstacle_sigmas)} obstacle sigmas for {self.bodies.n_obstacles} obstacles")
            self.scale = np.concatenate([self.scale, np.repeat(self.obstacle_sigmas, N_STATES)])
        self.r0 = len(self.scale)  # the first radius state (== len(x) without radius states)
        self.radius_sigmas = None
        if cfg.radius_states:
            self.radius_sigmas = np.array([cfg.sigma_radius_prior_m if e.sigma_radius_m is None else e.sigma_radius_m
                                           for e in self.evidence])
            self.scale = np.concatenate([self.scale, self.radius_sigmas])
        self.terms: list[Term] = []

    @property
    def n(self) -> int:
        return len(self.base)

    @property
    def n_log_vars(self) -> int:
        return self.width * self.n

    def offsets(self, x: np.ndarray) -> np.ndarray | None:
        """Per obstacle (shift in x, in y, erosion) [m]; None without obstacle states."""
        if self.obstacle_sigmas is None:
            return None
        return (x[self.n_log_vars:self.r0] * self.scale[self.n_log_vars:self.r0]).reshape(-1, N_STATES)

    def radius_changes(self, x: np.ndarray) -> np.ndarray:
        """Per log, its radius change [m] (zeros without radius states)."""
        return x[self.r0:] * self.scale[self.r0:] if self.radius_sigmas is not None else np.zeros(self.n)

    def butt_radius_changes(self, x: np.ndarray) -> np.ndarray:
        """Per log, its butt radius change as the settled pile carries it (floored: ``radius_min_share``) [m]."""
        return np.array([changed_radius(r, dr, self.cfg.radius_min_share) - r
                         for (r, _), dr in zip(self.radii, self.radius_changes(x))])

    def corrections(self, x: np.ndarray) -> np.ndarray:
        """Per log (ca, cb, ha, hb, la, lb) [m]: across, up and along (toward the top) at the butt and the top."""
        X = (x[:self.n_log_vars] * self.scale[:self.n_log_vars]).reshape(-1, self.width)
        return X if self.along else np.hstack([X, np.zeros((self.n, 2))])

    def segments(self, x: np.ndarray) -> list[Segment]:
        C, dr = self.corrections(x), self.radius_changes(x)
        return [self._segment(k, C[k], dr[k]) for k in range(self.n)]

    def pose_segments(self, x: np.ndarray) -> list[Segment]:
        """The logs moved by their pose corrections alone (their radius changes not applied): what a log was
        moved, not how its axis rose as it was thinned with its top kept."""
        C = self.corrections(x)
        return [self._segment(k, C[k]) for k in range(self.n)]

    def _segment(self, k: int, c: np.ndarray, dr_m: float = 0.0) -> Segment:
        (a, b), n, u, (ra, rb) = self.base[k], self.across[k], self.axes[k], self.radii[k]
        ca, cb, ha, hb, la, lb = c
        return radius_segment(Segment(a + ca * n + ha * UP + la * u, b + cb * n + hb * UP + lb * u, ra, rb), dr_m,
                              self.cfg.radius_min_share)

    def along_residuals(self, x: np.ndarray, k: int) -> list[float]:
        """Log ``k``'s two ends' along priors (dimensionless): a butt moved toward the top, or a top toward
        the butt, makes the log shorter (its ``inward_m`` sigma)."""
        if not self.along:
            return []
        la, lb = self.corrections(x)[k, 4:]
        butt, top = self.evidence[k].along
        return [la / (butt.inward_m if la > 0 else butt.outward_m), lb / (top.inward_m if lb < 0 else top.outward_m)]

    def evidence_residuals(self, x: np.ndarray, k: int) -> np.ndarray:
        """Log ``k``'s scan prior, its ends' along priors and robust survey residuals at ``x`` (dimensionless).
        A survey point's offset across is taken where it lies along the moved log."""
        ca, cb, ha, hb, la, lb = self.corrections(x)[k]
        L = self.lengths[k]
        out = list(x[self.width * k:self.width * k + 4]) + self.along_residuals(x, k)
        if self.radius_sigmas is not None:  # its radius prior: its own evidence
            out.append(x[self.r0 + k])
        prior = len(out)
        for p in self.evidence[k].pulls:
            s = (p.s * L - la) / max(L + lb - la, 1e-9) if self.along else p.s
            out.append((p.across_m - ((1 - s) * ca + s * cb)) / p.sigma_across_m)
            out.append((p.up_m - ((1 - s) * ha + s * hb)) / p.sigma_up_m)
        return np.concatenate([out[:prior], _robust(np.asarray(out[prior:], dtype=float), self.cfg.survey_loss_sigmas)])

    def depths(self, term: Term, segs: Sequence[Segment], off: np.ndarray | None) -> np.ndarray:
        """A contact's depths [m], its obstacle (if any) moved by its state ``off``."""
        if off is None or term.kind != "obstacle":
            return self.bodies.depths(term, segs)
        return offset_depths(self.bodies, segs[term.i], term.j, off[term.j])

    def contact_depths(self, x: np.ndarray) -> list[np.ndarray]:
        """Per term: depths [m] over what it allows (> 0: interpenetrating beyond the prism's roll)."""
        segs, off = self.segments(x), self.offsets(x)
        return [self.depths(t, segs, off) - t.allow_m for t in self.terms]

    def obstacle_residuals(self, x: np.ndarray) -> np.ndarray:
        """The obstacles' priors (dimensionless): their states themselves (none without obstacle states)."""
        return np.asarray(x[self.n_log_vars:self.r0], dtype=float)

    def residuals(self, x: np.ndarray, contacts: bool) -> np.ndarray:
        parts = [self.evidence_residuals(x, k) for k in range(self.n)] + [self.obstacle_residuals(x)]
        if contacts:
            parts += [np.maximum(d, 0.0) / self.cfg.contact_sigma_m for d in self.contact_depths(x)]
        return np.concatenate(parts)

    def contact_residuals(self, term: Term, segs: Sequence[Segment], off: np.ndarray | None = None) -> np.ndarray:
        """A contact's residuals: its depths over what it allows, in ``contact_sigma_m`` (zero when apart)."""
        return np.maximum(self.depths(term, segs, off) - term.allow_m, 0.0) / self.cfg.contact_sigma_m

    def jacobian(self, x: np.ndarray, contacts: bool) -> np.ndarray:
        """The residuals' forward-difference Jacobian at ``x``, with scipy's own steps ('2-point'), each column
        from the rows its variable changes only: its log's evidence and the contacts that log is in (a pile's
        contacts each hold one or two of its logs, so this is a few times cheaper than every row per column)."""
        ev0 = [self.evidence_residuals(x, k) for k in range(self.n)] + [self.obstacle_residuals(x)]
        segs0, off0, C0, dr0 = self.segments(x), self.offsets(x), self.corrections(x), self.radius_changes(x)
        ct0 = [self.contact_residuals(t, segs0, off0) for t in self.terms] if contacts else []
        starts = np.cumsum([0] + [len(r) for r in ev0 + ct0])
        J = np.zeros((int(starts[-1]), len(x)))
        mine = [[m for m, t in enumerate(self.terms) if k in (t.i, t.j if t.kind == "log" else -1)]
                for k in range(self.n)]
        pressed = [[m for m, t in enumerate(self.terms) if t.kind == "obstacle" and t.j == j]
                   for j in range(self.bodies.n_obstacles)]
        sign = np.where(x >= 0, 1.0, -1.0)
        steps = (x + np.sqrt(np.finfo(float).eps) * sign * np.maximum(1.0, np.abs(x))) - x
        for v, h in enumerate(steps):
            xv = x.copy()
            xv[v] += h
            segs, off = list(segs0), off0
            if self.n_log_vars <= v < self.r0:  # an obstacle's state: its own prior and the contacts it is in
                o = v - self.n_log_vars
                J[starts[self.n] + o, v] = (xv[v] - x[v]) / h
                off, rows = self.offsets(xv), pressed[o // N_STATES]
            else:  # a log's pose or (from r0) its radius: its evidence and its contacts
                k = v // self.width if v < self.r0 else v - self.r0
                J[starts[k]:starts[k + 1], v] = (self.evidence_residuals(xv, k) - ev0[k]) / h
                c, dr = (self.corrections(xv)[k], dr0[k]) if v < self.r0 else (C0[k], self.radius_changes(xv)[k])
                segs[k] = self._segment(k, c, dr)
                rows = mine[k]
            if not contacts:
                continue
            for m in rows:
                r = self.contact_residuals(self.terms[m], segs, off)
                J[starts[self.n + 1 + m]:starts[self.n + 2 + m], v] = (r - ct0[m]) / h
        return J

    def solve(self, x0: np.ndarray, contacts: bool) -> np.ndarray:
        from scipy.optimize import least_squares

        return least_squares(self.residuals, x0, jac=self.jacobian, args=(contacts,), method="trf", xtol=1e-10,
                             ftol=1e-10, max_nfev=self.cfg.settle_max_evaluations).x

    def cost(self, x: np.ndarray, k: int) -> float:
        """Log ``k``'s evidence cost at ``x`` with, under obstacle states, that of each obstacle it is in
        contact with (a contact shared by a log and an obstacle costs both their evidence) and, under radius
        states, the radius prior of each log it is in contact with (a neighbour thinned to clear it)."""
        own = float(np.sum(self.evidence_residuals(x, k) ** 2))
        shared = sum(float(x[self.r0 + j]) ** 2 for j in self.logs_of(k))
        return own + sum(self.obstacle_cost(x, j) for j in self.obstacles_of(k)) + shared

    def logs_of(self, k: int) -> list[int]:
        """The other logs log ``k`` has a contact term with, under radius states (none without)."""
        if self.radius_sigmas is None:
            return []
        return sorted({t.j if t.i == k else t.i for t in self.terms if t.kind == "log" and k in (t.i, t.j)})

    def obstacles_of(self, k: int) -> list[int]:
        """The obstacles (with states) log ``k`` has a contact term with."""
        if self.obstacle_sigmas is None:
            return []
        return sorted({t.j for t in self.terms if t.kind == "obstacle" and t.i == k})

    def obstacle_cost(self, x: np.ndarray, j: int) -> float:
        """Obstacle ``j``'s prior cost at ``x`` (its state in units of its sigma, squared)."""
        o = self.n_log_vars + N_STATES * j
        return float(np.sum(x[o:o + N_STATES] ** 2))

    def along_moves(self, x: np.ndarray, x_free: np.ndarray, k: int) -> tuple[float, float]:
        """How far the bodies moved log ``k``'s butt and top along it, toward its middle (+) [m]."""
        (la, lb), (fa, fb) = self.corrections(x)[k, 4:], self.corrections(x_free)[k, 4:]
        return float(la - fa), float(fb - lb)

    def moved_pile(self, x: np.ndarray, rolls: Sequence[float]) -> PileSpec:
        logs = []
        dr = self.radius_changes(x)
        for k, (log, seg, roll) in enumerate(zip(self.pile.logs, self.segments(x), rolls)):
            d = seg.b - seg.a
            L = float(np.linalg.norm(d))
            if L < MIN_LOG_LENGTH_M:  # the bodies would shorten it to nothing: its ends' evidence is no evidence
                raise SeparationError(f"log {k} would have to be shortened to {L:.2f} m to clear the bodies around "
                                      f"it (a log is at least {MIN_LOG_LENGTH_M} m); its fit or its GNSS end points "
                                      "are wrong", logs=(k,))
            logs.append(resized_log(replace(log, centre_m=tuple(float(v) for v in (seg.a + seg.b) / 2), length_m=L,
                                            orientation=tuple(float(v) for v in quat_from_x_axis(d / L, roll))),
                                    float(dr[k]), self.cfg.radius_min_share))
        off = self.offsets(x)
        pile = self.pile if off is None else moved_obstacles(self.pile, off)
        return pile.with_logs(tuple(logs))


def settle_pile(pile: PileSpec, evidence: Sequence[LogEvidence], cfg: JointConfig, tolerance_m: float,
                roll_steps: int, obstacle_sigmas: Sequence[float] | None = None
                ) -> tuple[Cleared, list[tuple[np.ndarray, np.ndarray]]]:
    """``pile``'s logs moved to the estimate of what holds each (``evidence``, per log) and the other bodies,
    checked in the twin to ``tolerance_m`` (``roll_steps`` rolls tried per touching log). Returns what was
    done (:class:`Cleared`: the pile, notes, each log's move by the bodies [m]) and each log's end centres
    (butt, top) without the bodies. Raises :class:`SeparationError` for a log the bodies move farther than
    its evidence allows, or that the twin still finds in another body. ``obstacle_sigmas`` (one per obstacle,
    stumps first; :func:`reconstruct.fitting.joint_obstacles.obstacle_sigmas`): each obstacle a state of the
    estimate with that sigma (None: the obstacles are fixed bodies, revision 12)."""
    prob = _Problem(pile, evidence, cfg, obstacle_sigmas)
    x_free = prob.solve(np.zeros(len(prob.scale)), contacts=False)
    prob.terms = prob.bodies.terms(prob.segments(x_free), cfg.contact_reach_m)
    rolls = [0.0] * prob.n
    x = x_free
    for round_ in range(cfg.twin_rounds):
        x = prob.solve(x, contacts=True)
        _refuse(prob, x, x_free, tolerance_m)
        moved = prob.moved_pile(x, rolls)
        bad = _twin_check(moved, rolls, tolerance_m, roll_steps)
        if not bad:
            return _cleared(prob, x, x_free, rolls), [(s.a, s.b) for s in prob.segments(x_free)]
        _allow_less(prob, bad, last=round_ >= cfg.twin_rounds - 2)
    i, other, depth = bad[0]
    raise SeparationError(f"log {i} still runs {depth * 100:.1f} cm into {other.other(i)} at its estimate (tolerance "
                          f"{tolerance_m * 100:.0f} cm); its fit or its GNSS end points are wrong",
                          logs=(i,) + ((other.j,) if other.kind == "log" else ()))  # i < j: the pair


def _refuse(prob: _Problem, x: np.ndarray, x_free: np.ndarray, tolerance_m: float) -> None:
    """Raise :class:`SeparationError` for the log whose evidence the bodies cost most, when that is over
    ``refuse_sigma`` squared, or for a contact the estimate leaves deeper than ``tolerance_m``."""
    cfg = prob.cfg
    extra = [prob.cost(x, k) - prob.cost(x_free, k) for k in range(prob.n)]
    depths = prob.contact_depths(x)
    k = int(np.argmax(extra))
    if extra[k] <= cfg.refuse_sigma ** 2 and all(d.max() <= tolerance_m for d in depths):
        return
    if extra[k] <= cfg.refuse_sigma ** 2:
        t = max(range(len(depths)), key=lambda m: depths[m].max())
        k = prob.terms[t].i
    term = _pressing(prob, x_free, k)
    other = term.other(k)
    seg, free = prob.pose_segments(x)[k], prob.pose_segments(x_free)[k]
    move = max(float(np.linalg.norm(seg.a - free.a)), float(np.linalg.norm(seg.b - free.b)))
    others = () if term.kind != "log" else (term.j if term.i == k else term.i,)
    off, dr = prob.offsets(x), prob.butt_radius_changes(x)[k]
    radius = ("" if prob.radius_sigmas is None else
              f", its radius +-{prob.radius_sigmas[k] * 100:.1f} cm, {-dr * 2000:.1f} mm thinner")
    shared = "".join(f", obstacle {j}'s (+-{prob.obstacle_sigmas[j] * 100:.1f} cm, {off[j, 2] * 100:.1f} cm smaller, "
                     f"{math.hypot(off[j, 0], off[j, 1]) * 100:.1f} cm moved)" for j in prob.obstacles_of(k))
    raise SeparationError(
        f"log {k} would have to move {move * 100:.1f} cm to clear {other}, {math.sqrt(max(extra[k], 0.0)):.1f} sigma "
        f"of what its scan ({prob.evidence[k].text()}{radius}) and survey points{shared} allow (limit "
        f"{cfg.refuse_sigma:.0f} sigma); its fit or its GNSS end points are wrong", logs=(k,) + others)


def _pressing(prob: _Problem, x_free: np.ndarray, k: int) -> Term:
    """The contact of log ``k`` that overlaps most where its evidence alone puts it."""
    depths = prob.contact_depths(x_free)
    mine = [m for m, t in enumerate(prob.terms) if k in (t.i, t.j if t.kind == "log" else -1)]
    if not mine:
        return Term(k, "terrain", -1, 0.0)
    return prob.terms[max(mine, key=lambda m: depths[m].max())]


def _twin_check(pile: PileSpec, rolls: list[float], tolerance_m: float, roll_steps: int
                ) -> list[tuple[int, Term, float]]:
    """Each log touching another body deeper than ``tolerance_m`` turned to its best roll (``rolls`` updated),
    then what the twin still finds interpenetrating: (log, the contact as a term, depth [m])."""
    from synth.physics.world import World

    with World(pile, visuals=False) as world:
        for i, body in enumerate(world.log_ids):
            if roll_steps > 0 and world.deepest_contact(i)[0] > tolerance_m:
                roll, _, _ = best_roll(world, body, world.pile.logs[i], roll_steps)
                if roll is not None:
                    rolls[i] = roll
        found = world.penetrations(tolerance_m)
    return [_as_term(a, b, depth) for a, b, depth in found]


def _as_term(a: str, b: str, depth: float) -> tuple[int, Term, float]:
    """A twin penetration ("log i" / "log j", "obstacle j" or "terrain") as (log, term, depth)."""
    names = sorted((a, b), key=lambda n: (not n.startswith("log "), n))
    i = int(names[0].split()[1])
    kind, _, j = names[1].partition(" ")
    if kind == "log":
        i, j_ = sorted((i, int(j)))
        return i, Term(i, "log", j_, 0.0), depth
    return i, Term(i, kind, int(j) if j else -1, 0.0), depth


def _allow_less(prob: _Problem, bad: list[tuple[int, Term, float]], last: bool) -> None:
    """Each contact the twin still finds allowed its depth (and a margin) less overlap; none at all on the
    ``last`` round (round surfaces that clear hold prisms that clear)."""
    for _, found, depth in bad:
        term = next((t for t in prob.terms if (t.i, t.kind, t.j) == (found.i, found.kind, found.j)), None)
        if term is None:
            term = Term(found.i, found.kind, found.j, 0.0)
            prob.terms.append(term)
        term.allow_m = 0.0 if last else max(0.0, term.allow_m - depth - SEPARATION_MARGIN_M)


def _cleared(prob: _Problem, x: np.ndarray, x_free: np.ndarray, rolls: Sequence[float]) -> Cleared:
    """The settled pile, a note per log the bodies moved, and each log's move by the bodies [m]."""
    notes, moved = [], []
    segs, free = prob.pose_segments(x), prob.pose_segments(x_free)
    for k, (s, f) in enumerate(zip(segs, free)):
        move = max(float(np.linalg.norm(s.a - f.a)), float(np.linalg.norm(s.b - f.b)))
        moved.append(move)
        if move >= REPORT_MOVE_M:
            extra = math.sqrt(max(prob.cost(x, k) - prob.cost(x_free, k), 0.0))
            along = [f"its {end} {abs(d) * 1000:.1f} mm {'in' if d > 0 else 'out'} along it"
                     for end, d in zip(("butt", "top"), prob.along_moves(x, x_free, k)) if abs(d) >= REPORT_MOVE_M]
            notes.append(f"log {k} moved {move * 1000:.1f} mm ({extra:.1f} sigma of its evidence) clear of "
                         f"{_pressing(prob, x_free, k).other(k)}" + (f" ({', '.join(along)})" if along else ""))
    off = prob.offsets(x)
    if off is not None:
        depths = prob.contact_depths(x_free)
        presses = [max(((depths[m].max(), t.i) for m, t in enumerate(prob.terms) if t.kind == "obstacle" and t.j == j),
                       default=(0.0, None))[1] for j in range(len(off))]
        notes += obstacle_notes(off, prob.obstacle_sigmas, presses)
    if prob.radius_sigmas is not None:
        notes += radius_notes(prob.butt_radius_changes(x), prob.radius_sigmas, prob.pile.logs)
    return Cleared(prob.moved_pile(x, rolls), [], notes, moved, {})


def along_priors(log: LogSpec, ends: Sequence[dict] | None, cfg: JointConfig) -> tuple[AlongPrior, AlongPrior]:
    """The priors on ``log``'s butt and top places along it, from its end estimates (``ends``, either order:
    each is the log end it lies at): their ``sigma_along_in_m`` / ``sigma_along_out_m``
    (:func:`reconstruct.fitting.joint_ends.along_sigmas`). An end without them (none placed) keeps its
    place as surely as an end can be known (``min_end_sigma_m``)."""
    floor = AlongPrior(cfg.min_end_sigma_m, cfg.min_end_sigma_m)
    out = [floor, floor]
    butt_top = log.endpoints_m()
    for e in ends or ():
        if e.get("sigma_along_in_m") is None:
            continue
        pos = np.asarray(e["position_m"], dtype=float)
        m = min((0, 1), key=lambda n: float(np.linalg.norm(butt_top[n] - pos)))
        out[m] = AlongPrior(float(e["sigma_along_in_m"]), float(e["sigma_along_out_m"]))
    return out[0], out[1]


class JointSettler:
    """``fit_pile``'s ``settle`` for the joint estimator: each log's evidence from how it was placed and its
    kept survey points (``survey_ends``: per log id, its points in the pile frame; ``lateral``: per log id,
    its placement's sigma across [m]), :func:`settle_pile`, and each end moved to where the scan and the
    survey put it without the bodies (the pipeline then takes it to the settled log's end, its sigma grown
    by that last move: :func:`reconstruct.fitting.joint_ends.joint_after_check`).

    ``points``: the scan (pile frame) and ``band_m`` how near a log's surface a point is on it: with
    ``cfg.per_log_sigma`` each log fitted to the scan gets its own sigma from the points on its surface that
    no other log explains (:func:`reconstruct.fitting.joint_scan_sigma.scan_sigma`); without points, or with
    it off, every such log gets ``settle_scan_sigma_m`` (revision 10). ``sigmas`` keeps each log's, by id."""

    def __init__(self, survey_ends: dict, lateral: dict[str, float], cfg: JointConfig, tolerance_m: float,
                 roll_steps: int, points: np.ndarray | None = None, band_m: float = 0.015) -> None:
        self.survey_ends, self.lateral, self.cfg = survey_ends, lateral, cfg
        self.tolerance_m, self.roll_steps = tolerance_m, roll_steps
        self.points, self.band_m = points, band_m
        self.sigmas: dict[str, Any] = {}

    def evidence(self, log: LogSpec, lf, own: np.ndarray | None = None, near: np.ndarray | None = None,
                 cfg: JointConfig | None = None) -> LogEvidence:
        """``log``'s evidence (``lf``: its fit report; ``own``: the scan points on its surface and no other's;
        ``near``: with radius states, the scan points no other log's surface claims, for its radius sigma's
        misfit: :func:`reconstruct.fitting.joint_scan_sigma.radius_misfit`; ``cfg``: default the settler's)."""
        from reconstruct.fitting.ends import axis_sigma_m
        from reconstruct.fitting.joint_scan_sigma import scan_sigma

        cfg = cfg or self.cfg
        ends_k = self.survey_ends.get(lf.log_id, (None, None))
        if lf.fit == "scan" and own is not None:
            sig = self.sigmas[lf.log_id] = scan_sigma(own, log, self.band_m, cfg, near)
            across, up, radius = sig.across_m, sig.up_m, sig.radius_m
        else:
            radius = None  # not fitted to the scan: sigma_radius_prior_m
            across = up = max(axis_sigma_m(lf.fit, self.lateral.get(lf.log_id, 0.0), ends_k),
                              cfg.settle_scan_sigma_m)
        pulls = [survey_pull(log, pt.position_m, math.hypot(pt.sigma_h_m, cfg.pose_sigma_m),
                             math.hypot(pt.sigma_v_m, cfg.pose_sigma_m))
                 for pt, e in zip(ends_k, lf.ends or (None, None))
                 if pt is not None and not (e or {}).get("contradicted")]
        along = along_priors(log, lf.ends, cfg) if cfg.along_ends else None
        return LogEvidence(across, up, tuple(pulls), along, radius)

    def own_points(self, pile: PileSpec, cfg: JointConfig | None = None
                   ) -> tuple[list[np.ndarray | None], list[np.ndarray | None]]:
        """Per log, the scan points on its surface that no other log's explains, and (with ``radius_states``)
        those and the points on no log's surface, for its radius sigma's misfit (None: no points given,
        ``per_log_sigma`` off, or radius states off; ``cfg``: default the settler's)."""
        from reconstruct.fitting.geometry import _owners

        cfg = cfg or self.cfg
        none: list[np.ndarray | None] = [None] * len(pile.logs)
        if self.points is None or not cfg.per_log_sigma:
            return none, none
        P = np.asarray(self.points, dtype=float)
        P = P[np.all(np.isfinite(P), axis=1)]
        owner = _owners(P, pile.logs, self.band_m)
        own: list[np.ndarray | None] = [P[owner == k] for k in range(len(pile.logs))]
        if not cfg.radius_states:
            return own, none
        return own, [P[(owner == k) | (owner < 0)] for k in range(len(pile.logs))]

    def __call__(self, pile: PileSpec, fits: Sequence) -> Cleared:
        """The pile settled (:func:`settle_pile`), with the radii as states only to rescue a refusal
        (``radius_rescue``: :func:`reconstruct.fitting.joint_rescue.settle_or_rescue`)."""
        return settle_or_rescue(lambda cfg: self.settle(pile, fits, cfg), fits, self.survey_ends, self.cfg)

    def settle(self, pile: PileSpec, fits: Sequence, cfg: JointConfig) -> Cleared:
        own, near = self.own_points(pile, cfg)
        evidence = [self.evidence(log, lf, pts, nr, cfg) for log, lf, pts, nr in zip(pile.logs, fits, own, near)]
        sigmas = obstacle_sigmas(pile, self.points, cfg) if cfg.obstacle_states else None
        cleared, free = settle_pile(pile, evidence, cfg, self.tolerance_m, self.roll_steps, sigmas)
        for k, lf in enumerate(fits):
            for j, e in enumerate(lf.ends or []):
                pos = np.asarray(e["position_m"], dtype=float)
                m = min((0, 1), key=lambda n: float(np.linalg.norm(free[k][n] - pos)))
                cleared.at_survey[(k, j)] = dict(e, position_m=[float(v) for v in free[k][m]])
                if lf.log_id in self.sigmas:  # the scan's sigma at this end (butt or top), for the report
                    sig = self.sigmas[lf.log_id]
                    cleared.at_survey[(k, j)]["scan_sigma_m"] = {"across": sig.across_m[m], "up": sig.up_m[m]}
        return cleared
