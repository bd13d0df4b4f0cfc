"""The grasp trial: lower, close, lift — the paper's test of one grasp on one settled pile.

:func:`run_trial` is the hot loop of data generation and evaluation. Each call builds a fresh
:class:`~synth.world.World` from the pile's stored (settled) poses — never ``saveState`` /
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

Outcomes (checked in this order): COLLISION (the contact force on the grapple from obstacles at
any time, or from non-target logs while lowering, averaged over ``collision_window_s``, exceeded
``collision_force_n``, under half the grapple's weight: landing on a rock, a stump or a log it
should not touch is a collision; grazing is not; the claws' squeeze on logs while closing is not), NOT_CLOSED (tip gap after closing above ``max_closed_gap_m``; the lift is
skipped, as an operator would not lift), SUCCESS (held set == targets, nothing dropped), DROPPED
(a log enclosed after closing was not held after the lift), MORE_THAN_INTENDED (held ⊋ targets),
FEWER_OR_OTHER (anything else, including nothing held).
"""

from __future__ import annotations

import enum
import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from synth.grapple import Grapple, GrappleConfig
from synth.grasp import Grasp
from synth.pile import PileSpec
from synth.world import PhysicsConfig, World

TRIAL_FORMAT_VERSION = "1.0"
# Revision of the trial's code (not its parameters, which TrialConfig records): data sets and
# stores record it, and a resumed job refuses another. 2: swing dampers, interleaving claws,
# a lift that goes on until the load hangs free. 3: a faster approach through the free air above
# the pile; ``fast`` freezes the logs left behind during the lift.
TRIAL_REVISION = 3


class Outcome(enum.Enum):
    SUCCESS = "success"
    MORE_THAN_INTENDED = "more_than_intended"
    FEWER_OR_OTHER = "fewer_or_other"
    COLLISION = "collision"
    NOT_CLOSED = "not_closed"
    DROPPED = "dropped"

    @property
    def ok(self) -> bool:
        return self is Outcome.SUCCESS


