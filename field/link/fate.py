"""What the operator is told about a command: :class:`CommandFate` and the reason texts."""

from __future__ import annotations

from dataclasses import dataclass

from field.link.messages import Ack, ControllerStatus, Outcome, RejectReason


@dataclass(frozen=True)
class CommandFate:
    """What the controller did with one command, as far as the laptop can know it: what to tell
    the operator. ``executed`` is True (it ran: ``outcome`` is its result, or None when the
    outcome is not known yet), False (it never ran: ``reason`` says why), or None (UNKNOWN: the
    controller is unreachable — check the crane on site)."""

    command_id: int
    executed: bool | None
    outcome: Outcome | None = None
    reason: RejectReason | None = None  # why it did not run (a rejection); None otherwise
    local: bool = False  # refused on the laptop: never sent
    summary: str = ""  # one line for the operator
    notes: tuple[str, ...] = ()  # conflicting or late answers that were reconciled

    @property
    def final_state(self) -> str:
        """SUCCESS / FEWER / ... (the outcome class), REJECTED, NOT EXECUTED, RUNNING or UNKNOWN."""
        if self.executed is None:
            return "UNKNOWN"
        if self.executed:
            return self.outcome.outcome_class.name if self.outcome is not None else "RUNNING"
        return "REJECTED" if self.reason is not None else "NOT EXECUTED"


def _runs_or_ran(command_id: int, status: ControllerStatus) -> bool:
    """The status says the controller is running ``command_id`` or finished it last."""
    last = status.last_outcome
    return status.current_command_id == command_id or (last is not None and last.command_id == command_id)


def _ack_word(ack: Ack) -> str:
    return "accepted" if ack.accepted else f"rejected {ack.reason.name}"


REASON_HELP: dict[RejectReason, str] = {
    RejectReason.CRC: "the frame was corrupted on the way; check the bus, send a new command",
    RejectReason.COUNTER: "frames were lost or reordered, or a second laptop is on the bus; send a new command",
    RejectReason.STALE: "the pile data is too old for the controller; rescan and plan again",
    RejectReason.DUPLICATE_ID: "this id was already used; use a new command id",
    RejectReason.OUT_OF_REACH: "the grasp point is outside the crane's reach; plan another grasp",
    RejectReason.WIDTH_RANGE: "the opening width is outside 0.30-1.55 m",
    RejectReason.HEADING_RANGE: "the heading is outside the rotator's range (fold it into [0, 180) deg)",
    RejectReason.BUSY: "a grasp is executing; wait for its outcome",
    RejectReason.ESTOP: "the crane is in emergency stop; reset it on the crane",
    RejectReason.MALFORMED: "the controller could not make sense of the frame; check versions",
    RejectReason.FAULT: "the controller is in FAULT; reset it on the crane",
    RejectReason.UNSUPERVISED: "the controller hears no live heartbeat / liveliness token from this laptop; "
                               "check the link, then send a new command",
}


def describe_fate(command_id: int, status: ControllerStatus | None) -> str:
    """One sentence on what happened to ``command_id`` given a status (for error messages)."""
    if status is None:
        return "the controller did not answer a status query either: its state is UNKNOWN - check the crane on site"
    if status.current_command_id == command_id:
        return f"the controller IS executing it (state {status.state.name})"
    if status.last_outcome is not None and status.last_outcome.command_id == command_id:
        return f"it finished: {status.last_outcome.outcome_class.name}"
    return f"the controller is NOT executing it (state {status.state.name}): it was lost or refused"


def _check_timeout(timeout_s: float) -> None:
    if not (isinstance(timeout_s, (int, float)) and timeout_s > 0):
        raise ValueError(f"timeout_s must be > 0 s, got {timeout_s!r}")
