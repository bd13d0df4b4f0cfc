"""Messages of the crane link: what the laptop and the crane controller say to each other.

These are plain typed values, independent of the transport: :mod:`field.link.codec` turns them
into the bytes of one CAN FD frame (the same bytes travel as the Zenoh payload). Integer fields
carry the wire units in their names (``_mm``, ``_cdeg`` = 0.01 degree, ``_ms``, ``_milli``), so a
value is exactly what goes on the wire; wire-range checks happen in the codec (a value out of
range raises :class:`field.errors.ProtocolError`), type checks here (``ValueError``).

Positions are SWEREF 99 TM (EPSG:3006) easting/northing and ellipsoidal heights (SWEREF 99 /
GRS80), in millimetres. The heading is the grapple's closing axis measured clockwise from grid
north; the closing axis is pi-periodic, so headings live in [0, 180) degrees.
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass


#: The one staleness limit of the link [s]: the oldest pile data a grasp command may be based on.
#: Laptop (:class:`field.link.safety.SafetyConfig`), controller
#: (:class:`field.controller.ControllerConfig`), field trial and CLI all default to it. A crane
#: acts on a pile as it was seconds ago, not minutes: logs settle and slide.
DEFAULT_MAX_PILE_AGE_S = 30.0
#: Plan timestamps ahead of the receiver's clock by more than this are refused as STALE [s].
DEFAULT_MAX_FUTURE_SKEW_S = 2.0


class RejectReason(enum.IntEnum):
    """Why the controller refused a command (values = the DBC ``RejectReason`` table)."""

    NONE = 0
    CRC = 1  # end-to-end CRC failed: the frame was corrupted
    COUNTER = 2  # rolling counter out of sequence (lost / reordered / replayed frame)
    STALE = 3  # the pile data the plan used is older than the controller accepts
    DUPLICATE_ID = 4  # this command id was already seen: never executed twice
    OUT_OF_REACH = 5  # grasp point outside the crane's reach envelope
    WIDTH_RANGE = 6  # opening width outside the grapple's range
    HEADING_RANGE = 7  # heading outside the rotator's accepted range
    BUSY = 8  # another command is executing
    ESTOP = 9  # the controller is in emergency stop
    MALFORMED = 10  # wrong length / version / impossible field values
    FAULT = 11  # the controller is in FAULT (executor failure); needs a local reset
    UNSUPERVISED = 12  # no live laptop supervises the command (no fresh, in-sequence heartbeat / token)


class ControllerState(enum.IntEnum):
    """Controller state (values = the DBC ``State`` table)."""

    IDLE = 0
    EXECUTING = 1
    DONE = 2
    FAULT = 3
    ESTOP = 4


class OutcomeClass(enum.IntEnum):
    """Classification of a finished grasp (values = the DBC ``OutcomeClass`` table); the
    paper's failure modes plus the link's own ``ABORTED``."""

    SUCCESS = 0  # exactly the target logs, grapple closed, no collision
    MORE_THAN_INTENDED = 1  # more logs than the target set ended in the grapple
    FEWER = 2  # fewer logs than the target set
    COLLISION = 3  # a collision force above the threshold acted on the grapple
    NOT_CLOSED = 4  # the grapple did not close sufficiently
    DROPPED = 5  # logs were lifted but dropped
    ABORTED = 6  # stopped by e-stop, link supervision, an executor failure or a controller crash


#: Status wire value meaning "no command finished yet".
NO_OUTCOME = 255


def _check_int(owner: str, name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{owner}.{name} must be an int (wire units), got {value!r}")


@dataclass(frozen=True)
class GraspCommand:
    """One grasp to execute. Construct from metres/degrees with :meth:`from_metres`."""

    command_id: int  # uint32, unique per command, never reused, 0 invalid
    easting_mm: int  # SWEREF 99 TM easting [mm], int64
    northing_mm: int  # SWEREF 99 TM northing [mm], int64
    height_mm: int  # ellipsoidal height of the grasp point [mm], int32
    heading_cdeg: int  # closing axis vs grid north, clockwise [0.01 deg], uint16 (0..35999)
    opening_width_mm: int  # claw opening before closing [mm], uint16
    target_log_count: int  # logs the plan intends to grasp, uint8
    plan_timestamp_ms: int  # capture time of the pile data the plan used [ms since epoch], uint64

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            _check_int("GraspCommand", name, getattr(self, name))

    @classmethod
    def from_metres(
        cls,
        command_id: int,
        easting_m: float,
        northing_m: float,
        height_m: float,
        heading_deg: float,
        opening_width_m: float,
        target_log_count: int,
        plan_time_s: float,
    ) -> "GraspCommand":
        """Build a command from SI values; the heading is folded into [0, 180) (pi-periodic
        closing axis) and everything is rounded to the wire resolution."""
        for name, v in (
            ("easting_m", easting_m),
            ("northing_m", northing_m),
            ("height_m", height_m),
            ("heading_deg", heading_deg),
            ("opening_width_m", opening_width_m),
            ("plan_time_s", plan_time_s),
        ):
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"GraspCommand.from_metres: {name} must be a finite number, got {v!r}")
        heading_cdeg = int(round((heading_deg % 180.0) * 100.0)) % 18000
        return cls(
            command_id=int(command_id),
            easting_mm=int(round(easting_m * 1000.0)),
            northing_mm=int(round(northing_m * 1000.0)),
            height_mm=int(round(height_m * 1000.0)),
            heading_cdeg=heading_cdeg,
            opening_width_mm=int(round(opening_width_m * 1000.0)),
            target_log_count=int(target_log_count),
            plan_timestamp_ms=int(round(plan_time_s * 1000.0)),
        )

    @classmethod
    def from_grasp_geo(cls, command_id: int, geo: "object", target_log_count: int,
                       plan_time_s: float) -> "GraspCommand":
        """A command from a :class:`field.geo.GraspGeo` (TM position, ellipsoidal height, grid
        heading, opening width), rounded to the wire resolution by :meth:`from_metres`."""
        return cls.from_metres(command_id, geo.easting_m, geo.northing_m, geo.h_ell_m, geo.heading_grid_deg,
                               geo.width_m, target_log_count, plan_time_s)

    @classmethod
    def from_pile_grasp(
        cls,
        command_id: int,
        grasp: "object",
        z_m: float,
        georef: "object",
        target_log_count: int,
        plan_time_s: float,
    ) -> "GraspCommand":
        """Build a command from a pile-frame :class:`synth.geometry.grasp.Grasp` (``x_m, y_m, phi_rad,
        width_m``) at pile height ``z_m`` [m], using the pile's :class:`synth.scene.pile.Georeference`:
        :func:`field.geo.grasp_to_gnss`, the conversion the field trial uses, then
        :meth:`from_grasp_geo`."""
        from field.geo import grasp_to_gnss

        return cls.from_grasp_geo(command_id, grasp_to_gnss(grasp, georef, z_m), target_log_count, plan_time_s)

    def to_pile_grasp(self, georef: "object") -> tuple["object", float]:
        """Inverse of :meth:`from_pile_grasp`: ``(synth.geometry.grasp.Grasp, z_m)`` in the pile frame of
        ``georef`` (what a simulator executor needs), by :func:`field.geo.tm_to_grasp`. Raises
        ``ValueError`` when the width is outside the grapple's range (the controller rejects such
        commands before execution)."""
        from field.geo import tm_to_grasp

        return tm_to_grasp(self.easting_mm / 1000.0, self.northing_mm / 1000.0, self.height_mm / 1000.0,
                           self.heading_deg, self.opening_width_m, georef)

    @property
    def heading_deg(self) -> float:
        return self.heading_cdeg / 100.0

    @property
    def opening_width_m(self) -> float:
        return self.opening_width_mm / 1000.0

    def age_s(self, now_s: float | None = None) -> float:
        """Age [s] of the pile data the plan used, at ``now_s`` (epoch seconds, default now)."""
        now = time.time() if now_s is None else now_s
        return now - self.plan_timestamp_ms / 1000.0


@dataclass(frozen=True)
class Ack:
    """The controller's answer to one command: accepted, or rejected with a reason."""

    command_id: int  # uint32
    accepted: bool
    reason: RejectReason = RejectReason.NONE  # NONE when accepted

    def __post_init__(self) -> None:
        _check_int("Ack", "command_id", self.command_id)
        object.__setattr__(self, "reason", RejectReason(self.reason))
        if self.accepted and self.reason is not RejectReason.NONE:
            raise ValueError(f"an accepted Ack carries reason NONE, got {self.reason.name}")
        if not self.accepted and self.reason is RejectReason.NONE:
            raise ValueError("a rejecting Ack needs a reason other than NONE")


