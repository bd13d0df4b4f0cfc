"""The laptop side's receive path: check, decode and store crane -> laptop frames.

A mixin of :class:`field.link.base.CraneLink` (its state lives there): frames delivered by a
backend go through :meth:`Receiving._deliver`: SecOC check (with a key) and the crane's
signature (with its public key; on CAN it comes in a frame of its own, :meth:`Receiving._deliver_signature`),
E2E check, rolling counter check, decode, then into the inbox that the public API waits on.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from field.errors import AuthenticationError, ProtocolError
from field.link.fate import _ack_word
from field.link.messages import Ack, ControllerStatus, Outcome, RejectReason

log = logging.getLogger(__name__)


class Receiving:
    """Crane -> laptop frames into :class:`field.link.base.CraneLink`'s inbox (under its ``_cond``)."""

    def _deliver(self, kind: str, data: bytes) -> None:
        """Feed one crane -> laptop frame (any thread): check, decode, store, notify. On CAN a
        signed frame is only held here, until :meth:`_deliver_signature` gets its signature."""
        self.stats.frames_received += 1
        self._resync_after_silence()
        self._accept(kind, self._unwrap(kind, data))

    def _deliver_signature(self, kind: str, signature: bytes) -> None:
        """Feed one CAN signature frame of a ``kind`` frame (any thread): the frame it releases
        goes on like :meth:`_deliver`'s."""
        self.stats.frames_received += 1
        plain, why = self._answer_check.on_signature(kind, signature)
        self._count_failure(kind, why)
        self._accept(kind, plain)

    def _accept(self, kind: str, plain: bytes | None) -> None:
        check = self._answer_check
        check.expire()
        self.stats.unsigned_dropped, self.stats.orphan_signatures = check.unsigned_dropped, check.orphan_signatures
        d = None if plain is None else self._decode(kind, plain)
        if d is None:
            return
        with self._cond:
            self._dispatch(d.message)
            self._cond.notify_all()

    def _mark_alive(self) -> None:
        """Backends with their own liveness signal (Zenoh liveliness) call this."""
        self._counters.reset()  # a (re)appearing controller starts a new counter session
        with self._cond:
            self._last_heartbeat_mono = time.monotonic()
            self._cond.notify_all()

    def _mark_lost(self) -> None:
        self._counters.reset()
        with self._cond:
            self._last_heartbeat_mono = None
            self._cond.notify_all()

    def _fail(self, exc: BaseException) -> None:
        """Backends report an unrecoverable transport error here; waiters raise LinkError."""
        self.stats.bus_errors += 1
        with self._cond:
            if self._failure is None:
                self._failure = exc
            self._cond.notify_all()

    # ---- receiving -----------------------------------------------------------------------

    def _resync_after_silence(self) -> None:
        now = time.monotonic()
        last, self._last_rx_mono = self._last_rx_mono, now
        if self._resync_on_silence and (last is None or now - last > self.config.heartbeat_timeout_s):
            self._counters.reset()  # the controller was silent: a new session, re-synchronise
            self._crane_heartbeat = None

    def _unwrap(self, kind: str, data: bytes) -> bytes | None:
        """The plain frame, after the SecOC check (and the crane's signature) when a key is
        configured (None: dropped and counted, or held for its signature frame)."""
        plain, why = self._answer_check.unwrap(kind, data)
        self._count_failure(kind, why)
        return plain

    def _auth_hint(self) -> str:
        """Why a crane that is there may not have been heard: frames that failed authentication, or
        crane frames whose signature never came ("" when neither)."""
        auth, unsigned = self.stats.auth_failures, self.stats.unsigned_dropped
        return ((f"; {auth} frames failed authentication: the crane uses another SecOC key or none (secoc_key= on "
                 f"both sides), or crane_key= is not this crane's public key" if auth else "")
                + (f"; {unsigned} crane frames came without their signature frame: does the crane sign its answers "
                   f"(signing_key=)?" if unsigned else ""))

    def _count_failure(self, kind: str, why: Any) -> None:
        """A frame that failed its MAC, signature, freshness or length: dropped, counted; past the
        link's ``max_auth_failures`` the link fails (its waiters raise :class:`LinkError`)."""
        if why is None:
            return
        self.stats.auth_failures += 1
        log.debug("dropped %s: %s", kind, why)
        cause = self._answer_check.count_failure(why)
        if cause is not None:
            with self._cond:
                first = self._failure is None
                if first:
                    self._failure = AuthenticationError(cause, check="threshold")
                self._cond.notify_all()
            if first:
                log.error("the %s link fails: %s", self.backend_name, cause)

    def _decode(self, kind: str, data: bytes) -> Any:
        from field.link.codec import CounterCheck, decode

        try:
            d = decode(kind, data)
        except ProtocolError as exc:
            if exc.reason is RejectReason.CRC:
                self.stats.crc_errors += 1
            else:
                self.stats.malformed += 1
            return None
        check = self._counters.check(d.kind, d.counter)
        if check is CounterCheck.REPEATED:
            self.stats.duplicates_dropped += 1
            return None
        if check is CounterCheck.WRONG_SEQUENCE:
            self.stats.sequence_errors += 1
        return d

    def _dispatch(self, msg: Any) -> None:
        """Store one decoded crane -> laptop message (under ``self._cond``)."""
        from field.link.codec import CraneHeartbeat

        if isinstance(msg, CraneHeartbeat):
            self._on_crane_heartbeat(msg)
        elif isinstance(msg, Ack):
            self._on_ack(msg)
        elif isinstance(msg, Outcome):
            self._on_outcome(msg)
        elif isinstance(msg, ControllerStatus):
            self._on_status(msg)

    def _on_crane_heartbeat(self, msg: Any) -> None:
        last, self._crane_heartbeat = self._crane_heartbeat, msg.heartbeat_counter
        self._last_crane_state = msg.state
        if last is None:
            return  # the first heartbeat of a session only primes the sequence
        if 1 <= (msg.heartbeat_counter - last) & 0xFFFFFFFF <= self._max_heartbeat_gap:
            self._last_heartbeat_mono = time.monotonic()
        else:
            self.stats.stale_heartbeats += 1

    def _on_ack(self, ack: Ack) -> None:
        if ack.command_id == 0:
            self.stats.unattributed_answers += 1  # the controller got a frame that failed its check
            return
        if self._foreign(ack.command_id, "acknowledgement"):
            return
        answers = self._answers.setdefault(ack.command_id, [])
        answers.append(ack)
        self._prune(self._answers)
        first = answers[0]
        if first.accepted != ack.accepted:
            self._note(ack.command_id, f"contradicting answers: {_ack_word(first)} then {_ack_word(ack)}")
        told = self._told.get(ack.command_id)
        if told in ("no answer", "not executed") and ack.accepted:
            self._note(ack.command_id, f"a late acceptance arrived after the operator was told '{told}'")

    def _on_outcome(self, out: Outcome) -> None:
        if self._foreign(out.command_id, "outcome"):
            return
        self._outcomes.setdefault(out.command_id, out)
        self._prune(self._outcomes)
        told = self._told.get(out.command_id)
        if told in ("rejected", "no answer", "not executed"):
            self._note(out.command_id, f"the controller reports an outcome ({out.outcome_class.name}) for a "
                                       f"command the operator was told was '{told}'")

    def _foreign(self, command_id: int, what: str) -> bool:
        """An answer naming a command this link never sent: dropped and counted (a forgery, or
        another laptop's answer), never taken for a decision about one of ours."""
        if command_id in self._issued:
            return False
        self.stats.foreign_answers += 1
        log.debug("dropped an %s for command %d, which this link never sent", what, command_id)
        return True

    def _on_status(self, msg: ControllerStatus) -> None:
        if msg.request_id in self._pending_status:
            self._last_heartbeat_mono = time.monotonic()  # the answer to our own query: fresh
            self._status_replies[msg.request_id] = msg
            self._prune(self._status_replies)
        elif msg.request_id:
            return  # an answer to a query this link did not make (or a replay): not ours
        if msg.laptops > 1 and self.laptops_heard <= 1:
            log.warning("the crane controller hears %d laptops: a second laptop is on the link; only one may "
                        "command a crane - disconnect the other", msg.laptops)
        self._latest_status = msg
