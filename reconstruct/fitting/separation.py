"""Logs that interpenetrate other bodies in the twin cleared, the worst contact first (:func:`separate_logs`).

Each log of a contact is first turned about its own axis (the twin's log collides as a pentagonal prism
inside the round surface the scan sees, so its roll is not known); a log fitted to its scan points may then
be made thinner with its top kept, as far as its radius is uncertain (the scan sees its top, and of two
stacked logs an overlap is the upper one's radius error; ``max_thinning_m``, off by default: measured, it
thinned logs already too thin); what is left is moved out along the contact normal by the penetration
depth (lifted when stacked, pushed apart when side by side). Every turn, thinning and move is reported."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from reconstruct.errors import FitError, SeparationError
from reconstruct.fitting.fit_config import FitConfig
from synth.scene.pile import LogSpec, PileSpec


# the twin's log collides as a prism of this many sides (its roll repeats every 1/this turn) [-]
PRISM_SIDES = 5
# a roll is taken only when it makes the deepest contact at least this much shallower [m]
MIN_ROLL_GAIN_M = 1e-3
# the check looks again at most this many times per log, plus this many [-]
ROUNDS_PER_LOG = 10
EXTRA_ROUNDS = 5
# thinning room or thinning under this is none [m]
MIN_THINNING_M = 1e-4
# a contact is cleared this far beyond its depth [m]
SEPARATION_MARGIN_M = 0.002
# a move this steep (its vertical share) is reported as a lift [-]
LIFT_MIN_UP = 0.7
# pybullet's getContactPoints fields: the other body, the contact normal on it (towards the first), the
# signed distance [m]
CONTACT_BODY_B, CONTACT_NORMAL_ON_B, CONTACT_DISTANCE = 2, 7, 8
# a contact between two logs whose normal is at least this horizontal (squared horizontal part of the
# unit normal; 0.5: within 45 deg of horizontal) is side by side: both are pushed apart [-]
SIDE_CONTACT_MIN_H2 = 0.5


# a log is thinned to clear a contact only where that takes at least this much depth per unit of radius
# (1 + the contact normal's part along its up-across direction: 2 lying on the other, 1 beside it, 0
# under it, where its top, kept, is what meets the other) [-]
MIN_THINNING_GAIN = 0.5


# a log is turned about its axis to clear its contacts at most this many times (the turns of two logs
# in contact could otherwise undo each other) [-]
MAX_ROLLS_PER_LOG = 2


def _up_across(log: LogSpec) -> np.ndarray:
    """The unit vector across ``log``'s axis in the vertical plane through it, pointing up: where its
    axis goes when it is thinned with its top kept."""
    u = log.axis()
    w = np.array([0.0, 0.0, 1.0]) - u[2] * u
    n = float(np.linalg.norm(w))
    return w / n if n > 1e-6 else np.array([1.0, 0.0, 0.0])


def thinned_keeping_top(log: LogSpec, by_m: float) -> LogSpec:
    """``log`` with both its diameters ``2 * by_m`` smaller and its axis ``by_m`` higher (across the
    axis, in the vertical plane): the top stays where it was."""
    p0, p1 = log.endpoints_m()
    up = by_m * _up_across(log)
    return LogSpec.from_endpoints(p0 + up, p1 + up, log.diameter_m - 2 * by_m,
                                  None if log.top_diameter_m is None else log.top_diameter_m - 2 * by_m, log.colour)


def _thinning_split(need_m: float, gains: Sequence[float], room: Sequence[float]) -> list[float]:
    """How much to thin each of the logs in one contact (radius, [m]) to take ``need_m`` of its depth:
    log k's thinning by d takes ``gains[k] * d`` (1 + the part of the contact normal, toward k, along
    k's up-across direction: 2 for the upper of two stacked logs, 1 side by side, 0 for the lower);
    the least total thinning (each in proportion to its gain), each at most ``room[k]``; a log with a gain
    under :data:`MIN_THINNING_GAIN` is not thinned."""
    out = [0.0] * len(gains)
    free = [k for k in range(len(gains)) if gains[k] >= MIN_THINNING_GAIN and room[k] > 0]
    left = need_m
    while free and left > 1e-6:
        g2 = sum(gains[k] ** 2 for k in free)
        want = {k: left * gains[k] / g2 for k in free}
        capped = [k for k in free if want[k] >= room[k] - out[k]]
        if not capped:
            for k in free:
                out[k] += want[k]
            break
        for k in capped:  # these take all they can; the rest is shared by the others
            left -= gains[k] * (room[k] - out[k])
            out[k] = room[k]
        free = [k for k in free if k not in capped]
    return out


def best_roll(world: Any, body: int, log: LogSpec, steps: int) -> tuple[float | None, float, float]:
    """The roll about its own axis, of ``steps`` over the prism's 72 deg period, at which log ``log`` (body
    ``body`` of ``world``) meets any body least deep (the twin's log is a pentagonal prism to the physics and
    round to the eye: the scan cannot tell its roll). Returns that roll [rad] (None when no roll does better
    by 1 mm than the log's own orientation) and its deepest contact before and after [m, <= 0]. The body is
    left at the returned roll."""
    from synth.scene.pile import quat_from_x_axis

    c = world.client

    def deepest() -> float:
        c.performCollisionDetection()
        return min((cp[CONTACT_DISTANCE] for cp in c.getContactPoints(bodyA=body)), default=0.0)

    before = deepest()
    best, best_roll_rad = before, None
    for k in range(steps):
        roll = 2 * math.pi / PRISM_SIDES * k / steps
        c.resetBasePositionAndOrientation(body, list(log.centre_m), list(quat_from_x_axis(log.axis(), roll)))
        d = deepest()
        if d > best + MIN_ROLL_GAIN_M:
            best, best_roll_rad = d, roll
    q = log.orientation if best_roll_rad is None else quat_from_x_axis(log.axis(), best_roll_rad)
    c.resetBasePositionAndOrientation(body, list(log.centre_m), list(q))
    return best_roll_rad, before, (before if best_roll_rad is None else best)


def _roll_to_clear(world: Any, body: int, log: LogSpec, steps: int) -> tuple[LogSpec, float, float]:
    """``log`` turned to its :func:`best_roll`: the log at that roll (as it was when no roll does better by
    1 mm) and its deepest contact before and after [m, <= 0]. The body is left at the returned roll."""
    from synth.scene.pile import quat_from_x_axis

    roll, before, best = best_roll(world, body, log, steps)
    if roll is None:
        return log, before, before
    return replace(log, orientation=tuple(float(v) for v in quat_from_x_axis(log.axis(), roll))), before, best


def separate_logs(pile: PileSpec, cfg: FitConfig | None = None, thinnable: Sequence[bool] | None = None,
                  ) -> tuple[PileSpec, list[str], list[float]]:
    """Clear logs that interpenetrate other bodies (fit noise), the worst contact first, until the
    twin accepts the pile. A ``thinnable`` log (one fitted to its scan points: its top is what the scan
    saw, its radius known to ``max_thinning_m`` only) is first made thinner with its top kept, by at
    most ``max_thinning_m`` in all: of two logs stacked with both tops seen, an overlap is the upper
    one's radius error. What thinning cannot take, a move takes: out along the contact normal by the
    remaining depth (two logs side by side, the contact normal within 45 deg of horizontal, are each
    pushed half the way apart, horizontally; of two stacked logs the upper one is lifted).
    Returns the pile, what was done, and how far each log moved [m] (its thinning:
    the pile's diameters). Raises :class:`FitError` when a log would have to move more than ``max_move_m``."""
    from synth.physics.world import World

    cfg = cfg or FitConfig()
    st = _Separation.start(pile.n_logs, cfg, thinnable)
    for _ in range(ROUNDS_PER_LOG * pile.n_logs + EXTRA_ROUNDS):
        with World(pile) as world:
            contact = _worst_contact(world, cfg)
            if contact is None:
                return pile, st.notes, [float(np.linalg.norm(m)) for m in st.moves]
            turned = _roll_contact(world, pile, contact, cfg, st)
        if turned is None:
            turned = _thin_contact(pile, contact, cfg, st)
        pile = turned if turned is not None else _move_contact(pile, contact, cfg, st)
    raise FitError("could not separate the reconstructed logs; check the fits")


@dataclass
class _Separation:
    """What :func:`separate_logs` has done so far, per log: moves [m], thinning room and thinning [m],
    turns about the axis, and the notes for the report."""

    moves: list[np.ndarray]
    thin_room: list[float]
    thinned: list[float]
    rolled: list[int]
    notes: list[str]

    @classmethod
    def start(cls, n_logs: int, cfg: FitConfig, thinnable: Sequence[bool] | None) -> "_Separation":
        room = [cfg.max_thinning_m if thinnable is not None and thinnable[k] else 0.0 for k in range(n_logs)]
        return cls([np.zeros(3) for _ in range(n_logs)], room, [0.0] * n_logs, [0] * n_logs, [])


@dataclass(frozen=True)
class _Contact:
    """The deepest interpenetration of a log: its signed distance [m] (< 0), the log, the other body's
    id, the contact normal (from the other body towards the log), the bodies' names and log indices."""

    dist: float
    log: int
    other: int
    normal: np.ndarray
    names: dict
    log_of: dict

    @property
    def other_log(self) -> int | None:
        return self.log_of.get(self.other)

    @property
    def other_name(self) -> str:
        return self.names.get(self.other, str(self.other))


def _worst_contact(world, cfg: FitConfig) -> _Contact | None:
    """The deepest contact beyond tolerance in ``world``, or None when the twin accepts the pile
    (raises :class:`FitError` when it still finds the pile not physical)."""
    from synth.errors import PileValidationError

    names = {world.terrain_id: "terrain"}
    names.update({b: f"log {i}" for i, b in enumerate(world.log_ids)})
    names.update({b: f"obstacle {j}" for j, b in enumerate(world.obstacle_ids)})
    log_of = {b: i for i, b in enumerate(world.log_ids)}
    world.client.performCollisionDetection()
    worst = None
    for i, b in enumerate(world.log_ids):
        for cp in world.client.getContactPoints(bodyA=b):
            dist = cp[CONTACT_DISTANCE]
            if dist < -cfg.penetration_tolerance_m and (worst is None or dist < worst[0]):
                worst = (dist, i, cp[CONTACT_BODY_B], np.asarray(cp[CONTACT_NORMAL_ON_B], dtype=float))  # normal B -> A
    if worst is None:
        # pybullet's contact generation is not always the same twice: ask the twin's own
        # check too, and lift a log it still finds interpenetrating
        bad = world.penetrations(cfg.penetration_tolerance_m)
        if not bad:
            try:
                world.check_valid(cfg.penetration_tolerance_m)
            except PileValidationError as exc:
                raise FitError(f"the reconstructed pile is not physical: {exc}") from exc
            return None
        a_name, b_name, depth = bad[0]
        i_bad = int((b_name if b_name.startswith("log ") else a_name).split()[1])
        other_id = next((b for b, n in names.items() if n == (a_name if b_name == f"log {i_bad}" else b_name)), -1)
        worst = (-depth, i_bad, other_id, np.array([0.0, 0.0, 1.0]))
    return _Contact(*worst, names=names, log_of=log_of)


def _roll_contact(world, pile: PileSpec, c: _Contact, cfg: FitConfig, st: _Separation) -> PileSpec | None:
    """First the roll the scan cannot see: each log of the contact turned about its axis (at most
    ``MAX_ROLLS_PER_LOG`` times each); the pile with the turned logs, or None when none turned."""
    ks = [c.log] + ([c.other_log] if c.other_log is not None else [])
    logs = list(pile.logs)
    turned = False
    for k in ks:
        if cfg.roll_steps <= 0 or st.rolled[k] >= MAX_ROLLS_PER_LOG:
            continue
        logs[k], d0, d1 = _roll_to_clear(world, world.log_ids[k], logs[k], cfg.roll_steps)
        if logs[k] is not pile.logs[k]:
            st.rolled[k] += 1
            turned = True
            st.notes.append(f"log {k} turned about its axis (its deepest contact {-d0 * 1000:.1f} -> "
                            f"{-d1 * 1000:.1f} mm)")
    return pile.with_logs(tuple(logs)) if turned else None


def _contact_pair(c: _Contact) -> list[tuple[int, np.ndarray]]:
    """Each log of the contact and the unit way out of it for that log."""
    n = c.normal / max(np.linalg.norm(c.normal), 1e-9)
    return [(c.log, n)] + ([(c.other_log, -n)] if c.other_log is not None else [])


def _thin_contact(pile: PileSpec, c: _Contact, cfg: FitConfig, st: _Separation) -> PileSpec | None:
    """A thinnable log of the contact made thinner with its top kept (the split by what each log's
    thinning gains); the pile, or None when there is no thinning room left (a move takes it)."""
    pair = _contact_pair(c)
    room = [min(st.thin_room[k] - st.thinned[k], pile.logs[k].top_d_m / 2 - cfg.min_radius_m) for k, _ in pair]
    if max(room) <= MIN_THINNING_M:
        return None
    gains = [1.0 + float(_up_across(pile.logs[k]) @ n_k) for k, n_k in pair]
    split = _thinning_split(-c.dist + SEPARATION_MARGIN_M, gains, room)
    if sum(split) <= MIN_THINNING_M:
        return None
    logs = list(pile.logs)
    for (k, _), d in zip(pair, split):
        if d > MIN_THINNING_M:
            logs[k] = thinned_keeping_top(logs[k], d)
            st.thinned[k] += d
            against = c.other_name if k == c.log else f"log {c.log}"
            st.notes.append(f"log {k} thinned {d * 1000:.1f} mm, its top kept (log {k} / {against} "
                            f"interpenetrated {-c.dist * 1000:.1f} mm)")
    return pile.with_logs(tuple(logs))  # the twin looks again: what thinning left, a move takes


def _move_contact(pile: PileSpec, c: _Contact, cfg: FitConfig, st: _Separation) -> PileSpec:
    """Out along the contact normal by the depth: side by side each log half the way, horizontally
    (neither pushed into the ground nor lifted off it); stacked, the upper one lifted (never one
    pushed down). Raises :class:`FitError` past ``max_move_m`` in all for a log."""
    i, j, other_name = c.log, c.other_log, c.other_name
    n = _contact_pair(c)[0][1]
    n_h = np.array([n[0], n[1], 0.0])
    if j is not None and np.linalg.norm(n_h) ** 2 >= SIDE_CONTACT_MIN_H2:
        step = n_h * ((-c.dist + SEPARATION_MARGIN_M) / (2 * float(n_h @ n_h)))
        steps = [(i, step, f"log {j}"), (j, -step, f"log {i}")]
    else:
        if j is not None and n[2] < 0:  # move whichever log goes UP
            i, n, other_name = j, -n, f"log {c.log}"
        steps = [(i, n * (-c.dist + SEPARATION_MARGIN_M), other_name)]
    logs = list(pile.logs)
    for k, step, against in steps:
        st.moves[k] = st.moves[k] + step
        if np.linalg.norm(st.moves[k]) > cfg.max_move_m:
            raise SeparationError(
                f"log {k} would have to move {np.linalg.norm(st.moves[k]) * 100:.1f} cm to clear {against} "
                f"(limit {cfg.max_move_m * 100:.0f} cm); its fit or its GNSS end points are wrong",
                logs=(k,) + tuple(o for o in (c.log, c.other_log) if o is not None and o != k))
        logs[k] = replace(logs[k], centre_m=tuple(float(v) for v in np.asarray(logs[k].centre_m) + step))
        how = "lifted" if step[2] > LIFT_MIN_UP * np.linalg.norm(step) else "moved"
        st.notes.append(f"log {k} {how} {np.linalg.norm(step) * 1000:.1f} mm along "
                        f"({step[0] / np.linalg.norm(step):+.2f}, {step[1] / np.linalg.norm(step):+.2f}, "
                        f"{step[2] / np.linalg.norm(step):+.2f}) (log {k} / {against} interpenetrated "
                        f"{-c.dist * 1000:.1f} mm)")
    return pile.with_logs(tuple(logs))
