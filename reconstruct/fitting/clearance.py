"""A pile the twin accepts, by moving an uncertain log end within its own uncertainty.

The twin's pile check (:func:`reconstruct.fitting.fit.separate_logs`) clears the small
interpenetrations that fit noise leaves, and refuses (``SeparationError``) when a log would have to
move farther than noise explains. Such a log is usually not badly *fitted* but badly *ended*: an end
placed from an RTK-float point (±20-30 cm) under other logs, where the scan cannot see it, lies
inside a neighbour; or the scan's walk along a log ran on over a stump beside its end and put the end
past an RTK-fixed point that the scan was then trusted over (the cases: docs/reconstruction.md,
"The cases behind the rules").

Both are estimates with a stated uncertainty, and the twin's check is evidence too: two bodies
cannot share space. :func:`clear_pile` therefore, for a log the check refuses, tries where else its
ends may lie — a contradicted end at its survey point after all (the scan's reading is what the pile
refutes), an end placed to σ at offsets of up to ``max_sigma`` σ along the log and across it
(horizontally) — in order of how unlikely each is (the offset in σ), and keeps the most likely one
at which the log clears everything but what the ordinary check takes. Every such change is a note
in the report, and the end's estimate records where the check left it (its σ grows by the move:
:func:`reconstruct.fitting.fuse.after_pile_check`). A log no end move clears stays the error it was.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from reconstruct.errors import SeparationError
from reconstruct.fitting.ends import MIN_LOG_LENGTH_M
from synth.scene.pile import LogSpec, PileSpec

#: Offsets tried, in units of the end's sigma, along and across the log (0.5 sigma steps).
OFFSET_STEPS = np.arange(-5, 6) * 0.5
FIX_LABEL = {"rtk_fixed": "fixed"}


@dataclass(frozen=True)
class ClearanceConfig:
    """How far an end may be moved to clear the pile, and what counts as cleared."""

    max_sigma: float = 2.5  # an end moves at most this many of its sigmas (Mahalanobis, along and across) [-]
    min_sigma_m: float = 0.02  # ends surer than this are not moved by their sigma (the ordinary check's job) [m]
    residual_depth_m: float = 0.045  # a moved log may still interpenetrate this deep (the ordinary check takes it) [m]
    max_rounds: int = 4  # logs re-ended per pile, at most [-]

    def __post_init__(self) -> None:
        if not self.max_sigma > 0 or not self.min_sigma_m > 0 or self.residual_depth_m < 0 or self.max_rounds < 0:
            raise ValueError("max_sigma and min_sigma_m must be > 0, residual_depth_m and max_rounds >= 0")


@dataclass(frozen=True)
class _Candidate:
    cost: float  # offset in sigmas (0: the survey point of a contradicted end)
    log: LogSpec
    end: int  # 0: end a, 1: end b (survey order)
    shift_m: float
    how: str  # "survey" or "sigma"


@dataclass
class Cleared:
    """A pile the twin accepts, and how it got there."""

    pile: PileSpec
    end_moves: list[str]  # each end the check moved within its uncertainty (or to its survey point), and why
    notes: list[str]  # the ordinary check's turns, thinnings and moves
    moved: list[float]  # per log: how far it moved [m] (its end moves included)
    at_survey: dict[tuple[int, int], dict]  # {(log, end): its estimate} for ends now at their survey point


def clear_pile(pile: PileSpec, ends: Sequence[Sequence[dict]], separate: Callable, cfg: ClearanceConfig | None = None,
               ) -> Cleared:
    """``separate(pile)`` (the twin's check: returns the pile, its notes and each log's move), and when
    it refuses a log, that log (or the other of the contact) re-ended within its uncertainty first.
    ``ends``: per log of ``pile``, its two end estimates (``EndEstimate.to_dict``, survey order;
    empty when unknown)."""
    cfg = cfg or ClearanceConfig()
    notes: list[str] = []
    shifted = [0.0] * pile.n_logs
    updates: dict[tuple[int, int], dict] = {}
    for _ in range(cfg.max_rounds + 1):
        try:
            out, sep_notes, moved = separate(pile)
        except SeparationError as exc:
            found = next((c for c in (_best_end_move(pile, k, ends[k], cfg) for k in exc.logs if k < len(ends))
                          if c is not None), None) if len(notes) < cfg.max_rounds else None
            if found is None:
                raise
            k, cand, why = found
            pile = pile.with_logs(tuple(cand.log if i == k else lg for i, lg in enumerate(pile.logs)))
            shifted[k] = max(shifted[k], cand.shift_m)
            notes.append(_note(k, cand, ends[k][cand.end], why))
            if cand.how == "survey":
                updates[(k, cand.end)] = _at_survey_point(ends[k][cand.end], why)
            continue
        return Cleared(out, notes, sep_notes, [math.hypot(m, s) for m, s in zip(moved, shifted)], updates)
    raise AssertionError("unreachable: the loop returns or raises")


def _best_end_move(pile: PileSpec, k: int, ends_k: Sequence[dict], cfg: ClearanceConfig):
    """The most likely place of log ``k``'s ends at which it clears the pile (to
    ``residual_depth_m``): (k, the candidate, what it ran into where it was), or None."""
    from synth.physics.world import World

    cands = sorted(_candidates(pile.logs[k], ends_k, cfg), key=lambda c: c.cost)
    if not cands:
        return None
    with World(pile, visuals=False) as world:
        depth0, other = world.deepest_contact(k)
        if depth0 <= cfg.residual_depth_m:  # not this log's end: its own contacts are what the check clears
            return None
        why = f"it ran {depth0 * 100:.1f} cm into {_name(world, other)}"
        for cand in cands:
            world.replace_log(k, cand.log)
            if world.deepest_contact(k)[0] <= cfg.residual_depth_m:
                return k, cand, why
    return None


def _candidates(log: LogSpec, ends_k: Sequence[dict], cfg: ClearanceConfig) -> list[_Candidate]:
    """Log ``log`` with one end moved: a contradicted end to its survey point; an end known to
    ``min_sigma_m`` or worse to offsets along / across the log within ``max_sigma`` of its sigma."""
    if len(ends_k) != 2:
        return []
    butt, top = log.endpoints_m()
    out = []
    for j, e in enumerate(ends_k):
        pos = np.asarray(e["position_m"], dtype=float)
        mine_is_butt = np.linalg.norm(pos - butt) <= np.linalg.norm(pos - top)
        here, there = (butt, top) if mine_is_butt else (top, butt)
        if e.get("contradicted") and e.get("gnss_position_m") is not None:
            point = np.asarray(e["gnss_position_m"], dtype=float)
            out.append(_moved(log, mine_is_butt, there, point, 0.0, j, "survey"))
        s_along = float(e.get("sigma_along_m") or e["sigma_m"])
        # sigma_m^2 = along^2 + 2 across^2 (fuse_end); an estimate with no across part moves across by its along one
        s_across = math.sqrt(max(float(e["sigma_m"]) ** 2 - s_along ** 2, 0.0) / 2) or s_along
        if float(e["sigma_m"]) < cfg.min_sigma_m:
            continue
        u = (here - there) / max(float(np.linalg.norm(here - there)), 1e-9)  # outward at this end
        n = np.array([-u[1], u[0], 0.0]) / max(math.hypot(u[0], u[1]), 1e-9)  # across, horizontal
        for a in OFFSET_STEPS:
            for c in OFFSET_STEPS:
                cost = math.hypot(a, c)
                if 0 < cost <= cfg.max_sigma:
                    out.append(_moved(log, mine_is_butt, there, here + a * s_along * u + c * s_across * n, cost, j,
                                      "sigma"))
    return [c for c in out if c is not None]


def _moved(log: LogSpec, moving_butt: bool, fixed_end: np.ndarray, new_end: np.ndarray, cost: float, j: int,
           how: str) -> _Candidate | None:
    """``log`` with its butt (``moving_butt``) or top at ``new_end``, the other end kept; None when the two
    ends come closer than ``MIN_LOG_LENGTH_M``."""
    butt, top = log.endpoints_m()
    if float(np.linalg.norm(new_end - fixed_end)) < MIN_LOG_LENGTH_M:
        return None
    b, t = (new_end, fixed_end) if moving_butt else (fixed_end, new_end)
    shift = float(np.linalg.norm(new_end - (butt if moving_butt else top)))
    return _Candidate(cost, LogSpec.from_endpoints(b, t, log.diameter_m, log.top_diameter_m, log.colour), j, shift, how)


def _name(world, body: int | None) -> str:
    if body is None:
        return "nothing"
    if body == world.terrain_id:
        return "the terrain"
    if body in world.log_ids:
        return f"log {world.log_ids.index(body)}"
    return f"obstacle {world.obstacle_ids.index(body)}" if body in world.obstacle_ids else f"body {body}"


def _note(k: int, cand: _Candidate, e: dict, why: str) -> str:
    end = "ab"[cand.end]
    if cand.how == "survey":
        return (f"log {k}: end {end} placed at its survey point ({e.get('gnss_fix')}) after all, "
                f"{cand.shift_m * 100:.1f} cm from where the scan put it: there {why}")
    return (f"log {k}: end {end} ({e['source']}, +-{e['sigma_m'] * 100:.0f} cm) moved {cand.shift_m * 100:.1f} cm "
            f"({cand.cost:.1f} sigma) within its uncertainty: where it was placed {why}")


def _at_survey_point(e: dict, why: str) -> dict:
    """End estimate ``e`` as placed at its survey point by the pile check: the point's source and
    sigma, no longer contradicted (the scan's reading is what the pile refuted)."""
    return dict(e, position_m=list(e["gnss_position_m"]), source=FIX_LABEL.get(e.get("gnss_fix"), "float"),
                sigma_m=float(e["gnss_sigma_m"]), sigma_along_m=float(e["gnss_sigma_m"]), contradicted=False,
                gnss_residual_m=0.0, gnss_residual_sigma=0.0,
                pile_check=f"placed at its survey point: the scan's end {why}")
