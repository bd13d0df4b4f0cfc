"""The grasp trial: lower, close, lift — the paper's test of one grasp on one settled pile.

:func:`run_trial` is the hot loop of data generation and evaluation. Each call builds a fresh
:class:`~synth.physics.world.World` from the pile's stored (settled) poses — never ``saveState`` /
``restoreState``, which is not history-free — so a trial's outcome depends only on
``(pile, grasp, targets, config)``, whatever ran before it in the process.

The trial (paper, "Simulator"):

1. The grapple hangs plumb above the grasp point, turned to ``phi`` and opened to ``width``, with
   its claw tips ``start_clearance_m`` above the highest thing near the grasp (a safe height).
2. *Lower* vertically at ``lower_speed_m_s`` until the number of logs inside the grapple reaches
   the number of targets, or the filtered contact force on the grapple exceeds
   ``stop_force_n``, or the claw tips reach the ground (grapple–terrain contacts are disabled).
   A log is *inside* when its axis crosses the region between the claws under the rotator: in
   the head frame, ``|u| <= gap/2`` (the current tip distance), ``|v| <= claw_width/2 +
   inside_margin_v_m`` and ``tip_z + inside_depth_m <= z <= head bottom``.
3. *Close* the claws as far as the torque limit allows (until they stop moving).
4. *Lift* back to the start height, then hold briefly and measure the balance ``cos β``.

What a trial is configured by and how it is judged (:class:`TrialConfig`, :class:`TrialResult`,
:func:`classify`) lives in :mod:`synth.physics.trial_spec`.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import numpy as np

from synth.physics.grapple import Grapple
from synth.geometry.grasp import Grasp
from synth.scene.pile import PileSpec, height_at, rotate
from synth.physics.trial_spec import Outcome, TrialConfig, TrialResult, classify
from synth.physics.world import World

class _Mean:
    """Moving mean over a fixed number of steps."""

    def __init__(self, n: int) -> None:
        self.buf: deque[float] = deque(maxlen=max(1, n))
        self.total = 0.0

    def push(self, v: float) -> float:
        if len(self.buf) == self.buf.maxlen:
            self.total -= self.buf[0]
        self.buf.append(v)
        self.total += v
        return self.total / self.buf.maxlen  # zeros before the window fills: a true moving mean


def trial_pile(pile: PileSpec, terrain_resolution: int | None) -> PileSpec:
    """The pile with its *physics* heightfield resampled to ``terrain_resolution`` (poses unchanged)."""
    t = pile.terrain
    if terrain_resolution is None or terrain_resolution == t.resolution:
        return pile
    grid = t.height_grid()
    xs = np.linspace(-t.extent_m / 2, t.extent_m / 2, terrain_resolution)
    X, Y = np.meshgrid(xs, xs)  # rows along +y, columns along +x
    h = height_at(grid, t.extent_m, X, Y)
    terrain = replace(t, resolution=terrain_resolution, heights_m=tuple(tuple(float(v) for v in r) for r in h))
    return replace(pile, terrain=terrain)


def _points_in_polygon(x: np.ndarray, y: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule: which points (any shape) lie inside the closed polygon (k, 2)."""
    inside = np.zeros(np.shape(x), dtype=bool)
    xj, yj = poly[-1]
    for xi, yi in poly:
        crosses = (yi > y) != (yj > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = (xj - xi) * (y - yi) / (yj - yi) + xi
        inside ^= crosses & (x < xc)
        xj, yj = xi, yi
    return inside


def _log_segments(pile: PileSpec) -> tuple[np.ndarray, np.ndarray]:
    """Per log: half-length [m] and radius [m] (mean)."""
    half = np.array([log.length_m / 2 for log in pile.logs])
    rad = np.array([log.mean_diameter_m / 2 for log in pile.logs])
    return half, rad


def _top_near(pile: PileSpec, grasp: Grasp, radius_m: float) -> float:
    """Highest point [m] of logs and obstacles within ``radius_m`` of the grasp point (xy)."""
    c = np.array([grasp.x_m, grasp.y_m])
    tops = [float(pile.terrain.height_at(grasp.x_m, grasp.y_m))]
    for log in pile.logs:
        a, b = log.endpoints_m()
        s = np.linspace(0.0, 1.0, 41)[:, None]
        pts = a + (b - a) * s
        near = np.linalg.norm(pts[:, :2] - c, axis=1) <= radius_m + log.diameter_m / 2
        if near.any():
            tops.append(float(pts[near, 2].max() + log.diameter_m / 2))
    for rock in pile.rocks:
        v = np.asarray(rock.vertices_m, dtype=float)
        world = np.array([rotate(rock.orientation, p) for p in v]) + np.asarray(rock.position_m)
        if np.min(np.linalg.norm(world[:, :2] - c, axis=1)) <= radius_m + rock.size_m() / 2:
            tops.append(float(world[:, 2].max()))
    for stump in pile.stumps:
        d = math.hypot(stump.position_m[0] - c[0], stump.position_m[1] - c[1])
        if d <= radius_m + stump.bottom_radius_m + 0.5:
            ground = float(pile.terrain.height_at(*stump.position_m))
            tops.append(ground + stump.height_m)
    return max(tops)


def _parse_targets(pile: PileSpec, targets: int | Iterable[int]) -> tuple[tuple[int, ...] | None, int]:
    if isinstance(targets, (int, np.integer)):
        n = int(targets)
        if not 1 <= n <= pile.n_logs:
            raise ValueError(f"n_targets must be in [1, {pile.n_logs}] (the pile's logs), got {n}")
        return None, n
    idx = tuple(sorted({int(i) for i in targets}))
    if not idx:
        raise ValueError("targets is empty: give at least one log index or a target count")
    bad = [i for i in idx if not 0 <= i < pile.n_logs]
    if bad:
        raise ValueError(f"target log indices {bad} are not in the pile (0..{pile.n_logs - 1})")
    return idx, len(idx)


def run_trial(
    pile: PileSpec,
    grasp: Grasp,
    targets: int | Iterable[int],
    config: TrialConfig | None = None,
    on_phase: Callable[[str, World, Grapple], None] | None = None,
    should_abort: Callable[[], bool] | None = None,
) -> TrialResult:
    """Run one grasp trial on a settled pile and classify it.

    ``targets`` is either the target log indices (success = the held set equals them) or a
    count (success = exactly that many logs held, whichever). ``on_phase(name, world, grapple)``
    is called at "start", "lowered", "closed" and "end" (e.g. to render pictures); it must not
    step the simulation. Deterministic: the same arguments give the same result in any process
    and after any other trials.

    ``should_abort()`` is asked after every simulation step; once it returns True the boom and
    the claws are held where they are and the trial returns at once with ``stop_reason``
    "aborted", ``aborted_in`` the phase, ``grasped`` the logs held (risen, inside) and
    ``enclosed`` the logs between the claws at that moment (``outcome`` is FEWER_OR_OTHER: the
    trial did not finish). Without it the trial is exactly as before.
    """
    clock = (time.perf_counter(), time.process_time())
    cfg = config or TrialConfig.fast()
    target_idx, n_targets = _parse_targets(pile, targets)
    # no visual meshes unless someone will look (pictures): ~25-30 ms less per trial
    with World(trial_pile(pile, cfg.terrain_resolution), cfg.physics, visuals=on_phase is not None) as world:
        run = _TrialRun(world, pile, grasp, cfg, target_idx, n_targets, should_abort, clock)
        try:
            ending = run.all_phases(on_phase)
        except _Aborted as stop:
            return run.result(stop.ending, Outcome.FEWER_OR_OTHER)
    closed = ending.final_gap_m <= cfg.max_closed_gap_m
    outcome = classify(ending.stats.max_collision_force_n, cfg.collision_force_n, closed, ending.grasped,
                       ending.enclosed, target_idx, n_targets)
    return run.result(ending, outcome)


#: the phases of a trial in order (``phase_s`` keys); an aborted trial stopped in the first one
#: that has no time recorded yet
_PHASES = ("lower", "close", "lift", "hold")
_SAMPLE_EVERY_S = 0.05  # how often the lift checks for a free load and log speeds are sampled [s]
_AXIS_SAMPLES = 33  # points along each log's axis tested against the inside region [-]
_HEAD_CLEARANCE_M = 0.05  # the inside region ends this far below the head's hinge plane [m]
_MIN_CLOSE_S = 0.2  # closing lasts at least this long, however still the claws [s]
_LIFT_SLACK_S = 2.0  # the lift's step budget: its travel time plus this [s]
_FREEZE_SPEED_M_S = 0.05  # a log left behind is frozen only once slower than this ... [m/s]
_FREEZE_SPIN_RAD_S = 0.2  # ... and turning slower than this [rad/s] (at rest on the pile)


@dataclass
class _Stats:
    """The running maxima a trial reports (TrialResult fields of the same names)."""

    max_force_n: float = 0.0
    max_collision_force_n: float = 0.0
    max_penetration_m: float = 0.0
    max_log_speed_m_s: float = 0.0


@dataclass(frozen=True)
class _Ending:
    """The state a trial's phases leave behind: what :func:`classify` and the result need."""

    grasped: tuple[int, ...]
    enclosed: tuple[int, ...]
    cos_beta: float
    final_gap_m: float
    stop_reason: str
    stats: _Stats
    phase_s: dict[str, float]
    sim_time_s: float
    final_poses: tuple[tuple[float, ...], ...]
    aborted_in: str | None = None


class _Aborted(Exception):
    """Raised inside a trial when ``should_abort()`` turned True; carries the state at that step."""

    def __init__(self, ending: _Ending):
        super().__init__("trial aborted")
        self.ending = ending


def _start_z(pile: PileSpec, grasp: Grasp, cfg: TrialConfig) -> float:
    """The boom height [m] the trial starts from: claw tips ``start_clearance_m`` above the top."""
    g = cfg.grapple
    top = _top_near(pile, grasp, grasp.width_m / 2 + cfg.footprint_margin_m)
    return top + cfg.start_clearance_m + g.hang_height_m(g.angle_for_gap(grasp.width_m))


class _TrialRun:
    """One trial in its world: the grapple, the force filters, the statistics and the phase times.

    :meth:`all_phases` runs :meth:`lower`, :meth:`close` and, if the claws closed, :meth:`lift`
    and :meth:`hold`; every simulation step goes through :meth:`step`.
    """

    def __init__(self, world: World, pile: PileSpec, grasp: Grasp, cfg: TrialConfig,
                 target_idx: tuple[int, ...] | None, n_targets: int, should_abort: Callable[[], bool] | None,
                 clock: tuple[float, float]) -> None:
        self.world, self.grasp, self.cfg, self.g = world, grasp, cfg, cfg.grapple
        self.target_idx, self.n_targets, self.should_abort, self.clock = target_idx, n_targets, should_abort, clock
        self.dt = dt = cfg.physics.dt_s
        self.start_z = _start_z(pile, grasp, cfg)
        self.c = world.client
        self.grapple = Grapple(self.c, self.g, grasp, self.start_z, terrain_id=world.terrain_id)
        self.log_ids = world.log_ids
        self.obstacle_set = set(world.obstacle_ids)
        self.log_set = set(self.log_ids)
        self.half_len, radius = _log_segments(pile)
        self.lower_depth = cfg.inside_radius_frac * radius + cfg.inside_depth_m
        self.start_centres = world.log_poses()[:, :3].copy()
        self.stop_mean = _Mean(round(cfg.stop_window_s / dt))
        self.coll_mean = _Mean(round(cfg.collision_window_s / dt))
        self.stats = _Stats()
        self.speed_every = max(1, round(_SAMPLE_EVERY_S / dt))
        self.phase_s: dict[str, float] = {}
        self.steps = 0
        self.frozen: set[int] = set()
        self.s_line = np.linspace(-1.0, 1.0, _AXIS_SAMPLES)
        self.v_half = self.g.claw_width_m / 2 + cfg.inside_margin_v_m
        # bodies whose contact counts as a collision: obstacles always, non-target logs while lowering
        non_target = set() if target_idx is None else {
            b for i, b in enumerate(self.log_ids) if i not in set(target_idx)}
        self.coll_lowering = self.obstacle_set | non_target

    # -- the phases ---------------------------------------------------------------------------
    def all_phases(self, on_phase: Callable[[str, World, Grapple], None] | None) -> _Ending:
        """Lower, close and (if closed) lift and hold; ``on_phase`` between them."""
        def tell(name: str) -> None:
            if on_phase:
                on_phase(name, self.world, self.grapple)

        tell("start")
        stop_reason = self.lower()
        tell("lowered")
        final_gap, enclosed = self.close()
        tell("closed")
        cos_beta, grasped = float("nan"), enclosed
        if final_gap <= self.cfg.max_closed_gap_m:
            self.lift(enclosed)
            cos_beta = self.hold()
            grasped = self.held_now()
        tell("end")
        return self.ending(tuple(sorted(set(grasped))), enclosed, cos_beta, final_gap, stop_reason)

    def lower(self) -> str:
        """Lower fast through the free air, then at the lowering speed, until a stop rule fires;
        hold the boom there. Returns the stop reason."""
        cfg, dt, grapple = self.cfg, self.dt, self.grapple
        approach_z = self.start_z - (cfg.start_clearance_m - cfg.approach_clearance_m)
        approaching = cfg.approach_speed_m_s > cfg.lower_speed_m_s and approach_z < self.start_z
        grapple.move_z(-(cfg.approach_speed_m_s if approaching else cfg.lower_speed_m_s))
        stop_reason = "timeout"
        for k in range(int(cfg.max_lower_s / dt)):
            if approaching and grapple.boom_z() <= approach_z:
                grapple.move_z(-cfg.lower_speed_m_s)
                approaching = False
            if self.step(lowering=True) >= cfg.stop_force_n:
                stop_reason = "force"
                break
            if k % cfg.check_every == 0:
                reached = self._lowered_far_enough()
                if reached:
                    stop_reason = reached
                    break
        self.phase_s["lower"] = (k + 1) * dt
        grapple.hold_xyz(self.grasp.x_m, self.grasp.y_m, grapple.boom_z())
        return stop_reason

    def _lowered_far_enough(self) -> str | None:
        """The stop reason if lowering should stop here: "ground" (a claw tip reached the ground)
        or "inside" (enough logs are inside); None to lower on."""
        tips = self.grapple.tips_world()
        ground = height_at(self.world.height_grid, self.world.pile.terrain.extent_m, tips[:, 0], tips[:, 1])
        if np.any(tips[:, 2] <= ground + self.cfg.ground_clearance_m):
            return "ground"
        if int(self.inside(self.lower_depth).sum()) >= self.n_targets:
            return "inside"
        return None

    def close(self) -> tuple[float, tuple[int, ...]]:
        """Close the claws until they stop moving. Returns the tip gap [m] and the enclosed logs."""
        cfg, dt = self.cfg, self.dt
        self.grapple.close()
        still_needed = max(1, round(cfg.close_still_s / dt))
        still = 0
        for k in range(int(cfg.close_timeout_s / dt)):
            self.step(lowering=False)
            sn, sp = self.grapple.claw_speeds()
            still = still + 1 if max(abs(sn), abs(sp)) < cfg.close_still_rad_s else 0
            if still >= still_needed and k * dt > _MIN_CLOSE_S:
                break
        self.phase_s["close"] = (k + 1) * dt
        final_gap = self.grapple.gap_m()
        enclosed = self.between_claws()
        self.sample_speed()
        return final_gap, enclosed

    def lift(self, enclosed: tuple[int, ...]) -> None:
        """Lift to the target height, then on until the load hangs free (at most
        ``free_lift_max_m`` more); hold the boom there."""
        cfg, dt, grapple = self.cfg, self.dt, self.grapple
        z0 = grapple.boom_z()
        target_z = self.start_z if cfg.lift_height_m is None else z0 + cfg.lift_height_m
        target_z = max(target_z, z0 + cfg.min_lift_m)
        grapple.move_z(cfg.lift_speed_m_s)
        top_z = target_z + cfg.free_lift_max_m
        n_lift = int(((top_z - z0) / cfg.lift_speed_m_s + _LIFT_SLACK_S) / dt)
        free_every = max(1, round(_SAMPLE_EVERY_S / dt))
        load = {self.log_ids[i] for i in enclosed}
        freezing = cfg.freeze_when_free and bool(load)
        for k in range(n_lift):
            self.step(lowering=False)
            z = grapple.boom_z()
            if k % free_every:
                continue
            if freezing:
                self.freeze_apart_from(load)
            if z >= top_z or (z >= target_z and self.load_is_free(load)):
                break
        self.phase_s["lift"] = (k + 1) * dt
        grapple.hold_xyz(self.grasp.x_m, self.grasp.y_m, grapple.boom_z())

    def hold(self) -> float:
        """Hold ``hold_s``; returns the balance cos β averaged over its second half."""
        n_hold = int(round(self.cfg.hold_s / self.dt))
        betas = []
        for k in range(n_hold):
            self.step(lowering=False)
            if k >= n_hold // 2:
                betas.append(self.grapple.cos_beta())
        self.phase_s["hold"] = n_hold * self.dt
        cos_beta = float(np.mean(betas)) if betas else self.grapple.cos_beta()
        self.sample_speed()
        return cos_beta

    # -- one step and its statistics ------------------------------------------------------------
    def step(self, lowering: bool) -> float:
        """Step once; update the filtered forces and the statistics. Returns the filtered total
        contact force [N]. Raises :class:`_Aborted` when ``should_abort()`` says so."""
        self.c.stepSimulation()
        self.steps += 1
        if self.should_abort is not None and self.should_abort():
            raise _Aborted(self.stopped_now())
        total = coll = pen = 0.0
        coll_set = self.coll_lowering if lowering else self.obstacle_set
        for cp in self.c.getContactPoints(bodyA=self.grapple.body):
            other, f = cp[2], cp[9]
            total += f
            if other in coll_set:
                coll += f
            if cp[8] < -pen and other in self.log_set:
                pen = -cp[8]
        fm = self.stop_mean.push(total)
        cm = self.coll_mean.push(coll)
        s = self.stats
        if fm > s.max_force_n:
            s.max_force_n = fm
        if cm > s.max_collision_force_n:
            s.max_collision_force_n = cm
        if pen > s.max_penetration_m:
            s.max_penetration_m = pen
        if self.steps % self.speed_every == 0:
            self.sample_speed()
        return fm

    def sample_speed(self) -> None:
        """Fold the fastest log's speed now into ``max_log_speed_m_s``."""
        best = 0.0
        for b in self.log_ids:
            v = self.c.getBaseVelocity(b)[0]
            best = max(best, math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
        self.stats.max_log_speed_m_s = max(self.stats.max_log_speed_m_s, best)

    # -- which logs are where -------------------------------------------------------------------
    def log_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Log centres (n, 3) and unit axes (n, 3) in the pile frame."""
        cen = np.empty((len(self.log_ids), 3))
        ax = np.empty((len(self.log_ids), 3))
        for i, b in enumerate(self.log_ids):
            pos, orn = self.c.getBasePositionAndOrientation(b)
            cen[i] = pos
            x, y, z, w = orn
            ax[i] = (1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w))
        return cen, ax

    def inside(self, depth_m: float | np.ndarray) -> np.ndarray:
        """Boolean per log: its axis crosses the region between the claws under the rotator.

        The region is the polygon in the closing plane bounded by both claw profiles (at their
        current angles), the line between the tips raised by ``depth_m`` and the head's bottom,
        extended ``v_half`` either side of the plane.
        """
        grapple, n = self.grapple, len(self.log_ids)
        o, R = grapple.head_pose()
        poly = grapple.enclosure_polygon()  # (k, 2) in (u, z)
        z_lo = float(poly[[grapple.tip_index_neg, grapple.tip_index_pos], 1].max()) + np.broadcast_to(
            np.asarray(depth_m, dtype=float), (n,))[:, None]
        z_hi = -self.g.head_drop_m - _HEAD_CLEARANCE_M
        cen, ax = self.log_axes()
        pts = cen[:, None, :] + ax[:, None, :] * (self.half_len[:, None, None] * self.s_line[None, :, None])
        loc = (pts - o) @ R  # head frame (n, m, 3)
        # add the exact crossing of the closing plane v = 0, where the axis crosses it
        p0 = loc[:, 0, :]
        d = loc[:, -1, :] - p0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(np.where(np.abs(d[:, 1]) > 1e-9, -p0[:, 1] / d[:, 1], 0.5), 0.0, 1.0)
        cross = p0 + d * t[:, None]
        loc = np.concatenate([loc, cross[:, None, :]], axis=1)
        u, v, z = loc[..., 0], loc[..., 1], loc[..., 2]
        ok = (np.abs(v) <= self.v_half) & (z >= z_lo) & (z <= z_hi)
        ok &= _points_in_polygon(u, z, poly)
        return ok.any(axis=1)

    def between_claws(self) -> tuple[int, ...]:
        """The logs inside the claws (region raised by half a claw thickness)."""
        return tuple(int(i) for i in np.flatnonzero(self.inside(-0.5 * self.g.claw_thickness_m)))

    def held_now(self) -> tuple[int, ...]:
        """The logs held: risen ``held_rise_m`` since the start and inside the claws."""
        cen, _ = self.log_axes()
        risen = cen[:, 2] - self.start_centres[:, 2] >= self.cfg.held_rise_m
        return tuple(int(i) for i in np.flatnonzero(risen & self.inside(-self.g.claw_thickness_m)))

    def load_is_free(self, load: set[int]) -> bool:
        """No log of ``load`` rests on anything but the grapple and the other logs of ``load``
        harder than ``free_contact_n``: the load hangs in the grapple."""
        for b in load:
            for cp in self.c.getContactPoints(bodyA=b):
                if cp[2] != self.grapple.body and cp[2] not in load and cp[9] > self.cfg.free_contact_n:
                    return False
        return True

    def freeze_apart_from(self, load: set[int]) -> None:
        """``freeze_when_free``: make static, where they lie, the logs that no longer touch the
        load, directly or through other logs, and have come to rest. Such a log costs a contact solve against the
        terrain every step and cannot change the outcome unless the swinging load hits it,
        which a static log still models (as an immovable one). Logs are never thawed."""
        linked, todo = set(load), list(load)
        while todo:
            for cp in self.c.getContactPoints(bodyA=todo.pop()):
                if cp[2] in self.log_set and cp[2] not in linked and cp[2] not in self.frozen:
                    linked.add(cp[2])
                    todo.append(cp[2])
        for b in sorted(self.log_set - linked - self.frozen):
            v, w = self.c.getBaseVelocity(b)
            if math.hypot(*v) > _FREEZE_SPEED_M_S or math.hypot(*w) > _FREEZE_SPIN_RAD_S:
                continue  # still moving (sliding off the load, falling): it may yet hit something
            self.c.resetBaseVelocity(b, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
            self.c.changeDynamics(b, -1, mass=0.0)
            self.frozen.add(b)

    # -- endings --------------------------------------------------------------------------------
    def stopped_now(self) -> _Ending:
        """Abort: hold the boom where it is, stop the claws; the true state at this moment."""
        grapple = self.grapple
        grapple.hold_xyz(self.grasp.x_m, self.grasp.y_m, grapple.boom_z())
        grapple.set_claws(float(np.mean(grapple.claw_angles())))
        held = self.held_now()
        aborted_in = next((ph for ph in _PHASES if ph not in self.phase_s), "end")
        return self.ending(held, self.between_claws(), grapple.cos_beta(), grapple.gap_m(), "aborted", aborted_in)

    def ending(self, grasped: tuple[int, ...], enclosed: tuple[int, ...], cos_beta: float, final_gap_m: float,
               stop_reason: str, aborted_in: str | None = None) -> _Ending:
        """The state now (the world must still be open)."""
        return _Ending(grasped=grasped, enclosed=enclosed, cos_beta=cos_beta, final_gap_m=final_gap_m,
                       stop_reason=stop_reason, stats=replace(self.stats), phase_s=dict(self.phase_s),
                       sim_time_s=self.steps * self.dt,
                       final_poses=tuple(tuple(float(v) for v in row) for row in self.world.log_poses()),
                       aborted_in=aborted_in)

    def result(self, e: _Ending, outcome: Outcome) -> TrialResult:
        """The trial's result; wall and CPU times run from the call's start to now."""
        t_wall, t_cpu = self.clock
        s = e.stats
        return TrialResult(
            outcome=outcome, grasp=self.grasp, targets=self.target_idx, n_targets=self.n_targets,
            grasped=e.grasped, enclosed=e.enclosed, cos_beta=e.cos_beta, final_gap_m=e.final_gap_m,
            max_force_n=s.max_force_n, max_collision_force_n=s.max_collision_force_n,
            max_penetration_m=s.max_penetration_m, max_log_speed_m_s=s.max_log_speed_m_s, phase_s=e.phase_s,
            sim_time_s=e.sim_time_s, wall_time_s=time.perf_counter() - t_wall,
            cpu_time_s=time.process_time() - t_cpu, stop_reason=e.stop_reason, final_poses=e.final_poses,
            aborted_in=e.aborted_in)


def render_view(world: World, look_at_m, distance_m: float = 3.2, yaw_deg: float = 35.0,
                pitch_deg: float = -28.0, size_px: tuple[int, int] = (640, 480)) -> np.ndarray:
    """An oblique RGB picture (H, W, 3) uint8 of the world with TinyRenderer (for docs/debugging).

    Use as ``on_phase`` callback of :func:`run_trial` to picture a trial's phases.
    """
    c, p = world.client, world.p
    w, h = size_px
    view = c.computeViewMatrixFromYawPitchRoll(list(map(float, look_at_m)), distance_m, yaw_deg, pitch_deg, 0, 2)
    proj = c.computeProjectionMatrixFOV(50.0, w / h, 0.05, 30.0)
    img = c.getCameraImage(w, h, view, proj, renderer=p.ER_TINY_RENDERER, lightDirection=[0.4, 0.3, 1.0],
                           shadow=0, flags=p.ER_NO_SEGMENTATION_MASK)
    rgba = np.asarray(img[2], dtype=np.uint8).reshape(h, w, 4)
    return rgba[:, :, :3].copy()
