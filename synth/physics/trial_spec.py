"""What a grasp trial is: its code revision, its configuration, its result and the rules that
classify its outcome. :mod:`synth.physics.trial` runs it.

Outcomes (checked in this order by :func:`classify`): COLLISION (the contact force on the grapple from obstacles at
any time, or from non-target logs while lowering, averaged over ``collision_window_s``, exceeded
``collision_force_n``, under half the grapple's weight: landing on a rock, a stump or a log it
should not touch is a collision; grazing is not; the claws' squeeze on logs while closing is not), NOT_CLOSED (tip gap after closing above ``max_closed_gap_m``; the lift is
skipped, as an operator would not lift), SUCCESS (held set == targets, nothing dropped), DROPPED
(a log enclosed after closing was not held after the lift), MORE_THAN_INTENDED (held ⊋ targets),
FEWER_OR_OTHER (anything else, including nothing held).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass, field

from synth.geometry.grasp import Grasp
from synth.physics.grapple import GrappleConfig
from synth.physics.world import PhysicsConfig

TRIAL_FORMAT_VERSION = "1.0"
# Revision of the trial's code (not its parameters, which TrialConfig records): data sets and
# stores record it, and a resumed job refuses another. 2: swing dampers, interleaving claws,
# a lift that goes on until the load hangs free. 3: a faster approach through the free air above
# the pile; ``fast`` freezes the logs left behind during the lift. 4: the claws' stroke ends where
# the bowl holds a 0.19 m log (``closed_bowl_diameter_m``), so they squeeze a thin load instead of
# leaving it loose in the bowl; only logs at rest are frozen.
TRIAL_REVISION = 4


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
    def preset(name: str) -> "TrialConfig":
        """The named preset: ``"fast"`` (:meth:`fast`) or ``"careful"`` (:meth:`careful`)."""
        if name == "fast":
            return TrialConfig.fast()
        if name == "careful":
            return TrialConfig.careful()
        raise ValueError(f"trial preset must be 'fast' or 'careful', got {name!r}")

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


def classify(max_collision_force_n: float, collision_force_n: float, closed: bool, held: Iterable[int],
             enclosed: Iterable[int], targets: tuple[int, ...] | None, n_targets: int) -> Outcome:
    """A finished trial's outcome, by the rules in this module's docstring, checked in order:
    COLLISION (``max_collision_force_n`` above ``collision_force_n``), NOT_CLOSED, SUCCESS (the
    held set is the targets, or ``n_targets`` logs when ``targets`` is None, and every enclosed
    log is held), DROPPED (an enclosed log is not held), MORE_THAN_INTENDED (a strict superset of
    the targets, or more than ``n_targets`` logs), FEWER_OR_OTHER."""
    held, enclosed = set(held), set(enclosed)
    if max_collision_force_n > collision_force_n:
        return Outcome.COLLISION
    if not closed:
        return Outcome.NOT_CLOSED
    wanted_ok = (held == set(targets)) if targets is not None else (len(held) == n_targets)
    if wanted_ok and enclosed <= held:
        return Outcome.SUCCESS
    if not enclosed <= held:
        return Outcome.DROPPED
    if (targets is not None and held > set(targets)) or (targets is None and len(held) > n_targets):
        return Outcome.MORE_THAN_INTENDED
    return Outcome.FEWER_OR_OTHER
