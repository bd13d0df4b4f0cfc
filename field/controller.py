"""The crane controller twin: the crane's side of the link, speaking the protocol like a real one.

:class:`CraneController` is transport-agnostic protocol logic. A transport (CAN bus or Zenoh
session, :data:`field.link.base.CONTROLLER_TRANSPORTS`) feeds it frames with
:meth:`CraneController.on_frame` and sends what it answers / publishes. For every grasp command
it checks, in this order, and rejects with the first failing reason:

1. end-to-end CRC (CRC), frame length / version / field sanity (MALFORMED);
2. rolling counter (a repeated counter = duplicated frame: dropped silently; a jump larger than
   ``counter_max_delta`` or backwards = COUNTER);
3. command id seen before (DUPLICATE_ID) — an id is never executed twice, also across controller
   restarts when ``journal_path`` is set (the id is journaled *before* execution starts);
4. ESTOP / FAULT / BUSY state;
5. pile data age (STALE), opening width (WIDTH_RANGE), heading (HEADING_RANGE), target log count
   (MALFORMED), reach envelope around the crane base in SWEREF 99 TM (OUT_OF_REACH).

Accepted commands run on a worker thread through an injected executor
(``Callable[[GraspCommand], Outcome]``, see :class:`GraspExecutor`); the outcome is published
and remembered in the status (``last_outcome``). The controller sends a heartbeat (CAN:
``send_periodic``; Zenoh: a liveliness token), watches the laptop's (abort on loss when
``abort_on_laptop_loss``), and latches ESTOP on an e-stop frame — fail-safe: any frame on the
e-stop identifier stops, even one that fails its CRC. Only a local :meth:`reset_estop` clears it.

Executors are registered by name in :data:`EXECUTORS` (imported when chosen): ``"fixed"``
(deterministic, here, for tests) and ``"pybullet"`` (:mod:`field.executor`, grasp trials on the
twin pile: ``make_executor("pybullet", pile="pile.json")``).

Run as its own process with :func:`run_controller` (a CLI calls it).
"""

from __future__ import annotations

import importlib
import json
import math
import secrets
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

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

JOURNAL_FORMAT = "loggrasp.controller_journal"
JOURNAL_VERSION = "1.0"
EXECUTION_LOG_FORMAT = "loggrasp.execution_log"
EXECUTION_LOG_VERSION = "1.0"


# --- configuration --------------------------------------------------------------------------


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

    def contains(self, cmd: GraspCommand) -> bool:
        de = cmd.easting_mm / 1000.0 - self.base_easting_m
        dn = cmd.northing_mm / 1000.0 - self.base_northing_m
        dz = cmd.height_mm / 1000.0 - self.base_height_m
        r = math.hypot(de, dn)
        return self.min_reach_m <= r <= self.max_reach_m and self.min_dz_m <= dz <= self.max_dz_m


@dataclass(frozen=True)
class ControllerConfig:
    reach: ReachEnvelope = field(default_factory=ReachEnvelope)
    max_pile_age_s: float = 30.0  # oldest pile data a command may be based on [s]
    max_future_skew_s: float = 2.0  # plan timestamps ahead of the crane clock by more are STALE [s]
    min_width_mm: int = 300  # grapple opening range [mm]
    max_width_mm: int = 1550  # [mm]
    min_heading_cdeg: int = 0  # accepted closing-axis headings [0.01 deg]; pi-periodic axis
    max_heading_cdeg: int = 17999  # [0.01 deg]
    max_target_logs: int = 12  # more target logs than this is MALFORMED [-]
    counter_max_delta: int = 2  # rolling-counter jump tolerated on commands (lost frames) [-]
    heartbeat_period_s: float = 0.05  # crane heartbeat period [s]
    laptop_timeout_s: float = 1.0  # laptop counts as lost after this long without a frame [s]
    abort_on_laptop_loss: bool = True  # abort the running grasp when the laptop is lost [-]
    journal_path: str | None = None  # persist seen ids / outcomes here (survives restarts)
    journal_keep: int = 10_000  # journal entries kept [-]

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
        for name in ("heartbeat_period_s", "laptop_timeout_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 s, got {getattr(self, name)}")


