"""The crane controller's protocol logic (:class:`CraneController`); see :mod:`field.controller`."""

from __future__ import annotations

import logging
import secrets
from collections import deque
import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable

from field.controller.config import ControllerConfig, check_command
from field.controller.executors import FixedOutcomeExecutor, GraspExecutor
from field.controller.journal import ControllerJournal
from field.errors import ControllerError, ProtocolError
from field.link.messages import (
    Ack,
    ControllerState,
    ControllerStatus,
    GraspCommand,
    Outcome,
    OutcomeClass,
    RejectReason,
)

log = logging.getLogger(__name__)


Reply = Callable[[str, bytes], None]
_CAN = "can"  # the command channel of a bus without source addresses (one counter session)


@dataclass
class _Run:
    """One accepted command on its way through the executor."""

    cmd: GraspCommand
    peer: str  # the commanding laptop (live at the acceptance: nothing is accepted unsupervised)
    accepted_s: float  # monotonic time of the acceptance [s]
    abort: threading.Event = field(default_factory=threading.Event)
    acked: threading.Event = field(default_factory=threading.Event)
    reason: str | None = None  # why it was aborted
    worker: threading.Thread | None = None


def _raw_command_id(data: bytes) -> int:
    return int.from_bytes(bytes(data[4:8]), "little") if len(data) >= 8 else 0


def command_digest(cmd: GraspCommand) -> str:
    """A short digest of a command's content: tells a copy of a frame from another command."""
    import hashlib

    return hashlib.sha256(repr(asdict(cmd)).encode()).hexdigest()[:16]


