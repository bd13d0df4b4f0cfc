"""The crane controller twin: the crane's side of the link, speaking the protocol like a real one.

:class:`CraneController` is transport-agnostic protocol logic. A transport (CAN bus or Zenoh
session, :data:`field.link.base.CONTROLLER_TRANSPORTS`) feeds it frames with
:meth:`CraneController.on_frame` and sends what it answers / publishes. For every grasp command
it checks, in this order, and rejects with the first failing reason:

0. with a SecOC key: the frame's MAC and freshness (a failing frame is dropped unanswered);
1. end-to-end CRC (CRC), frame length / reserved bits / version / field sanity (MALFORMED). A
   reply names the command id only when the frame passed its E2E check; otherwise it carries
   id 0, so no laptop ever takes the answer to a corrupted frame for the answer to its command;
2. rolling counter (a repeated counter = duplicated frame: dropped silently; a jump larger than
   ``counter_max_delta`` or backwards = COUNTER);
3. command id seen before — every id the controller has seen, accepted or rejected, is burned
   and never executed again; with ``journal_path`` also across restarts (the id is journaled
   *before* the answer goes out and before execution starts). An identical copy of a command
   it has decided on (a duplicated or late frame) gets that same decision again, never a second
   execution; another command under a used id gets DUPLICATE_ID. So the first answer a laptop
   gets for its command is always the controller's decision about it;
4. ESTOP / FAULT / BUSY state;
5. :func:`check_command`: pile data age (STALE), opening width (WIDTH_RANGE), heading
   (HEADING_RANGE), target log count (MALFORMED), reach envelope around the crane base in
   SWEREF 99 TM (OUT_OF_REACH: horizontal reach and height window).

Accepted commands run on a worker thread through an injected executor (see
:class:`GraspExecutor`), started under the same lock that accepted them, so an e-stop is either
before the acceptance (the command is refused ESTOP) or after it (the grasp is aborted, or never
starts): no e-stop is ever lost. The outcome is published and remembered in the status
(``last_outcome``).

Supervision: the controller sends a heartbeat (CAN: ``send_periodic``; Zenoh: a liveliness
token) and follows the laptops (:mod:`field.link.supervision`): on CAN a laptop is alive only
while its heartbeats are fresh and in sequence; on Zenoh while its liveliness token exists. The
laptop that was live when a command was accepted (on Zenoh: the one that sent it) is its
*commanding peer*; losing it aborts the grasp (``abort_on_laptop_loss``), whoever else is
connected. A second laptop is reported (log warning, ``ControllerStatus.laptops``). An e-stop
frame latches ESTOP — fail-safe: any frame on the e-stop identifier stops, even one that fails
its CRC or MAC. Only a local :meth:`reset_estop` clears it.

Executors are registered by name in :data:`EXECUTORS` (imported when chosen): ``"fixed"``
(deterministic, here, for tests) and ``"pybullet"`` (:mod:`field.executor`, grasp trials on the
twin pile: ``make_executor("pybullet", pile="pile.json")``).

Run as its own process with :func:`run_controller` (a CLI calls it).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import logging
import math
import os
import secrets
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Protocol, runtime_checkable

from field.audit.journal import chained_journal, rewrite_journal
from field.errors import ControllerError, ProtocolError
from field.link.messages import (
    DEFAULT_MAX_FUTURE_SKEW_S,
    DEFAULT_MAX_PILE_AGE_S,
    Ack,
    ControllerState,
    ControllerStatus,
    GraspCommand,
    Outcome,
    OutcomeClass,
    RejectReason,
)

log = logging.getLogger(__name__)

JOURNAL_FORMAT = "loggrasp.controller_journal"
JOURNAL_VERSION = "2.1"  # 2.1: hash-chained lines (field/audit/chain.py); 2.0 is read and rewritten chained
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
    abort_on_laptop_loss: bool = True  # abort the running grasp when its commanding laptop is lost [-]
    journal_path: str | None = None  # burn seen ids / outcomes here (survives restarts); crane-sim: on
    journal_keep: int = 10_000  # journal entries kept on compaction [-]
    journal_fsync: bool = True  # fsync every journal line (off only for throw-away twins in tests) [-]
    secoc_key_path: str | None = None  # pre-shared key file: accept authenticated frames only
    secoc_window_s: float = 2.0  # SecOC freshness window [s]

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
        for name in ("heartbeat_period_s", "laptop_timeout_s", "secoc_window_s"):
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


# --- executors ------------------------------------------------------------------------------


@runtime_checkable
class GraspExecutor(Protocol):
    """What the controller runs for an accepted command.

    ``execute(cmd, should_abort) -> Outcome`` executes the grasp (blocking; called on a worker
    thread, one command at a time) and returns its outcome for ``cmd.command_id``.
    ``should_abort()`` turns True once the grasp must stop (e-stop, commanding laptop lost,
    shutdown): the executor polls it, stops promptly and returns the true state (logs held at
    that moment). The controller reports ``ABORTED`` whatever class it returns then. Raising
    marks the controller FAULT (outcome ABORTED).

    A plain callable ``cmd -> Outcome`` is accepted too; it cannot be stopped (an ``abort()``
    method on it is called on abort).
    """

    def execute(self, cmd: GraspCommand, should_abort: Callable[[], bool]) -> Outcome: ...


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
    process can prove a command never ran twice. ``should_abort`` cuts the delay short.
    """

    poll_s = 0.005  # how often should_abort is looked at while "moving" [s]

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
        self.aborted: list[int] = []  # ids whose delay was cut short by should_abort
        if log_path is not None and not Path(log_path).exists():
            Path(log_path).parent.mkdir(parents=True, exist_ok=True)
            with open(log_path, "w") as f:
                f.write(json.dumps({"format": EXECUTION_LOG_FORMAT, "version": EXECUTION_LOG_VERSION}) + "\n")

    def execute(self, cmd: GraspCommand, should_abort: Callable[[], bool]) -> Outcome:
        self.executed.append(cmd.command_id)
        self._log_start(cmd.command_id)
        end = time.monotonic() + self.delay_by_target_logs.get(cmd.target_log_count, self.delay_s)
        while (left := end - time.monotonic()) > 0:
            if should_abort():
                self.aborted.append(cmd.command_id)
                break
            time.sleep(min(left, self.poll_s))
        n = cmd.target_log_count if self.logs_grasped is None else self.logs_grasped
        return Outcome(cmd.command_id, self.outcome_class, n, self.balance_cos_milli)

    def __call__(self, cmd: GraspCommand) -> Outcome:
        return self.execute(cmd, lambda: False)

    def _log_start(self, command_id: int) -> None:
        if self.log_path is None:
            return
        with open(self.log_path, "a") as f:
            f.write(json.dumps({"command_id": command_id, "t": time.time()}) + "\n")
            f.flush()
            os.fsync(f.fileno())


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


