"""The controller's configuration and its pure command checks (unit-testable without a link).

:func:`check_command` runs the payload checks of one grasp command in order and names the first
failing reason; :class:`ControllerConfig` holds every limit with its unit.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from field.link.messages import (
    DEFAULT_MAX_FUTURE_SKEW_S,
    DEFAULT_MAX_PILE_AGE_S,
    GraspCommand,
    RejectReason,
)


@dataclass(frozen=True)
class ReachEnvelope:
    """Where the crane can grasp: an annulus around its base, with a height window.

    The default base is an arbitrary site near Umeå (64.1°N 20.0°E); configure the real one.
    """

    base_easting_m: float = 744_000.0  # SWEREF 99 TM easting of the slewing axis [m]
    base_northing_m: float = 7_112_000.0  # SWEREF 99 TM northing of the slewing axis [m]
    base_height_m: float = 50.0  # ellipsoidal height of the crane base [m]
    min_reach_m: float = 2.0  # closest grasp to the slewing axis [m]
    max_reach_m: float = 10.0  # farthest grasp (boom fully out) [m]
    min_dz_m: float = -6.0  # lowest grasp point relative to the base [m]
    max_dz_m: float = 3.0  # highest grasp point relative to the base [m]

    def __post_init__(self) -> None:
        for name in ("base_easting_m", "base_northing_m", "base_height_m"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"ReachEnvelope.{name} must be finite")
        if not 0 <= self.min_reach_m < self.max_reach_m:
            raise ValueError(
                f"reach must satisfy 0 <= min_reach_m < max_reach_m, got {self.min_reach_m}, {self.max_reach_m}"
            )
        if not self.min_dz_m < self.max_dz_m:
            raise ValueError(f"min_dz_m ({self.min_dz_m}) must be < max_dz_m ({self.max_dz_m})")

    def horizontal_ok(self, cmd: GraspCommand) -> bool:
        """The grasp point lies in the annulus around the slewing axis."""
        de = cmd.easting_mm / 1000.0 - self.base_easting_m
        dn = cmd.northing_mm / 1000.0 - self.base_northing_m
        return self.min_reach_m <= math.hypot(de, dn) <= self.max_reach_m

    def height_ok(self, cmd: GraspCommand) -> bool:
        """The grasp point lies in the height window around the base."""
        return self.min_dz_m <= cmd.height_mm / 1000.0 - self.base_height_m <= self.max_dz_m

    def contains(self, cmd: GraspCommand) -> bool:
        return self.horizontal_ok(cmd) and self.height_ok(cmd)


@dataclass(frozen=True)
class ControllerConfig:
    reach: ReachEnvelope = field(default_factory=ReachEnvelope)
    max_pile_age_s: float = DEFAULT_MAX_PILE_AGE_S  # oldest pile data a command may be based on [s]
    max_future_skew_s: float = DEFAULT_MAX_FUTURE_SKEW_S  # plan timestamps ahead of the crane clock by more are STALE [s]
    min_width_mm: int = 300  # grapple opening range [mm]
    max_width_mm: int = 1550  # [mm]
    min_heading_cdeg: int = 0  # accepted closing-axis headings [0.01 deg]; pi-periodic axis
    max_heading_cdeg: int = 17999  # [0.01 deg]
    max_target_logs: int = 12  # more target logs than this is MALFORMED [-]
    counter_max_delta: int = 2  # rolling-counter jump tolerated on commands (lost frames) [-]
    heartbeat_period_s: float = 0.05  # crane heartbeat period [s]
    laptop_timeout_s: float = 1.0  # laptop counts as lost after this long without a fresh heartbeat [s]
    # burn seen ids / outcomes here, so nothing runs twice across restarts. None: run_controller uses
    # the link's default file (default_journal_path); a CraneController built directly needs a path
    journal_path: str | None = None
    no_journal: bool = False  # the explicit opt-out: ids kept in memory only, forgotten on restart (logged) [-]
    journal_keep: int = 10_000  # journal entries kept on compaction [-]
    journal_fsync: bool = True  # fsync every journal line (off only for throw-away twins in tests) [-]
    secoc_key_path: str | None = None  # pre-shared key file: accept authenticated frames only
    insecure_link: bool = False  # the explicit opt-out: no key, frames not authenticated (logged) [-]
    secoc_window_s: float = 2.0  # SecOC freshness window [s]
    signing_key_path: str | None = None  # Ed25519 signing key: every answer signed (needed with a SecOC key)
    # more frames than this failing their MAC (or key id) within mac_failure_window_s: someone
    # without the key is on the bus - FAULT (commands refused, a running grasp aborted, local reset)
    max_mac_failures: int = 20  # [-]
    mac_failure_window_s: float = 10.0  # [s]

    def __post_init__(self) -> None:
        if not self.max_pile_age_s > 0:
            raise ValueError(f"max_pile_age_s must be > 0 s, got {self.max_pile_age_s}")
        if not 0 < self.min_width_mm < self.max_width_mm:
            raise ValueError(f"need 0 < min_width_mm < max_width_mm, got {self.min_width_mm}, {self.max_width_mm}")
        if not 0 <= self.min_heading_cdeg <= self.max_heading_cdeg <= 35999:
            raise ValueError(
                f"need 0 <= min_heading_cdeg <= max_heading_cdeg <= 35999, got "
                f"{self.min_heading_cdeg}, {self.max_heading_cdeg}"
            )
        if not 1 <= self.max_target_logs <= 255:
            raise ValueError(f"max_target_logs must be in [1, 255], got {self.max_target_logs}")
        if self.no_journal and self.journal_path is not None:
            raise ValueError(f"give journal_path ({self.journal_path}) or no_journal=True, not both")
        if not self.max_mac_failures >= 1:
            raise ValueError(f"max_mac_failures must be >= 1, got {self.max_mac_failures}")
        for name in ("heartbeat_period_s", "laptop_timeout_s", "secoc_window_s", "mac_failure_window_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 s, got {getattr(self, name)}")


# --- the command checks (pure: unit-testable without a link) --------------------------------


def check_age(cmd: GraspCommand, config: ControllerConfig, now_s: float) -> RejectReason:
    """STALE when the pile data is older than ``max_pile_age_s`` or from the future beyond
    ``max_future_skew_s`` (by the crane's clock ``now_s``)."""
    age = cmd.age_s(now_s)
    ok = -config.max_future_skew_s <= age <= config.max_pile_age_s
    return RejectReason.NONE if ok else RejectReason.STALE


def check_width(cmd: GraspCommand, config: ControllerConfig) -> RejectReason:
    ok = config.min_width_mm <= cmd.opening_width_mm <= config.max_width_mm
    return RejectReason.NONE if ok else RejectReason.WIDTH_RANGE


def check_heading(cmd: GraspCommand, config: ControllerConfig) -> RejectReason:
    ok = config.min_heading_cdeg <= cmd.heading_cdeg <= config.max_heading_cdeg
    return RejectReason.NONE if ok else RejectReason.HEADING_RANGE


def check_target_count(cmd: GraspCommand, config: ControllerConfig) -> RejectReason:
    ok = 1 <= cmd.target_log_count <= config.max_target_logs
    return RejectReason.NONE if ok else RejectReason.MALFORMED


def check_reach(cmd: GraspCommand, config: ControllerConfig) -> RejectReason:
    return RejectReason.NONE if config.reach.contains(cmd) else RejectReason.OUT_OF_REACH


def check_command(cmd: GraspCommand, config: ControllerConfig, now_s: float) -> RejectReason:
    """The payload checks of one command, first failing reason (or NONE)."""
    for reason in (check_age(cmd, config, now_s), check_width(cmd, config), check_heading(cmd, config),
                   check_target_count(cmd, config), check_reach(cmd, config)):
        if reason is not RejectReason.NONE:
            return reason
    return RejectReason.NONE


def controller_config_from_dict(d: dict[str, Any]) -> ControllerConfig:
    """Build a :class:`ControllerConfig` from plain values (e.g. a JSON file; ``reach`` nested)."""
    from synth.common.configs import config_from_dict

    return config_from_dict(ControllerConfig, d, "controller config")


def controller_config_to_dict(c: ControllerConfig) -> dict[str, Any]:
    return asdict(c)
