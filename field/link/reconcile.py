"""Reconciling answers per command id: the first answer naming a command is the decision about it.

A mixin of :class:`field.link.base.CraneLink` (its state lives there): a later contradicting
answer, or an outcome for a rejected command, is recorded in ``notes``, and the controller's own
status settles what the operator is told.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

from field.errors import CommandRejected, LinkTimeout
from field.link.fate import CommandFate, _runs_or_ran
from field.link.messages import Ack, GraspCommand, RejectReason

log = logging.getLogger(__name__)

#: target log count of a revocation: a command the controller refuses by definition (MALFORMED),
#: sent under the id of a command whose acknowledgement never came, to burn that id
REVOKE_TARGET_LOGS = 0


class Reconciling:
    """Decisions, revocations and notes per command id for :class:`field.link.base.CraneLink`."""

    def _decision(self, command_id: int) -> Ack | None:
        """The controller's decision about ``command_id``: the first answer naming it."""
        answers = self._answers.get(command_id)
        return answers[0] if answers else None

    def _await_decision(self, command_id: int, timeout_s: float) -> Ack | None:
        """The decision, or None at the deadline; an outcome for the id overrides a rejection."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while (ack := self._decision(command_id)) is None:
                self._raise_if_failed()
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(min(left, 0.05))
            ran = command_id in self._outcomes
        if not ack.accepted and ran:
            self._note(command_id, f"rejected {ack.reason.name}, but the controller reports an outcome: it ran")
            return Ack(command_id, True)
        return ack

    def _settle_unanswered(self, cmd: GraspCommand, outcome_timeout_s: float) -> CommandFate:
        """No answer, and the controller is not running the command: revoke its id, so that a
        copy delayed on the way can never run after the operator was told it did not."""
        cid = cmd.command_id
        ack = self._revoke(cmd)
        if ack is None:
            self._tell(cid, "no answer")
            return CommandFate(cid, None, summary=(
                f"no acknowledgement for command {cid}; the controller is not executing it, but its id could not "
                f"be revoked (no answer): a delayed copy could still run - watch the crane"), notes=self._notes(cid))
        if ack.accepted or ack.reason is RejectReason.DUPLICATE_ID:  # the original got there after all
            status = self._status_or_none()
            if ack.accepted or (status is not None and _runs_or_ran(cid, status)):
                self._note(cid, "its acknowledgement was lost; the frame reached the controller late")
                return self._follow(cid, outcome_timeout_s)
        self._tell(cid, "not executed")
        return CommandFate(cid, False, summary=(
            f"no acknowledgement for command {cid}; the controller is not executing it and its id is revoked: "
            f"it can never run. Send a new command"), notes=self._notes(cid))

    def _revoke(self, cmd: GraspCommand, attempts: int = 3) -> Ack | None:
        """Send the revocation of ``cmd``'s id (the same command with zero target logs, which the
        controller refuses by definition and so burns the id); the controller's first answer
        naming the id, or None."""
        revoke = replace(cmd, target_log_count=REVOKE_TARGET_LOGS)
        for _ in range(attempts):
            self._send(*self._wire(revoke))
            ack = self._await_decision(cmd.command_id, self.config.status_timeout_s)
            if ack is not None:
                return ack
        return None

    def _confirm_rejection(self, command_id: int, exc: CommandRejected) -> CommandFate:
        """A rejection, checked against the controller's status: it must not be running it."""
        status = self._status_or_none()
        if status is not None and _runs_or_ran(command_id, status):
            self._note(command_id, f"rejected {exc.reason.name}, but the controller runs or ran it")
            return self._follow(command_id, 30.0)
        self._tell(command_id, "rejected")
        return CommandFate(command_id, False, reason=exc.reason, summary=str(exc), notes=self._notes(command_id))

    def _follow(self, command_id: int, timeout_s: float) -> CommandFate:
        try:
            out = self.wait_outcome(command_id, timeout_s)
        except LinkTimeout as exc:
            self._tell(command_id, "outcome unknown")
            return CommandFate(command_id, True if exc.status is not None else None, summary=str(exc),
                               notes=self._notes(command_id))
        self._tell(command_id, "finished")
        return CommandFate(command_id, True, out, summary=f"finished: {out.outcome_class.name}",
                           notes=self._notes(command_id))

    def _tell(self, command_id: int, what: str) -> None:
        with self._cond:
            self._told[command_id] = what
            self._prune(self._told)

    def _note(self, command_id: int, text: str) -> None:
        """Record a reconciled conflict (call with or without ``self._cond``)."""
        with self._cond:
            self.notes.setdefault(command_id, []).append(text)
            self._prune(self.notes)
        self.stats.conflicts += 1
        log.warning("command %d: %s", command_id, text)

    def _notes(self, command_id: int) -> tuple[str, ...]:
        with self._cond:
            return tuple(self.notes.get(command_id, ()))

    def _second_laptop_hint(self) -> str:
        n = self.laptops_heard
        return f"; NOTE: the controller hears {n} laptops - disconnect the other one" if n > 1 else ""