def _outcome_doc(out: Outcome) -> dict[str, Any]:
    return {"outcome_class": out.outcome_class.name, "logs_grasped": out.logs_grasped,
            "balance_cos_milli": out.balance_cos_milli}


class ControllerJournal:
    """Persistent memory of every command id seen, and of outcomes (append-only JSON lines).

    First line ``{"format", "version"}``, then one entry per line: ``{"command_id", "status":
    "accepted"|"rejected"|"done", "reason": NAME (rejected), "outcome": {...} (done)}``; a later
    line about an id supersedes an earlier one. Each line is flushed (and fsynced) before the
    controller answers. An id accepted but never finished (controller crashed mid-command) is
    reported ABORTED on load. A version-1 journal (one JSON document) is read and rewritten as
    version 2; a journal with more than ``2 * keep`` lines is compacted to its last ``keep`` ids
    on load (an id older than that is long past any staleness limit). Lines are hash-chained
    (2.1, :mod:`field.audit.chain`; a compaction's head continues the old head); ``loggrasp audit
    verify`` checks the file, and a chain that does not verify is refused on load.
    """

    def __init__(self, path: str | Path, keep: int = 10_000, fsync: bool = True):
        self.path = Path(path)
        self.keep = keep
        self.fsync = fsync
        self.entries: dict[int, dict[str, Any]] = {}
        self._lines = 0
        self._chain = None  # the hash chain's writer (field.audit.chain.ChainFile)
        if self.path.exists():
            self._load()
        if not self.path.exists() or self._lines > 2 * keep:
            self._rewrite()

    def _load(self) -> None:
        try:
            lines = self.path.read_text().splitlines()
            head = json.loads(lines[0]) if lines else {}
        except (OSError, ValueError) as exc:
            raise ControllerError(f"controller journal {self.path} is unreadable ({exc}); move it away") from exc
        if head.get("format") != JOURNAL_FORMAT:
            raise ControllerError(f"{self.path} is not a {JOURNAL_FORMAT} file; move it away or fix --journal")
        major = str(head.get("version", "")).split(".")[0]
        if major == "1":
            for e in head.get("entries", []):
                self._put(e)
            self._lines = 10 ** 9  # rewrite as version 2
            return
        if major != JOURNAL_VERSION.split(".")[0]:
            raise ControllerError(f"{self.path} has journal version {head.get('version')}, this code reads "
                                  f"1.x and {JOURNAL_VERSION.split('.')[0]}.x; update loggrasp")
        self._read_entries(lines[1:])
        self._chain = chained_journal(self.path, self.fsync)  # None: rewrite it chained
        self._lines = self._lines if self._chain is not None else 10 ** 9

    def _read_entries(self, lines: list[str]) -> None:
        for i, line in enumerate(lines):
            try:
                self._put(json.loads(line))
            except (ValueError, KeyError, TypeError) as exc:
                if i == len(lines) - 1:  # a torn last line: the controller died while writing it
                    log.warning("journal %s: ignoring its torn last line", self.path)
                    break
                raise ControllerError(f"controller journal {self.path} line {i + 2} is corrupt ({exc}); "
                                      f"move the file away") from exc
        self._lines = len(lines)

    def _put(self, entry: dict[str, Any]) -> None:
        cid = int(entry["command_id"])
        self.entries.pop(cid, None)  # re-insert: dict order = order of the latest line
        self.entries[cid] = entry

    def _rewrite(self) -> None:
        items = list(self.entries.values())[-self.keep:]
        self.entries = {int(e["command_id"]): e for e in items}
        self._chain = rewrite_journal(self.path, {"format": JOURNAL_FORMAT, "version": JOURNAL_VERSION}, items,
                                      self._chain, self.fsync)
        self._lines = len(items)

    def _append(self, entry: dict[str, Any]) -> None:
        self._put(entry)
        self._chain.append(entry)  # one write of a whole line, fsynced
        self._lines += 1

    def record_accepted(self, command_id: int, digest: str | None = None) -> None:
        self._append({"command_id": command_id, "status": "accepted", "digest": digest})

    def record_rejected(self, command_id: int, reason: RejectReason, digest: str | None = None) -> None:
        self._append({"command_id": command_id, "status": "rejected", "reason": reason.name, "digest": digest})

    def record_outcome(self, outcome: Outcome) -> None:
        digest = self.entries.get(outcome.command_id, {}).get("digest")
        self._append({"command_id": outcome.command_id, "status": "done", "digest": digest,
                      "outcome": _outcome_doc(outcome)})

    def recover(self) -> tuple[dict[int, tuple[str | None, RejectReason]], Outcome | None]:
        """(decision per id seen: (command digest, reason; NONE = accepted), last outcome);
        interrupted commands become ABORTED (and are journaled)."""
        last: Outcome | None = None
        decisions: dict[int, tuple[str | None, RejectReason]] = {}
        for cid, e in list(self.entries.items()):
            reason = RejectReason[e["reason"]] if e["status"] == "rejected" else RejectReason.NONE
            decisions[cid] = (e.get("digest"), reason)
            if e["status"] == "accepted":
                last = Outcome(cid, OutcomeClass.ABORTED, 0, 0)
                self.record_outcome(last)
            elif e["status"] == "done":
                o = e["outcome"]
                last = Outcome(cid, OutcomeClass[o["outcome_class"]], int(o["logs_grasped"]), int(o["balance_cos_milli"]))
        return decisions, last