@dataclass(frozen=True)
class TrialConfig:
    """Everything that decides a trial's outcome besides the pile and the grasp.

    Use :meth:`fast` (data generation, evaluation) or :meth:`careful` (the reference the fast
    preset is measured against); both run the same controller, only numerics and early exits
    differ. Fix one config per data set: the time step changes outcomes near decision boundaries.
    """

    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    grapple: GrappleConfig = field(default_factory=GrappleConfig)
    terrain_resolution: int | None = None  # physics heightfield override [samples/side]; None = pile's
    # controller
    start_clearance_m: float = 0.30  # claw tips above the highest object near the grasp [m]
    footprint_margin_m: float = 0.40  # horizontal margin around the open claws for that search [m]
    lower_speed_m_s: float = 0.5  # [m/s]
    approach_speed_m_s: float = 1.0  # lower this fast through the free air above the pile ... [m/s]
    approach_clearance_m: float = 0.10  # ... until the claw tips are this far above its top [m]
    lift_speed_m_s: float = 0.5  # [m/s]
    inside_radius_frac: float = 1.0  # while lowering, a log's axis must be this many radii ... [-]
    inside_depth_m: float = 0.03  # ... plus this [m] above the claw tips to count as inside
    inside_margin_v_m: float = 0.10  # extra reach of the inside box along v beyond the claws [m]
    ground_clearance_m: float = -0.03  # stop lowering when a tip reaches this height over the ground
    # [m]; negative: tips dig a few cm into soil, as real ones do (terrain contacts are disabled)
    stop_force_n: float = 1500.0  # stop lowering on this filtered contact force (all contacts) [N]
    stop_window_s: float = 0.10  # its moving-mean window [s]
    collision_force_n: float = 1000.0  # filtered force from obstacles / non-target logs = collision [N]
    collision_window_s: float = 0.075  # its moving-mean window [s] (50–100 ms)
    max_closed_gap_m: float = 0.12  # claws "sufficiently closed" below this tip gap [m]
    close_timeout_s: float = 2.5  # [s]
    close_still_s: float = 0.15  # claws count as stopped after this long below close_still_rad_s [s]
    close_still_rad_s: float = 0.05  # [rad/s]
    lift_height_m: float | None = None  # lift this far; None = back to the start height [m]
    min_lift_m: float = 0.5  # lift at least this far [m]
    free_lift_max_m: float = 1.5  # then lift on, at most this much more, until the load hangs free [m]
    free_contact_n: float = 20.0  # a held log touching anything else harder than this is not free [N]
    hold_s: float = 0.5  # hold after the lift before judging [s]
    held_rise_m: float = 0.25  # a log is held if its centre rose this much and it is inside [m]
    max_lower_s: float = 8.0  # safety limits [s]
    check_every: int = 1  # evaluate the inside rule every n steps [-]
    record_penetration: bool = True  # track grapple-log interpenetration (cheap) [-]
    freeze_when_free: bool = False  # once the load hangs free, make the logs left behind static [-]

    def __post_init__(self) -> None:
        if self.terrain_resolution is not None and not 8 <= self.terrain_resolution <= 512:
            raise ValueError(f"terrain_resolution must be in [8, 512] or None, got {self.terrain_resolution}")
        for name in ("lower_speed_m_s", "approach_speed_m_s", "lift_speed_m_s", "stop_force_n", "stop_window_s",
                     "collision_force_n", "collision_window_s", "max_closed_gap_m", "close_timeout_s",
                     "min_lift_m", "held_rise_m", "max_lower_s", "start_clearance_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"trial {name} must be > 0, got {getattr(self, name)}")
        if self.check_every < 1:
            raise ValueError("check_every must be >= 1")
        if not 0 <= self.approach_clearance_m <= self.start_clearance_m:
            raise ValueError(f"approach_clearance_m must be in [0, start_clearance_m = {self.start_clearance_m}] m, "
                             f"got {self.approach_clearance_m}")
        if self.hold_s < 0 or self.free_lift_max_m < 0 or self.free_contact_n <= 0:
            raise ValueError("hold_s and free_lift_max_m must be >= 0 and free_contact_n > 0")

    @staticmethod
    def careful() -> "TrialConfig":
        """Reference settings: dt 1/240 s, 50 solver iterations, the pile's own terrain (64²)."""
        return TrialConfig(physics=PhysicsConfig(dt_s=1 / 240, solver_iterations=50), hold_s=2.0)

    @staticmethod
    def fast() -> "TrialConfig":
        """Data-generation and evaluation settings: :meth:`careful` with dt 1/120 s, the inside
        rule checked every second step, a 1.0 s hold and the logs left behind frozen during the
        lift (``freeze_when_free``). Measured against :meth:`careful` on the 160 bench grasps
        (docs/trials.md, trial revision 3): 0.41 s CPU per 4-log trial (careful 1.03 s),
        outcome-class agreement 95.0 %, success/failure 98.8 %."""
        return TrialConfig(
            physics=PhysicsConfig(dt_s=1 / 120, solver_iterations=50),
            terrain_resolution=None, start_clearance_m=0.30, hold_s=1.0, check_every=2,
            freeze_when_free=True,
        )


@dataclass(frozen=True)
class TrialResult:
    outcome: Outcome
    grasp: Grasp
    targets: tuple[int, ...] | None  # target log indices (None when only a count was given)
    n_targets: int
    grasped: tuple[int, ...]  # logs held after the lift (enclosed after closing if not lifted)
    enclosed: tuple[int, ...]  # logs inside the closed claws before lifting
    cos_beta: float  # balance after the lift (nan if not lifted) [-]
    final_gap_m: float  # claw tip gap after closing [m]
    max_force_n: float  # max filtered (stop window) contact force on the grapple [N]
    max_collision_force_n: float  # max filtered force counted for collisions [N]
    max_penetration_m: float  # deepest grapple-log interpenetration seen [m]
    max_log_speed_m_s: float  # fastest log seen [m/s]
    phase_s: dict[str, float]  # simulated time per phase: lower, close, lift, hold [s]
    sim_time_s: float  # total simulated time [s]
    wall_time_s: float  # wall-clock time of the whole call [s]
    cpu_time_s: float  # CPU time of the whole call (this process) [s]
    stop_reason: str  # why lowering stopped: "inside", "force", "ground", "timeout"; "aborted" (should_abort)
    final_poses: tuple[tuple[float, ...], ...]  # per log: x, y, z [m], quaternion x, y, z, w at the end
    aborted_in: str | None = None  # the phase an aborted trial stopped in ("lower", "close", ...); None = ran to the end

    @property
    def success(self) -> bool:
        return self.outcome is Outcome.SUCCESS

    def to_dict(self) -> dict:
        return {
            "format": "loggrasp.trial", "format_version": TRIAL_FORMAT_VERSION,
            "outcome": self.outcome.value, "grasp": self.grasp.to_dict(),
            "targets": None if self.targets is None else list(self.targets), "n_targets": self.n_targets,
            "grasped": list(self.grasped), "enclosed": list(self.enclosed), "cos_beta": self.cos_beta,
            "final_gap_m": self.final_gap_m, "max_force_n": self.max_force_n,
            "max_collision_force_n": self.max_collision_force_n,
            "max_penetration_m": self.max_penetration_m, "max_log_speed_m_s": self.max_log_speed_m_s,
            "phase_s": dict(self.phase_s), "sim_time_s": self.sim_time_s,
            "wall_time_s": self.wall_time_s, "cpu_time_s": self.cpu_time_s,
            "stop_reason": self.stop_reason, "final_poses": [list(p) for p in self.final_poses],
        } | ({} if self.aborted_in is None else {"aborted_in": self.aborted_in})


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
    from synth.pile import height_at

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
        from synth.pile import rotate

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
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    cfg = config or TrialConfig.fast()
    target_idx, n_targets = _parse_targets(pile, targets)
    g = cfg.grapple
    dt = cfg.physics.dt_s

    q_open = g.angle_for_gap(grasp.width_m)
    top = _top_near(pile, grasp, grasp.width_m / 2 + cfg.footprint_margin_m)
    start_z = top + cfg.start_clearance_m + g.hang_height_m(q_open)

    # no visual meshes unless someone will look (pictures): ~25-30 ms less per trial
    with World(trial_pile(pile, cfg.terrain_resolution), cfg.physics, visuals=on_phase is not None) as world, \
            _AbortCatcher() as aborted:
        c = world.client
        grapple = Grapple(c, g, grasp, start_z, terrain_id=world.terrain_id)
        log_ids = world.log_ids
        obstacle_set = set(world.obstacle_ids)
        log_set = set(log_ids)
        half_len, radius = _log_segments(pile)
        lower_depth = cfg.inside_radius_frac * radius + cfg.inside_depth_m
        start_centres = world.log_poses()[:, :2 + 1].copy()
        terrain = world.pile.terrain
        grid, extent = world.height_grid, terrain.extent_m
        from synth.pile import height_at

        stop_mean = _Mean(round(cfg.stop_window_s / dt))
        coll_mean = _Mean(round(cfg.collision_window_s / dt))
        stats = {"max_force": 0.0, "max_coll": 0.0, "pen": 0.0, "speed": 0.0}
        speed_every = max(1, round(0.05 / dt))
        phase_s: dict[str, float] = {}
        steps = 0

        # bodies whose contact counts as a collision: obstacles always, non-target logs while lowering
        if target_idx is not None:
            non_target = {log_ids[i] for i in range(len(log_ids)) if i not in set(target_idx)}
        else:
            non_target = set()
        coll_lowering = obstacle_set | non_target

        def contact_step(lowering: bool) -> float:
            """Step once; update the filtered forces and the stability statistics."""
            nonlocal steps
            c.stepSimulation()
            steps += 1
            if should_abort is not None and should_abort():
                raise _Aborted(stopped_now())
            total = coll = pen = 0.0
            coll_set = coll_lowering if lowering else obstacle_set
            for cp in c.getContactPoints(bodyA=grapple.body):
                other, f = cp[2], cp[9]
                total += f
                if other in coll_set:
                    coll += f
                if cp[8] < -pen and other in log_set:
                    pen = -cp[8]
            fm = stop_mean.push(total)
            cm = coll_mean.push(coll)
            if fm > stats["max_force"]:
                stats["max_force"] = fm
            if cm > stats["max_coll"]:
                stats["max_coll"] = cm
            if pen > stats["pen"]:
                stats["pen"] = pen
            if steps % speed_every == 0:
                stats["speed"] = max(stats["speed"], max_log_speed())
            return fm

        def log_axes() -> tuple[np.ndarray, np.ndarray]:
            """Log centres (n, 3) and unit axes (n, 3) in the pile frame."""
            cen = np.empty((len(log_ids), 3))
            ax = np.empty((len(log_ids), 3))
            for i, b in enumerate(log_ids):
                pos, orn = c.getBasePositionAndOrientation(b)
                cen[i] = pos
                x, y, z, w = orn
                ax[i] = (1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w))
            return cen, ax

        n_samp = 33
        s_line = np.linspace(-1.0, 1.0, n_samp)
        v_half = g.claw_width_m / 2 + cfg.inside_margin_v_m

        def inside(depth_m: float | np.ndarray) -> np.ndarray:
            """Boolean per log: its axis crosses the region between the claws under the rotator.

            The region is the polygon in the closing plane bounded by both claw profiles (at their
            current angles), the line between the tips raised by ``depth_m`` and the head's bottom,
            extended ``v_half`` either side of the plane.
            """
            o, R = grapple.head_pose()
            poly = grapple.enclosure_polygon()  # (k, 2) in (u, z)
            z_lo = float(poly[[grapple.tip_index_neg, grapple.tip_index_pos], 1].max()) + np.broadcast_to(
                np.asarray(depth_m, dtype=float), (len(log_ids),))[:, None]
            z_hi = -g.head_drop_m - 0.05
            cen, ax = log_axes()
            pts = cen[:, None, :] + ax[:, None, :] * (half_len[:, None, None] * s_line[None, :, None])
            loc = (pts - o) @ R  # head frame (n, m, 3)
            # add the exact crossing of the closing plane v = 0, where the axis crosses it
            p0 = loc[:, 0, :]
            d = loc[:, -1, :] - p0
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.clip(np.where(np.abs(d[:, 1]) > 1e-9, -p0[:, 1] / d[:, 1], 0.5), 0.0, 1.0)
            cross = p0 + d * t[:, None]
            loc = np.concatenate([loc, cross[:, None, :]], axis=1)
            u, v, z = loc[..., 0], loc[..., 1], loc[..., 2]
            ok = (np.abs(v) <= v_half) & (z >= z_lo) & (z <= z_hi)
            ok &= _points_in_polygon(u, z, poly)
            return ok.any(axis=1)

        def load_is_free(load: set[int]) -> bool:
            """No log of ``load`` rests on anything but the grapple and the other logs of ``load``
            harder than ``free_contact_n``: the load hangs in the grapple."""
            for b in load:
                for cp in c.getContactPoints(bodyA=b):
                    if cp[2] != grapple.body and cp[2] not in load and cp[9] > cfg.free_contact_n:
                        return False
            return True

        frozen: set[int] = set()

        def freeze_apart_from(load: set[int]) -> None:
            """``freeze_when_free``: make static, where they lie, the logs that no longer touch the
            load, directly or through other logs. Such a log costs a contact solve against the
            terrain every step and cannot change the outcome unless the swinging load hits it,
            which a static log still models (as an immovable one). Logs are never thawed."""
            linked, todo = set(load), list(load)
            while todo:
                for cp in c.getContactPoints(bodyA=todo.pop()):
                    if cp[2] in log_set and cp[2] not in linked and cp[2] not in frozen:
                        linked.add(cp[2])
                        todo.append(cp[2])
            for b in sorted(log_set - linked - frozen):
                c.resetBaseVelocity(b, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
                c.changeDynamics(b, -1, mass=0.0)
                frozen.add(b)

        def max_log_speed() -> float:
            best = 0.0
            for b in log_ids:
                v = c.getBaseVelocity(b)[0]
                best = max(best, math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
            return best

        def stopped_now() -> TrialResult:
            """Abort: hold the boom where it is, stop the claws; the true state at this moment."""
            grapple.hold_xyz(grasp.x_m, grasp.y_m, grapple.boom_z())
            grapple.set_claws(float(np.mean(grapple.claw_angles())))
            cen, _ = log_axes()
            risen = cen[:, 2] - start_centres[:, 2] >= cfg.held_rise_m
            held = tuple(int(i) for i in np.flatnonzero(risen & inside(-g.claw_thickness_m)))
            between = tuple(int(i) for i in np.flatnonzero(inside(-0.5 * g.claw_thickness_m)))
            return TrialResult(
                outcome=Outcome.FEWER_OR_OTHER, grasp=grasp, targets=target_idx, n_targets=n_targets, grasped=held,
                enclosed=between, cos_beta=grapple.cos_beta(), final_gap_m=grapple.gap_m(),
                max_force_n=stats["max_force"], max_collision_force_n=stats["max_coll"],
                max_penetration_m=stats["pen"], max_log_speed_m_s=stats["speed"], phase_s=dict(phase_s),
                sim_time_s=steps * dt, wall_time_s=time.perf_counter() - t_wall,
                cpu_time_s=time.process_time() - t_cpu, stop_reason="aborted",
                final_poses=tuple(tuple(float(v) for v in row) for row in world.log_poses()),
                aborted_in=next((ph for ph in _PHASES if ph not in phase_s), "end"))

        if on_phase:
            on_phase("start", world, grapple)

        # -- 1. lower: fast through the free air, then at the lowering speed --------------------
        approach_z = start_z - (cfg.start_clearance_m - cfg.approach_clearance_m)
        approaching = cfg.approach_speed_m_s > cfg.lower_speed_m_s and approach_z < start_z
        grapple.move_z(-(cfg.approach_speed_m_s if approaching else cfg.lower_speed_m_s))
        stop_reason = "timeout"
        n_lower = int(cfg.max_lower_s / dt)
        for k in range(n_lower):
            if approaching and grapple.boom_z() <= approach_z:
                grapple.move_z(-cfg.lower_speed_m_s)
                approaching = False
            fm = contact_step(lowering=True)
            if fm >= cfg.stop_force_n:
                stop_reason = "force"
                break
            if k % cfg.check_every == 0:
                tips = grapple.tips_world()
                ground = height_at(grid, extent, tips[:, 0], tips[:, 1])
                if np.any(tips[:, 2] <= ground + cfg.ground_clearance_m):
                    stop_reason = "ground"
                    break
                if int(inside(lower_depth).sum()) >= n_targets:
                    stop_reason = "inside"
                    break
        phase_s["lower"] = (k + 1) * dt
        grasp_xy = (grasp.x_m, grasp.y_m)
        grapple.hold_xyz(*grasp_xy, grapple.boom_z())
        if on_phase:
            on_phase("lowered", world, grapple)

        # -- 2. close --------------------------------------------------------------------------
        grapple.close()
        still_needed = max(1, round(cfg.close_still_s / dt))
        still = 0
        n_close = int(cfg.close_timeout_s / dt)
        for k in range(n_close):
            contact_step(lowering=False)
            sn, sp = grapple.claw_speeds()
            still = still + 1 if max(abs(sn), abs(sp)) < cfg.close_still_rad_s else 0
            if still >= still_needed and k * dt > 0.2:
                break
        phase_s["close"] = (k + 1) * dt
        final_gap = grapple.gap_m()
        enclosed = np.flatnonzero(inside(-0.5 * g.claw_thickness_m))
        stats["speed"] = max(stats["speed"], max_log_speed())
        if on_phase:
            on_phase("closed", world, grapple)

        cos_beta = float("nan")
        grasped = tuple(int(i) for i in enclosed)
        closed = final_gap <= cfg.max_closed_gap_m
        if closed:
            # -- 3. lift ---------------------------------------------------------------------
            z0 = grapple.boom_z()
            target_z = start_z if cfg.lift_height_m is None else z0 + cfg.lift_height_m
            target_z = max(target_z, z0 + cfg.min_lift_m)
            grapple.move_z(cfg.lift_speed_m_s)
            top_z = target_z + cfg.free_lift_max_m
            n_lift = int(((top_z - z0) / cfg.lift_speed_m_s + 2.0) / dt)
            free_every = max(1, round(0.05 / dt))
            load = {log_ids[i] for i in enclosed}
            freezing = cfg.freeze_when_free and bool(load)
            for k in range(n_lift):
                contact_step(lowering=False)
                z = grapple.boom_z()
                if k % free_every:
                    continue
                if freezing:
                    freeze_apart_from(load)
                if z >= top_z or (z >= target_z and load_is_free(load)):
                    break
            target_z = grapple.boom_z()
            phase_s["lift"] = (k + 1) * dt
            grapple.hold_xyz(*grasp_xy, target_z)
            n_hold = int(round(cfg.hold_s / dt))
            betas = []
            for k in range(n_hold):
                contact_step(lowering=False)
                if k >= n_hold // 2:
                    betas.append(grapple.cos_beta())
            phase_s["hold"] = n_hold * dt
            cos_beta = float(np.mean(betas)) if betas else grapple.cos_beta()
            stats["speed"] = max(stats["speed"], max_log_speed())
            cen, _ = log_axes()
            risen = cen[:, 2] - start_centres[:, 2] >= cfg.held_rise_m
            now_inside = inside(-g.claw_thickness_m)
            grasped = tuple(int(i) for i in np.flatnonzero(risen & now_inside))
        if on_phase:
            on_phase("end", world, grapple)
        sim_time = steps * dt
        final_poses = tuple(tuple(float(v) for v in row) for row in world.log_poses())

    if aborted.result is not None:
        return aborted.result
    enclosed_t = tuple(int(i) for i in enclosed)
    held = set(grasped)
    wanted_ok = (held == set(target_idx)) if target_idx is not None else (len(held) == n_targets)
    if stats["max_coll"] > cfg.collision_force_n:
        outcome = Outcome.COLLISION
    elif not closed:
        outcome = Outcome.NOT_CLOSED
    elif wanted_ok and set(enclosed_t) <= held:
        outcome = Outcome.SUCCESS
    elif not set(enclosed_t) <= held:
        outcome = Outcome.DROPPED
    elif (target_idx is not None and held > set(target_idx)) or (target_idx is None and len(held) > n_targets):
        outcome = Outcome.MORE_THAN_INTENDED
    else:
        outcome = Outcome.FEWER_OR_OTHER
    return TrialResult(
        outcome=outcome, grasp=grasp, targets=target_idx, n_targets=n_targets, grasped=tuple(sorted(held)),
        enclosed=enclosed_t, cos_beta=cos_beta, final_gap_m=final_gap, max_force_n=stats["max_force"],
        max_collision_force_n=stats["max_coll"], max_penetration_m=stats["pen"],
        max_log_speed_m_s=stats["speed"], phase_s=phase_s, sim_time_s=sim_time,
        wall_time_s=time.perf_counter() - t_wall, cpu_time_s=time.process_time() - t_cpu,
        stop_reason=stop_reason, final_poses=final_poses,
    )


#: the phases of a trial in order (``phase_s`` keys); an aborted trial stopped in the first one
#: that has no time recorded yet
_PHASES = ("lower", "close", "lift", "hold")


class _Aborted(Exception):
    """Raised inside a trial when ``should_abort()`` turned True; carries the result."""

    def __init__(self, result: TrialResult):
        super().__init__("trial aborted")
        self.result = result


class _AbortCatcher:
    """Context manager ending an aborted trial quietly (the world still closes after it)."""

    result: TrialResult | None = None

    def __enter__(self) -> "_AbortCatcher":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if isinstance(exc, _Aborted):
            self.result = exc.result
            return True
        return False


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