# --- executors ------------------------------------------------------------------------------


@runtime_checkable
class GraspExecutor(Protocol):
    """What the controller runs for an accepted command.

    ``__call__(cmd) -> Outcome`` executes the grasp (blocking; called on a worker thread, one
    command at a time) and returns its outcome for ``cmd.command_id``. An executor MAY define
    ``abort()`` (called from another thread on e-stop / laptop loss) to cut the grasp short; the
    controller reports ``ABORTED`` whatever it returns afterwards. Raising marks the controller
    FAULT (outcome ABORTED).
    """

    def __call__(self, cmd: GraspCommand) -> Outcome: ...


#: executor name -> "module:Class" (imported when chosen, so pybullet loads only for "pybullet").
EXECUTORS: dict[str, str] = {
    "fixed": "field.controller:FixedOutcomeExecutor",  # deterministic, for tests
    "pybullet": "field.executor:PybulletTrialExecutor",  # grasp trials on the twin pile (pile=...)
}


def make_executor(name: str, **kwargs: Any) -> GraspExecutor:
    """Instantiate a registered executor by name."""
    if name not in EXECUTORS:
        raise ControllerError(f"unknown executor {name!r}; registered: {sorted(EXECUTORS)}")
    module_name, _, attr = EXECUTORS[name].partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ControllerError(f"executor {name!r} could not be loaded ({exc}); install what it needs") from exc
    return cls(**kwargs)


class FixedOutcomeExecutor:
    """Deterministic test executor: after ``delay_s`` returns a fixed outcome.

    ``delay_by_target_logs`` overrides the delay per target log count (a slow command in tests).

    ``logs_grasped`` defaults to the command's target count. Every execution start is appended
    to ``log_path`` (when given; read it with :func:`read_execution_log`) so tests in another
    process can prove a command never ran twice. ``abort()`` cuts the delay short.
    """

    def __init__(
        self,
        delay_s: float = 0.05,
        outcome_class: OutcomeClass | str | int = OutcomeClass.SUCCESS,
        logs_grasped: int | None = None,
        balance_cos_milli: int = 985,
        log_path: str | None = None,
        delay_by_target_logs: dict[int, float] | None = None,
    ):
        if not delay_s >= 0:
            raise ValueError(f"delay_s must be >= 0 s, got {delay_s}")
        if isinstance(outcome_class, str):
            outcome_class = OutcomeClass[outcome_class.upper()]
        self.delay_s = float(delay_s)
        self.outcome_class = OutcomeClass(outcome_class)
        self.logs_grasped = logs_grasped
        self.balance_cos_milli = int(balance_cos_milli)
        self.log_path = log_path
        # per-target-count delay overrides [s] (lets a test make one command slow)
        self.delay_by_target_logs = {int(k): float(v) for k, v in (delay_by_target_logs or {}).items()}
        self.executed: list[int] = []
        self._abort = threading.Event()
        if log_path is not None and not Path(log_path).exists():
            Path(log_path).parent.mkdir(parents=True, exist_ok=True)
            with open(log_path, "w") as f:
                f.write(json.dumps({"format": EXECUTION_LOG_FORMAT, "version": EXECUTION_LOG_VERSION}) + "\n")

    def __call__(self, cmd: GraspCommand) -> Outcome:
        self._abort.clear()
        self.executed.append(cmd.command_id)
        if self.log_path is not None:
            import os

            with open(self.log_path, "a") as f:
                f.write(json.dumps({"command_id": cmd.command_id, "t": time.time()}) + "\n")
                f.flush()
                os.fsync(f.fileno())
        self._abort.wait(self.delay_by_target_logs.get(cmd.target_log_count, self.delay_s))
        n = cmd.target_log_count if self.logs_grasped is None else self.logs_grasped
        return Outcome(cmd.command_id, self.outcome_class, n, self.balance_cos_milli)

    def abort(self) -> None:
        self._abort.set()