# --- the controller -------------------------------------------------------------------------

Reply = Callable[[str, bytes], None]
_CAN = "can"  # the command channel of a bus without source addresses (one counter session)


@dataclass
class _Run:
    """One accepted command on its way through the executor."""

    cmd: GraspCommand
    peer: str | None  # the commanding laptop (None: none was live yet; adopted when one is)
    accepted_s: float  # monotonic time of the acceptance [s]
    abort: threading.Event = field(default_factory=threading.Event)
    acked: threading.Event = field(default_factory=threading.Event)
    reason: str | None = None  # why it was aborted
    worker: threading.Thread | None = None
    peer_seen: bool = False  # the commanding laptop was live at some point since the acceptance


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
        self._secoc = self._load_secoc()
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
        self._auth_warned_s: dict[str, float] = {}
        self._stop = threading.Event()
        self._supervisor: threading.Thread | None = None

    def _load_secoc(self) -> Any:
        if self.config.secoc_key_path is None:
            return None
        from field.link.secoc import SecOC

        return SecOC.from_key_file(self.config.secoc_key_path, window_s=self.config.secoc_window_s, clock=self._clock)

    def _open_journal(self) -> ControllerJournal | None:
        if self.config.journal_path is None:
            return None
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
            if run is not None and run.peer == peer and self.config.abort_on_laptop_loss:
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
        return plain

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
            reason = known if known is not None else self._decide(cmd, check is CounterCheck.WRONG_SEQUENCE)
            if known is None:
                self._burn(cmd.command_id, reason, digest)
            run = self._accept(cmd, peer) if known is None and reason is RejectReason.NONE else None
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

    def _decide(self, cmd: GraspCommand, out_of_sequence: bool) -> RejectReason:
        if cmd.command_id == 0:
            return RejectReason.MALFORMED
        if out_of_sequence:
            return RejectReason.COUNTER
        state = {ControllerState.ESTOP: RejectReason.ESTOP, ControllerState.FAULT: RejectReason.FAULT,
                 ControllerState.EXECUTING: RejectReason.BUSY}.get(self._state)
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

    def _accept(self, cmd: GraspCommand, peer: str | None) -> _Run:
        """EXECUTING, and the worker started - under the lock, so no e-stop falls in between."""
        run = _Run(cmd, peer, time.monotonic(), peer_seen=peer is not None and self._peers.is_live(peer))
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
        """``msg`` as frame bytes: E2E, then SecOC when a key is configured."""
        kind, data = self._encoder.encode(msg)
        return data if self._secoc is None else self._secoc.secure(kind, data)

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
            if run is None or run.reason is not None or not self.config.abort_on_laptop_loss:
                return
            why = self._peer_loss(run)
            if why is not None:
                self._abort_run(run, why)

    def _peer_loss(self, run: _Run) -> str | None:
        """Why ``run``'s commanding laptop counts as lost, or None (under the lock).

        A command accepted before its laptop counted as live (no laptop yet, or a Zenoh token
        not seen yet) adopts the first live one and gets one laptop timeout of grace."""
        if run.peer is None:
            run.peer = self._peers.primary()
        if run.peer is not None and self._peers.is_live(run.peer):
            run.peer_seen = True
            return None
        if run.peer_seen:
            return f"commanding laptop {run.peer} lost (no fresh heartbeat for {self.config.laptop_timeout_s:.2f} s)"
        late = time.monotonic() - run.accepted_s > self.config.laptop_timeout_s
        if late and self._peers.ever_seen:
            return "no live laptop since the command was accepted"
        return None


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
    before (e.g. to watch its ``rejections``). A ``secoc_key=PATH`` in the URL is the
    controller's key when ``config`` names none.
    """
    from field.link.base import LinkURL, open_controller_transport

    if isinstance(executor, str):
        executor = make_executor(executor)
    stop_event = stop_event or threading.Event()
    config = config or ControllerConfig()
    url_key = LinkURL.parse(link_url).pop_link_config()[0].secoc_key_path
    if url_key is not None and config.secoc_key_path is None:
        config = replace(config, secoc_key_path=url_key)
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


@contextlib.contextmanager
def controller_in_thread(link_url: str, executor: GraspExecutor | Callable[[GraspCommand], Outcome] | str = "fixed",
                         config: ControllerConfig | None = None,
                         start_timeout_s: float = 30.0) -> Iterator[None]:
    """:func:`run_controller` on a thread of this process for the ``with`` block (a twin crane beside
    the laptop: the demo, benchmarks, tests); :class:`LinkError` when it cannot serve (with the cause)
    or is not serving within ``start_timeout_s``."""
    from field.errors import LinkError

    stop, ready = threading.Event(), threading.Event()
    failure: list[BaseException] = []

    def serve() -> None:
        try:
            run_controller(link_url, executor, stop, config, ready_event=ready)
        except BaseException as exc:  # raised in the caller's thread below
            failure.append(exc)
            ready.set()

    thread = threading.Thread(target=serve, daemon=True, name="crane-controller")
    thread.start()
    try:
        if not ready.wait(start_timeout_s) or failure:
            if failure:
                raise LinkError(f"the crane controller twin could not serve {link_url}: {failure[0]}") from failure[0]
            raise LinkError(f"the crane controller twin did not start on {link_url} within {start_timeout_s:g} s")
        yield
    finally:
        stop.set()
        thread.join(10)


def default_journal_path(link_url: str) -> Path:
    """Where a controller serving ``link_url`` burns its command ids by default:
    ``$XDG_STATE_HOME/loggrasp/journal-<link>.jsonl`` (``~/.local/state`` without the variable)."""
    import re

    state = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state")
    slug = re.sub(r"[^A-Za-z0-9.-]+", "_", link_url.split("?", 1)[0]).strip("_")[:80]
    return state / "loggrasp" / f"journal-{slug}.jsonl"


def controller_config_from_dict(d: dict[str, Any]) -> ControllerConfig:
    """Build a :class:`ControllerConfig` from plain values (e.g. a JSON file; ``reach`` nested)."""
    from synth.common.configs import config_from_dict

    return config_from_dict(ControllerConfig, d, "controller config")


def controller_config_to_dict(c: ControllerConfig) -> dict[str, Any]:
    return asdict(c)
