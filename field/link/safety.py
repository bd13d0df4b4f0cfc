"""Laptop-side safety rules of the crane link, enforced before anything goes on the wire.

* A command id is used at most once per link (never sent twice, even after a timeout: the
  operator sends a NEW command after learning the final state).
* A command whose pile data is older than ``max_pile_age_s`` (or stamped in the future) is
  refused locally with :class:`field.errors.CommandRejected` (``reason=STALE, local=True``).
* A missing acknowledgement raises :class:`field.errors.LinkTimeout`, after a status query
  whose answer is attached to the exception (``.status``): the final state is always known or
  explicitly unknown (``None``, controller unreachable).
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass
from typing import Callable

from field.errors import CommandRejected
from field.link.messages import DEFAULT_MAX_FUTURE_SKEW_S, DEFAULT_MAX_PILE_AGE_S, GraspCommand, RejectReason


@dataclass(frozen=True)
class SafetyConfig:
    max_pile_age_s: float = DEFAULT_MAX_PILE_AGE_S  # oldest pile data a command may be based on [s]
    max_future_skew_s: float = DEFAULT_MAX_FUTURE_SKEW_S  # plan timestamps ahead of the laptop clock by more are refused [s]

    def __post_init__(self) -> None:
        if not self.max_pile_age_s > 0:
            raise ValueError(f"max_pile_age_s must be > 0 s, got {self.max_pile_age_s}")
        if not self.max_future_skew_s >= 0:
            raise ValueError(f"max_future_skew_s must be >= 0 s, got {self.max_future_skew_s}")


class CommandGuard:
    """Remembers every command id this link used and checks staleness (thread-safe)."""

    def __init__(self, config: SafetyConfig | None = None, clock: Callable[[], float] = time.time):
        self.config = config or SafetyConfig()
        self._clock = clock
        self._used: set[int] = set()
        self._lock = threading.Lock()

    def new_command_id(self) -> int:
        """A fresh random non-zero uint32 id, never returned before by this guard."""
        with self._lock:
            while True:
                cid = secrets.randbits(32)
                if cid != 0 and cid not in self._used:
                    return cid

    def used(self, command_id: int) -> bool:
        with self._lock:
            return command_id in self._used

    def reserve(self, cmd: GraspCommand) -> None:
        """Check ``cmd`` and burn its id. Raises :class:`CommandRejected` (``local=True``)."""
        age = cmd.age_s(self._clock())
        with self._lock:
            if cmd.command_id in self._used:
                raise CommandRejected(
                    f"command id {cmd.command_id} was already used on this link; a command is never "
                    f"sent twice. Query status() for its fate and send a new command with a new id "
                    f"(link.new_command_id())",
                    reason=RejectReason.DUPLICATE_ID,
                    command_id=cmd.command_id,
                    local=True,
                )
            if age > self.config.max_pile_age_s or age < -self.config.max_future_skew_s:
                self._used.add(cmd.command_id)
                raise CommandRejected(
                    f"command {cmd.command_id} is based on pile data {age:.1f} s old (limit "
                    f"{self.config.max_pile_age_s:.1f} s, future skew limit "
                    f"{self.config.max_future_skew_s:.1f} s); rescan the pile and plan again",
                    reason=RejectReason.STALE,
                    command_id=cmd.command_id,
                    local=True,
                )
            self._used.add(cmd.command_id)