def read_execution_log(path: str | Path) -> list[int]:
    """Command ids in the order a :class:`FixedOutcomeExecutor` started them."""
    lines = Path(path).read_text().splitlines()
    if not lines:
        return []
    head = json.loads(lines[0])
    if head.get("format") != EXECUTION_LOG_FORMAT or str(head.get("version", "")).split(".")[0] != "1":
        raise ControllerError(f"{path} is not a version-1 {EXECUTION_LOG_FORMAT} file")
    return [int(json.loads(line)["command_id"]) for line in lines[1:] if line.strip()]


# --- journal --------------------------------------------------------------------------------


class ControllerJournal:
    """Persistent memory of command ids and outcomes (atomic JSON rewrite per change).

    Entries: ``{"command_id", "status": "accepted"|"done", "outcome": {...}|null}``. An id
    accepted but never finished (controller crashed mid-command) is reported ABORTED on load.
    """

    def __init__(self, path: str | Path, keep: int = 10_000):
        self.path = Path(path)
        self.keep = keep
        self.entries: dict[int, dict[str, Any]] = {}
        if self.path.exists():
            self._load()

    def _load(self) -> None:
        try:
            doc = json.loads(self.path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ControllerError(f"controller journal {self.path} is unreadable ({exc}); move it away") from exc
        if doc.get("format") != JOURNAL_FORMAT:
            raise ControllerError(f"{self.path} is not a {JOURNAL_FORMAT} file")
        major = str(doc.get("version", "")).split(".")[0]
        if major != JOURNAL_VERSION.split(".")[0]:
            raise ControllerError(
                f"{self.path} has journal version {doc.get('version')}, this code reads "
                f"{JOURNAL_VERSION.split('.')[0]}.x; update loggrasp"
            )
        for e in doc.get("entries", []):
            self.entries[int(e["command_id"])] = e

    def save(self) -> None:
        from synth.pile import atomic_write_bytes

        items = list(self.entries.values())[-self.keep :]
        doc = {"format": JOURNAL_FORMAT, "version": JOURNAL_VERSION, "entries": items}
        atomic_write_bytes(self.path, json.dumps(doc).encode())

    def record_accepted(self, command_id: int) -> None:
        self.entries[command_id] = {"command_id": command_id, "status": "accepted", "outcome": None}
        self.save()

    def record_outcome(self, outcome: Outcome) -> None:
        self.entries[outcome.command_id] = {
            "command_id": outcome.command_id,
            "status": "done",
            "outcome": {
                "outcome_class": outcome.outcome_class.name,
                "logs_grasped": outcome.logs_grasped,
                "balance_cos_milli": outcome.balance_cos_milli,
            },
        }
        self.save()

    def recover(self) -> tuple[set[int], Outcome | None]:
        """(all ids seen, last outcome); interrupted commands become ABORTED (and are saved)."""
        last: Outcome | None = None
        changed = False
        for cid, e in self.entries.items():
            if e["status"] == "accepted":
                out = Outcome(cid, OutcomeClass.ABORTED, 0, 0)
                e.update(status="done", outcome={"outcome_class": "ABORTED", "logs_grasped": 0, "balance_cos_milli": 0})
                changed = True
            else:
                o = e["outcome"]
                out = Outcome(cid, OutcomeClass[o["outcome_class"]], int(o["logs_grasped"]), int(o["balance_cos_milli"]))
            last = out
        if changed:
            self.save()
        return set(self.entries), last


# --- the controller -------------------------------------------------------------------------

Reply = Callable[[str, bytes], None]


class CraneController:
    """Protocol logic of the crane controller (thread-safe). See the module docstring."""

    def __init__(
        self,
        config: ControllerConfig | None = None,
        executor: GraspExecutor | Callable[[GraspCommand], Outcome] | None = None,
        *,
        clock: Callable[[], float] = time.time,
    ):
        from field.link.codec import CounterMonitor, Encoder

        self.config = config or ControllerConfig()
        self.executor = executor if executor is not None else FixedOutcomeExecutor()
        if not callable(self.executor):
            raise ValueError(f"executor must be callable (GraspCommand -> Outcome), got {self.executor!r}")
        self._clock = clock
        self._encoder = Encoder(first_counter=secrets.randbits(8))  # a restart is a new counter session
        self._counters = CounterMonitor(self.config.counter_max_delta)
        self._lock = threading.RLock()
        self._state = ControllerState.IDLE
        self._current = 0
        self._heartbeat = 0
        self._last_outcome: Outcome | None = None
        self._seen: set[int] = set()
        self._outcomes: dict[int, Outcome] = {}
        self._abort_reason: str | None = None
        self._worker: threading.Thread | None = None
        self._laptop_last_seen: float | None = None
        self._publish: Reply | None = None
        self._journal = ControllerJournal(self.config.journal_path, self.config.journal_keep) if self.config.journal_path else None
        if self._journal is not None:
            self._seen, self._last_outcome = self._journal.recover()
        self.rejections: list[tuple[int, RejectReason]] = []  # diagnostics
        self._stop = threading.Event()
        self._supervisor: threading.Thread | None = None

    # ---- wiring --------------------------------------------------------------------------

    def attach(self, publish: Reply) -> None:
        """Give the controller its way to publish unsolicited frames (Outcome, Status)."""
        self._publish = publish

    def start(self) -> None:
        """Start laptop-loss supervision."""
        if self._supervisor is None:
            self._supervisor = threading.Thread(target=self._supervise, name="controller-supervisor", daemon=True)
            self._supervisor.start()

    def close(self, timeout_s: float = 2.0) -> None:
        """Abort a running grasp and stop supervision."""
        self._stop.set()
        with self._lock:
            worker = self._worker
            if worker is not None and worker.is_alive():
                self._abort_reason = "controller shutdown"
                self._abort_executor()
        if worker is not None:
            worker.join(timeout_s)
        if self._supervisor is not None:
            self._supervisor.join(timeout_s)

    # ---- state ---------------------------------------------------------------------------

    @property
    def state(self) -> ControllerState:
        return self._state

    def status(self, request_id: int = 0) -> ControllerStatus:
        with self._lock:
            return ControllerStatus(self._state, self._current, self._heartbeat, self._last_outcome, request_id)

    def outcome_of(self, command_id: int) -> Outcome | None:
        return self._outcomes.get(command_id)

    def reset_estop(self) -> None:
        """Local reset on the crane (not reachable over the link): ESTOP/FAULT -> IDLE."""
        with self._lock:
            if self._worker is not None and self._worker.is_alive():
                raise ControllerError("cannot reset while the aborted grasp is still winding down; retry")
            if self._state in (ControllerState.ESTOP, ControllerState.FAULT):
                self._state = ControllerState.IDLE
        self._publish_status()

    reset_fault = reset_estop

    def heartbeat_frame(self) -> bytes:
        """Next crane heartbeat frame (counter incremented; carries the state)."""
        from field.link.codec import CraneHeartbeat

        with self._lock:
            self._heartbeat = (self._heartbeat + 1) & 0xFFFFFFFF
            msg = CraneHeartbeat(self._heartbeat, self._state)
        return self._encoder.encode(msg)[1]

    def laptop_seen(self) -> None:
        """A transport saw the laptop alive (heartbeat frame, liveliness token)."""
        now = time.monotonic()
        with self._lock:
            last = self._laptop_last_seen
            if last is None or now - last > self.config.laptop_timeout_s:
                self._counters.reset()  # a new laptop session: re-synchronise counters
            self._laptop_last_seen = now

    def laptop_lost(self, why: str = "laptop heartbeat lost") -> None:
        with self._lock:
            self._laptop_last_seen = None
            self._counters.reset()
            running = self._worker is not None and self._worker.is_alive()
            if running and self.config.abort_on_laptop_loss and self._abort_reason is None:
                self._abort_reason = why
                self._abort_executor()

    # ---- frames --------------------------------------------------------------------------

    def on_frame(self, kind: str, data: bytes, reply: Reply) -> None:
        """Handle one laptop -> crane frame; answers go through ``reply(kind, bytes)``."""
        from field.link.codec import decode

        if kind == "EStop":
            # fail-safe: any frame on the e-stop identifier stops the crane
            self.laptop_seen()
            self.estop("e-stop frame")  # publishes the new status
            return
        if kind == "GraspCommand":
            self._on_command(data, reply)
            return
        if kind in ("StatusRequest", "LaptopHeartbeat"):
            try:
                d = decode(kind, data)
            except ProtocolError:
                return  # corrupted query / heartbeat: ignore (the laptop retries / times out)
            self.laptop_seen()
            if kind == "StatusRequest":
                reply("Status", self._status_frame(d.message.request_id))
            return
        # anything else (our own frames echoed, foreign frames): ignore

    def estop(self, why: str = "e-stop") -> None:
        with self._lock:
            self._state = ControllerState.ESTOP
            if self._worker is not None and self._worker.is_alive() and self._abort_reason is None:
                self._abort_reason = why
                self._abort_executor()
        self._publish_status()

    def _on_command(self, data: bytes, reply: Reply) -> None:
        from field.link.codec import CounterCheck, decode

        raw_id = int.from_bytes(bytes(data[4:8]), "little") if len(data) >= 8 else 0
        try:
            d = decode("GraspCommand", data)
        except ProtocolError as exc:
            self._reject(raw_id, exc.reason or RejectReason.MALFORMED, reply)
            return
        cmd: GraspCommand = d.message
        self.laptop_seen()
        check = self._counters.check("GraspCommand", d.counter)
        if check is CounterCheck.REPEATED:
            return  # a duplicated frame: the original was answered already
        with self._lock:
            if cmd.command_id == 0:
                reason = RejectReason.MALFORMED
            elif cmd.command_id in self._seen:
                reason = RejectReason.DUPLICATE_ID
            elif check is CounterCheck.WRONG_SEQUENCE:
                reason = RejectReason.COUNTER
            else:
                reason = self._validate(cmd)
            if cmd.command_id != 0:
                self._seen.add(cmd.command_id)
            if reason is not RejectReason.NONE:
                self.rejections.append((cmd.command_id, reason))
            else:
                if self._journal is not None:
                    self._journal.record_accepted(cmd.command_id)  # write-ahead: never twice
                self._state = ControllerState.EXECUTING
                self._current = cmd.command_id
                self._abort_reason = None
        if reason is not RejectReason.NONE:
            self._reject(cmd.command_id, reason, reply)
            return
        reply("Ack", self._encoder.encode(Ack(cmd.command_id, True))[1])
        worker = threading.Thread(target=self._execute, args=(cmd,), name=f"grasp-{cmd.command_id}", daemon=True)
        with self._lock:
            self._worker = worker
        worker.start()

    def _validate(self, cmd: GraspCommand) -> RejectReason:
        c = self.config
        if self._state is ControllerState.ESTOP:
            return RejectReason.ESTOP
        if self._state is ControllerState.FAULT:
            return RejectReason.FAULT
        if self._state is ControllerState.EXECUTING:
            return RejectReason.BUSY
        age = cmd.age_s(self._clock())
        if age > c.max_pile_age_s or age < -c.max_future_skew_s:
            return RejectReason.STALE
        if not c.min_width_mm <= cmd.opening_width_mm <= c.max_width_mm:
            return RejectReason.WIDTH_RANGE
        if not c.min_heading_cdeg <= cmd.heading_cdeg <= c.max_heading_cdeg:
            return RejectReason.HEADING_RANGE
        if not 1 <= cmd.target_log_count <= c.max_target_logs:
            return RejectReason.MALFORMED
        if not c.reach.contains(cmd):
            return RejectReason.OUT_OF_REACH
        return RejectReason.NONE

    def _reject(self, command_id: int, reason: RejectReason, reply: Reply) -> None:
        reply("Ack", self._encoder.encode(Ack(command_id & 0xFFFFFFFF, False, reason))[1])

    def _execute(self, cmd: GraspCommand) -> None:
        fault = False
        try:
            out = self.executor(cmd)
            if not isinstance(out, Outcome):
                raise TypeError(f"executor returned {type(out).__name__}, not Outcome")
        except Exception:
            fault = True
            out = Outcome(cmd.command_id, OutcomeClass.ABORTED, 0, 0)
        with self._lock:
            if self._abort_reason is not None and out.outcome_class is not OutcomeClass.ABORTED:
                out = Outcome(cmd.command_id, OutcomeClass.ABORTED, out.logs_grasped, out.balance_cos_milli)
            if out.command_id != cmd.command_id:
                out = Outcome(cmd.command_id, out.outcome_class, out.logs_grasped, out.balance_cos_milli)
            self._last_outcome = out
            self._outcomes[cmd.command_id] = out
            self._current = 0
            if fault:
                self._state = ControllerState.FAULT
            elif self._state is ControllerState.EXECUTING:
                self._state = ControllerState.DONE
            if self._journal is not None:
                self._journal.record_outcome(out)
        self._publish_frame("Outcome", self._encoder.encode(out)[1])
        self._publish_status()

    def _abort_executor(self) -> None:
        abort = getattr(self.executor, "abort", None)
        if callable(abort):
            try:
                abort()
            except Exception:
                pass  # the outcome is ABORTED regardless

    def _status_frame(self, request_id: int) -> bytes:
        return self._encoder.encode(self.status(request_id))[1]

    def _publish_status(self) -> None:
        self._publish_frame("Status", self._status_frame(0))

    def _publish_frame(self, kind: str, data: bytes) -> None:
        if self._publish is not None:
            try:
                self._publish(kind, data)
            except Exception:
                pass  # the status query recovers what a lost publication carried

    def _supervise(self) -> None:
        period = min(0.05, self.config.laptop_timeout_s / 4)
        while not self._stop.wait(period):
            last = self._laptop_last_seen
            if last is not None and time.monotonic() - last > self.config.laptop_timeout_s:
                self.laptop_lost()


# --- running as a process -------------------------------------------------------------------


def run_controller(
    link_url: str,
    executor: GraspExecutor | Callable[[GraspCommand], Outcome] | str = "fixed",
    stop_event: threading.Event | None = None,
    config: ControllerConfig | None = None,
    *,
    ready_event: threading.Event | None = None,
    on_serve: Callable[[CraneController], None] | None = None,
    **transport_kwargs: Any,
) -> ControllerStatus:
    """Serve the crane side of ``link_url`` until ``stop_event`` is set; returns the final status.

    ``executor`` is a callable or a registered name (:data:`EXECUTORS`). The URL forms are those
    of :func:`field.link.open_link` (``can://virtual/ch0``, ``can://remote/127.0.0.1:PORT/ch0``,
    ``zenoh://127.0.0.1:7447/crane1`` — the controller LISTENS on that endpoint — ...).
    ``ready_event`` is set once the controller serves; ``on_serve(controller)`` is called just
    before (e.g. to watch its ``rejections``).
    """
    from field.link.base import open_controller_transport

    if isinstance(executor, str):
        executor = make_executor(executor)
    stop_event = stop_event or threading.Event()
    controller = CraneController(config, executor)
    transport = open_controller_transport(link_url, heartbeat_period_s=controller.config.heartbeat_period_s, **transport_kwargs)
    try:
        transport.start(controller)
        controller.start()
        if on_serve is not None:
            on_serve(controller)
        if ready_event is not None:
            ready_event.set()
        # poll: a signal delivered to a library thread (zenoh, python-can) must not leave the
        # main thread blocked forever, so handlers that set stop_event get to run
        while not stop_event.wait(0.1):
            pass
    finally:
        controller.close()
        transport.close()
    return controller.status()


def controller_config_from_dict(d: dict[str, Any]) -> ControllerConfig:
    """Build a :class:`ControllerConfig` from plain values (e.g. a JSON file; ``reach`` nested)."""
    d = dict(d)
    reach = ReachEnvelope(**d.pop("reach", {}))
    return ControllerConfig(reach=reach, **d)


def controller_config_to_dict(c: ControllerConfig) -> dict[str, Any]:
    return asdict(c)