class CraneController:
    """Protocol logic of the crane controller (thread-safe). See the module docstring."""

    def __init__(
        self,
        config: ControllerConfig | None = None,
        executor: GraspExecutor | Callable[[GraspCommand], Outcome] | None = None,
        *,
        clock: Callable[[], float] = time.time,
    ):
        from field.link.codec import Encoder
        from field.link.supervision import HeartbeatStreams, PeerTracker

        self.config = config or ControllerConfig()
        self.executor = executor if executor is not None else FixedOutcomeExecutor()
        if not (callable(self.executor) or callable(getattr(self.executor, "execute", None))):
            raise ValueError(f"executor must have execute(cmd, should_abort) or be callable, got {self.executor!r}")
        self._clock = clock
        self._encoder = Encoder(first_counter=secrets.randbits(8))  # a restart is a new counter session
        from field.link.signing import load_crane_keys

        self._secoc, self._signer = load_crane_keys(self.config, self._clock)
        self._counters: dict[str, Any] = {}  # command channel -> CounterMonitor
        self._streams = HeartbeatStreams(self.config.laptop_timeout_s)
        self._peers = PeerTracker(self.config.laptop_timeout_s)
        self._lock = threading.RLock()
        self._state = ControllerState.IDLE
        self._fault_cause: str | None = None  # the executor's exception while FAULT
        self._current = 0
        self._heartbeat = 0
        self._last_outcome: Outcome | None = None
        self._decisions: dict[int, tuple[str | None, RejectReason]] = {}  # id -> (digest, decision)
        self._outcomes: dict[int, Outcome] = {}
        self._run: _Run | None = None
        self._last_run: _Run | None = None
        self._publish: Reply | None = None
        self._journal = self._open_journal()
        self.rejections: list[tuple[int, RejectReason]] = []  # diagnostics
        self.auth_failures = 0  # frames dropped by the SecOC check
        self._mac_failures: deque[float] = deque()  # monotonic times of recent MAC failures [s]
        self._auth_warned_s: dict[str, float] = {}
        self._stop = threading.Event()
        self._supervisor: threading.Thread | None = None

    def _open_journal(self) -> ControllerJournal | None:
        if self.config.no_journal:
            log.warning("controller journal OFF (no_journal=True): command ids are kept in memory only - a "
                        "restart forgets them and a replayed command could run again")
            return None
        if self.config.journal_path is None:
            raise ControllerError("a crane controller needs a journal so that no command runs twice across "
                                  "restarts: set ControllerConfig.journal_path (run_controller derives one from "
                                  "the link), or opt out explicitly with no_journal=True")
        journal = ControllerJournal(self.config.journal_path, self.config.journal_keep, self.config.journal_fsync)
        self._decisions, self._last_outcome = journal.recover()
        return journal

    # ---- wiring --------------------------------------------------------------------------

    def attach(self, publish: Reply) -> None:
        """Give the controller its way to publish unsolicited frames (Outcome, Status)."""
        self._publish = publish

    def start(self) -> None:
        """Start laptop supervision."""
        if self._supervisor is None:
            self._supervisor = threading.Thread(target=self._supervise, name="controller-supervisor", daemon=True)
            self._supervisor.start()

    def close(self, timeout_s: float = 2.0) -> None:
        """Abort a running grasp and stop supervision."""
        self._stop.set()
        with self._lock:
            run = self._run
            if run is not None:
                self._abort_run(run, "controller shutdown")
        if run is not None and run.worker is not None:
            run.worker.join(timeout_s)
        if self._supervisor is not None:
            self._supervisor.join(timeout_s)

    # ---- state ---------------------------------------------------------------------------

    @property
    def state(self) -> ControllerState:
        return self._state

    @property
    def _worker(self) -> threading.Thread | None:
        """The running (or last) grasp's worker thread (tests join it)."""
        run = self._run or self._last_run
        return None if run is None else run.worker

    @property
    def fault_cause(self) -> str | None:
        """Why the controller is in FAULT (the executor's exception), None otherwise. The link's
        status frame carries only the state; the crane's operator reads the cause here."""
        with self._lock:
            return self._fault_cause

    def status(self, request_id: int = 0) -> ControllerStatus:
        with self._lock:
            return ControllerStatus(self._state, self._current, self._heartbeat, self._last_outcome, request_id,
                                    laptops=len(self._peers.live()))

    def outcome_of(self, command_id: int) -> Outcome | None:
        return self._outcomes.get(command_id)

    def seen(self, command_id: int) -> bool:
        """Whether ``command_id`` is burned (seen before, accepted or rejected)."""
        with self._lock:
            return command_id in self._decisions

    def reset_estop(self) -> None:
        """Local reset on the crane (not reachable over the link): ESTOP/FAULT -> IDLE."""
        with self._lock:
            if self._run is not None:
                raise ControllerError("cannot reset while the aborted grasp is still winding down; retry")
            if self._state in (ControllerState.ESTOP, ControllerState.FAULT):
                self._state = ControllerState.IDLE
                self._fault_cause = None
        self._publish_status()

    reset_fault = reset_estop

    def heartbeat_frame(self) -> bytes:
        """Next crane heartbeat frame (counter incremented; carries the state)."""
        from field.link.codec import CraneHeartbeat

        with self._lock:
            self._heartbeat = (self._heartbeat + 1) & 0xFFFFFFFF
            msg = CraneHeartbeat(self._heartbeat, self._state)
        return self._wire(msg)

    # ---- laptops -------------------------------------------------------------------------

    def peer_present(self, peer: str) -> None:
        """A transport saw laptop ``peer`` appear (Zenoh: its liveliness token)."""
        if self._peers.present(peer):
            self._new_peer(peer)

    def peer_gone(self, peer: str, why: str = "laptop liveliness token gone") -> None:
        """Laptop ``peer`` left; aborts the grasp it commands."""
        self._peers.gone(peer)
        self._counters.pop(peer, None)
        with self._lock:
            run = self._run
            if run is not None and run.peer == peer:
                self._abort_run(run, f"commanding laptop lost: {why}")
        self._publish_status()

    def _new_peer(self, peer: str) -> None:
        live = self._peers.live()
        if live == [peer] and peer.startswith(_CAN + ":"):
            self._counters.pop(_CAN, None)  # a new laptop session on the bus: re-synchronise counters
        if len(live) > 1:
            self._publish_status()  # every laptop learns that a second one is on the link

    def _on_heartbeat(self, data: bytes) -> None:
        from field.link.codec import decode

        try:
            d = decode("LaptopHeartbeat", data)
        except ProtocolError:
            return
        sid = self._streams.feed(d.message.heartbeat_counter, d.counter)
        if sid is not None and self._peers.refresh(f"{_CAN}:{sid}"):
            self._new_peer(f"{_CAN}:{sid}")

    # ---- frames --------------------------------------------------------------------------

    def on_frame(self, kind: str, data: bytes, reply: Reply, peer: str | None = None) -> None:
        """Handle one laptop -> crane frame; answers go through ``reply(kind, bytes)``.

        ``peer`` names the sending laptop when the transport knows it (Zenoh)."""
        if kind == "EStop":
            self.estop("e-stop frame")  # fail-safe: any frame on the e-stop identifier stops the crane
            return
        plain = self._unwrap(kind, data)
        if plain is None:
            return
        if kind == "GraspCommand":
            self._on_command(plain, reply, peer)
        elif kind == "LaptopHeartbeat":
            self._on_heartbeat(plain)
        elif kind == "StatusRequest":
            self._on_status_request(plain, reply)
        # anything else (our own frames echoed, foreign frames): ignore

    def _unwrap(self, kind: str, data: bytes) -> bytes | None:
        """The plain frame, after the SecOC check when a key is configured (None: dropped)."""
        from field.link.secoc import unwrap

        plain, why = unwrap(self._secoc, kind, data)
        if why is not None:
            self.auth_failures += 1
            now = time.monotonic()
            if now - self._auth_warned_s.get(kind, -1e9) > 1.0:  # at most one warning per kind and second
                self._auth_warned_s[kind] = now
                log.warning("dropped a %s frame that failed authentication (%d so far): %s", kind, self.auth_failures, why)
            if why.check != "freshness":  # a stale or replayed frame is a clock or a replay, not a key
                self._count_mac_failure(now)
        return plain

    def _count_mac_failure(self, now: float) -> None:
        """Past ``max_mac_failures`` MAC failures within ``mac_failure_window_s``: the safe state
        (FAULT: commands refused, the running grasp aborted; only a local reset clears it)."""
        window = self._mac_failures
        window.append(now)
        while window and now - window[0] > self.config.mac_failure_window_s:
            window.popleft()
        if len(window) <= self.config.max_mac_failures:
            return
        cause = (f"{len(window)} frames failed their MAC within {self.config.mac_failure_window_s:g} s (limit "
                 f"{self.config.max_mac_failures}): a node without the key is on the bus - check it, then reset")
        with self._lock:
            if self._state is ControllerState.FAULT:
                return
            self._state, self._fault_cause = ControllerState.FAULT, cause
            if self._run is not None:
                self._abort_run(self._run, cause)
        log.error("controller FAULT: %s", cause)
        self._publish_status()

    def _on_status_request(self, data: bytes, reply: Reply) -> None:
        from field.link.codec import decode

        try:
            d = decode("StatusRequest", data)
        except ProtocolError:
            return  # corrupted query: ignore (the laptop times out)
        reply("Status", self._wire(self.status(d.message.request_id)))

    def estop(self, why: str = "e-stop") -> None:
        with self._lock:
            self._state = ControllerState.ESTOP
            if self._run is not None:
                self._abort_run(self._run, why)
        self._publish_status()

    # ---- commands ------------------------------------------------------------------------

    def _on_command(self, data: bytes, reply: Reply, peer: str | None) -> None:
        from field.link.codec import CounterCheck, decode

        try:
            d = decode("GraspCommand", data)
        except ProtocolError as exc:
            self._refuse_frame(data, exc, reply)
            return
        channel, peer = self._channel(peer)
        check = self._counter(channel).check("GraspCommand", d.counter)
        if check is CounterCheck.REPEATED:
            return  # a duplicated frame: the original was answered already
        cmd: GraspCommand = d.message
        digest = command_digest(cmd)
        with self._lock:
            known = self._known_decision(cmd.command_id, digest)
            reason = known if known is not None else self._decide(cmd, check is CounterCheck.WRONG_SEQUENCE, peer)
            if known is None:
                self._burn(cmd.command_id, reason, digest)
            run = self._accept(cmd, peer) if known is None and reason is RejectReason.NONE and peer else None
        if reason is not RejectReason.NONE:
            self.rejections.append((cmd.command_id, reason))
            self._reject(cmd.command_id, reason, reply)
            return
        try:  # accepted now, or an identical copy of an accepted command: the same answer, no run
            reply("Ack", self._wire(Ack(cmd.command_id, True)))
        finally:
            if run is not None:
                run.acked.set()

    def _refuse_frame(self, data: bytes, exc: ProtocolError, reply: Reply) -> None:
        """A command frame that failed decoding: name its id only if it passed its E2E check."""
        cid = _raw_command_id(data) if exc.integrity_ok else 0
        reason = exc.reason or RejectReason.MALFORMED
        if cid:
            with self._lock:
                if cid in self._decisions:
                    reason = RejectReason.DUPLICATE_ID
                else:
                    self._burn(cid, reason, None)
        self.rejections.append((cid, reason))
        self._reject(cid, reason, reply)

    def _channel(self, peer: str | None) -> tuple[str, str | None]:
        """(command counter channel, commanding peer) of a command from ``peer``."""
        if peer is not None:
            return peer, peer
        return _CAN, self._peers.primary()

    def _counter(self, channel: str) -> Any:
        from field.link.codec import CounterMonitor

        with self._lock:
            if channel not in self._counters:
                self._counters[channel] = CounterMonitor(self.config.counter_max_delta)
            return self._counters[channel]

    def _known_decision(self, command_id: int, digest: str) -> RejectReason | None:
        """The decision already taken on ``command_id`` (its own decision for an identical copy,
        DUPLICATE_ID for another command under a used id), or None when the id is new."""
        if command_id not in self._decisions:
            return None
        seen_digest, reason = self._decisions[command_id]
        return reason if seen_digest == digest else RejectReason.DUPLICATE_ID

    def _decide(self, cmd: GraspCommand, out_of_sequence: bool, peer: str | None) -> RejectReason:
        if cmd.command_id == 0:
            return RejectReason.MALFORMED
        if out_of_sequence:
            return RejectReason.COUNTER
        state = {ControllerState.ESTOP: RejectReason.ESTOP, ControllerState.FAULT: RejectReason.FAULT,
                 ControllerState.EXECUTING: RejectReason.BUSY}.get(self._state)
        if state is None and (peer is None or not self._peers.is_live(peer)):
            return RejectReason.UNSUPERVISED  # no live laptop would see it run, or could stop it
        return state or check_command(cmd, self.config, self._clock())

    def _burn(self, command_id: int, reason: RejectReason, digest: str | None) -> None:
        """Remember the decision on ``command_id`` for ever (journal first); under the lock."""
        if command_id == 0:
            return
        self._decisions[command_id] = (digest, reason)
        if self._journal is None:
            return
        if reason is RejectReason.NONE:
            self._journal.record_accepted(command_id, digest)  # write-ahead: never twice
        else:
            self._journal.record_rejected(command_id, reason, digest)

    def _accept(self, cmd: GraspCommand, peer: str) -> _Run:
        """EXECUTING, and the worker started - under the lock, so no e-stop falls in between."""
        run = _Run(cmd, peer, time.monotonic())
        self._state = ControllerState.EXECUTING
        self._current = cmd.command_id
        self._run = run
        run.worker = threading.Thread(target=self._execute, args=(run,), name=f"grasp-{cmd.command_id}", daemon=True)
        run.worker.start()
        return run

    def _reject(self, command_id: int, reason: RejectReason, reply: Reply) -> None:
        reply("Ack", self._wire(Ack(command_id & 0xFFFFFFFF, False, reason)))

    # ---- execution -----------------------------------------------------------------------

    def _execute(self, run: _Run) -> None:
        out, fault = self._call_executor(run)
        run.acked.wait(1.0)  # the Ack goes out before the Outcome
        with self._lock:
            out = self._final_outcome(run, out)
            self._last_outcome = out
            self._outcomes[run.cmd.command_id] = out
            self._current = 0
            self._last_run, self._run = run, None
            if fault:
                self._state = ControllerState.FAULT
                self._fault_cause = fault
            elif self._state is ControllerState.EXECUTING:
                self._state = ControllerState.DONE
            if self._journal is not None:
                self._journal.record_outcome(out)
        self._publish_frame("Outcome", self._wire(out))
        self._publish_status()

    def _call_executor(self, run: _Run) -> tuple[Outcome, str | None]:
        """(outcome, why the executor failed or None); an already aborted command never starts."""
        cmd = run.cmd
        if run.abort.is_set():
            return Outcome(cmd.command_id, OutcomeClass.ABORTED, 0, 0), None
        try:
            execute = getattr(self.executor, "execute", None)
            out = execute(cmd, run.abort.is_set) if callable(execute) else self.executor(cmd)
            if not isinstance(out, Outcome):
                raise TypeError(f"executor returned {type(out).__name__}, not Outcome")
            return out, None
        except Exception as exc:
            log.exception("executor failed on command %d: controller FAULT", cmd.command_id)
            return (Outcome(cmd.command_id, OutcomeClass.ABORTED, 0, 0),
                    f"executor failed on command {cmd.command_id}: {type(exc).__name__}: {exc}")

    @staticmethod
    def _final_outcome(run: _Run, out: Outcome) -> Outcome:
        cls = OutcomeClass.ABORTED if run.reason is not None else out.outcome_class
        return Outcome(run.cmd.command_id, cls, out.logs_grasped, out.balance_cos_milli)

    def _abort_run(self, run: _Run, why: str) -> None:
        """Stop ``run`` (under the lock): the flag the executor polls, and ``abort()`` if any."""
        if run.reason is not None:
            return
        run.reason = why
        run.abort.set()
        log.warning("aborting command %d: %s", run.cmd.command_id, why)
        abort = getattr(self.executor, "abort", None)
        if callable(abort) and not callable(getattr(self.executor, "execute", None)):
            try:
                abort()
            except Exception:
                log.exception("executor abort() failed; the outcome is ABORTED regardless")

    # ---- output --------------------------------------------------------------------------

    def _wire(self, msg: Any) -> bytes:
        """``msg`` as frame bytes: E2E, then SecOC when a key is configured, then the crane's
        signature appended when it has its signing key (the transport carries it:
        :func:`field.link.signing.carriage_frames`)."""
        kind, data = self._encoder.encode(msg)
        if self._secoc is None:
            return data
        data = self._secoc.secure(kind, data)
        return data if self._signer is None else data + self._signer.sign(kind, data)

    def _publish_status(self) -> None:
        self._publish_frame("Status", self._wire(self.status(0)))

    def _publish_frame(self, kind: str, data: bytes) -> None:
        if self._publish is not None:
            try:
                self._publish(kind, data)
            except Exception:
                log.debug("publishing %s failed; a status query recovers what it carried", kind, exc_info=True)

    # ---- supervision ---------------------------------------------------------------------

    def _supervise(self) -> None:
        period = min(0.05, self.config.laptop_timeout_s / 4)
        while not self._stop.wait(period):
            self._check_commanding_peer()

    def _check_commanding_peer(self) -> None:
        with self._lock:
            run = self._run
            if run is None or run.reason is not None:
                return
            why = self._peer_loss(run)
            if why is not None:
                self._abort_run(run, why)

    def _peer_loss(self, run: _Run) -> str | None:
        """Why ``run``'s commanding laptop counts as lost, or None (under the lock). It was live at
        the acceptance; it is lost once it is not live (CAN: no fresh, in-sequence heartbeat for
        ``laptop_timeout_s``; Zenoh: its token gone), whatever another laptop does."""
        if self._peers.is_live(run.peer):
            return None
        return f"commanding laptop {run.peer} lost (no fresh heartbeat or token for {self.config.laptop_timeout_s:.2f} s)"