@dataclass(frozen=True)
class Outcome:
    """Final result of one accepted command."""

    command_id: int  # uint32
    outcome_class: OutcomeClass
    logs_grasped: int  # uint8
    balance_cos_milli: int  # cos(beta) x 1000, beta = grapple tilt from world z; int16 in [-1000, 1000]

    def __post_init__(self) -> None:
        for name in ("command_id", "logs_grasped", "balance_cos_milli"):
            _check_int("Outcome", name, getattr(self, name))
        object.__setattr__(self, "outcome_class", OutcomeClass(self.outcome_class))

    @property
    def balance_cos(self) -> float:
        return self.balance_cos_milli / 1000.0

    @property
    def success(self) -> bool:
        return self.outcome_class is OutcomeClass.SUCCESS


@dataclass(frozen=True)
class ControllerStatus:
    """What the controller reports about itself (reply to a status query, or on a change)."""

    state: ControllerState
    current_command_id: int  # command being executed, 0 = none
    heartbeat_counter: int  # controller heartbeat counter (uint32, wraps)
    last_outcome: Outcome | None = None  # the last finished command, None = none yet
    request_id: int = 0  # echo of the status query's id, 0 = unsolicited
    laptops: int = 0  # laptops the controller hears now (more than 1: a second laptop is on the link)

    def __post_init__(self) -> None:
        object.__setattr__(self, "state", ControllerState(self.state))
        for name in ("current_command_id", "heartbeat_counter", "request_id", "laptops"):
            _check_int("ControllerStatus", name, getattr(self, name))
