"""The crane link seam: one base class, backends chosen by name (the python-can pattern).

:class:`CraneLink` is what the laptop talks to; :func:`open_link` picks a backend from a URL::

    can://virtual/<channel>?bitrate=500000&fd=1     python-can virtual bus (in-process)
    can://socketcan/can0                            any python-can interface / channel
    can://remote/127.0.0.1:PORT/<channel>           python-can-remote (``python -m can_remote``)
    can://                                          python-can's own config: can.rc, CAN_* env, ~/can.conf
    zenoh://<crane>?config=PATH                     Zenoh session from a JSON5 config file
    zenoh://127.0.0.1:7447/<crane>                  Zenoh, connect to that TCP endpoint
    twin://?delay_ms=50                             in-process controller twin behind a virtual bus

Backends are registered in :data:`BACKENDS` as ``"module:Class"`` and imported only when
chosen, so ``import field.link`` loads neither python-can nor zenoh. Link options common to all
backends may be given as URL query parameters: ``record=PATH`` (CAN: BLF recording),
``heartbeat_ms``, ``heartbeat_timeout_ms``, ``max_pile_age_s``, ``connect_timeout_s``,
``secoc_key=PATH`` (authenticated frames, :mod:`field.link.secoc`; the crane needs the same key)
and ``crane_key=PATH.pub`` (the crane's public key: its answers are signed, :mod:`field.link.signing`);
without them a link to a crane is refused unless ``insecure=1`` opts out explicitly.

Frames delivered by a backend go through :meth:`CraneLink._deliver`: SecOC check (with a key),
E2E check, rolling counter check, decode, then into an inbox that ``send_grasp`` /
``wait_outcome`` / ``status`` wait on. Answers are reconciled per command id: the controller
answers a copy of a frame with its original decision and a frame that failed its check with id
0 (counted for nobody), so the first answer naming a command is the decision about it; a later
contradicting answer, or an outcome for a rejected command, is recorded in ``notes`` and the
controller's own status settles what the operator is told (:meth:`CraneLink.execute`).
"""

from __future__ import annotations

import abc
import importlib
import logging
import secrets
import threading
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any, Callable

from field.errors import CommandRejected, LinkClosed, LinkError, LinkTimeout
from field.link.fate import (  # noqa: F401 - re-exported: their import path stays field.link.base
    REASON_HELP,
    CommandFate,
    _check_timeout,
    _runs_or_ran,
    describe_fate,
)
from field.link.link_config import LinkConfig, LinkURL
from field.link.messages import Ack, ControllerState, ControllerStatus, GraspCommand, Outcome
from field.link.receiving import Receiving
from field.link.reconcile import REVOKE_TARGET_LOGS, Reconciling  # noqa: F401 - re-exported
from field.link.resources import (  # noqa: F401 - re-exported
    close_leaked_resources,
    open_resources,
    track_resource,
    untrack_resource,
)
from field.link.safety import CommandGuard

log = logging.getLogger(__name__)

#: link backends, name -> "module:Class" (imported only when chosen)
BACKENDS: dict[str, str] = {
    "can": "field.link.can_backend:CanLink",
    "zenoh": "field.link.zenoh_backend:ZenohLink",
    "twin": "field.link.twin_backend:TwinLink",
}
#: controller-side transports, name -> "module:Class"
CONTROLLER_TRANSPORTS: dict[str, str] = {
    "can": "field.link.can_backend:CanControllerTransport",
    "zenoh": "field.link.zenoh_backend:ZenohControllerTransport",
}


def load_entry(registry: dict[str, str], name: str, what: str) -> Any:
    """Import ``registry[name]`` ("module:Class") and return the object."""
    if name not in registry:
        raise LinkError(f"unknown {what} {name!r}; choose one of {sorted(registry)}")
    module_name, _, attr = registry[name].partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise LinkError(f"{what} {name!r} needs a library that is not installed ({exc}); install it") from exc
    return getattr(module, attr)


# --- the link --------------------------------------------------------------------------------


@dataclass
class LinkStats:
    """Counters of what the link saw (diagnostics, and what fault tests assert on)."""

    frames_sent: int = 0
    frames_received: int = 0
    crc_errors: int = 0
    malformed: int = 0
    duplicates_dropped: int = 0  # repeated rolling counter
    sequence_errors: int = 0  # counter jumped (lost / reordered frames)
    bus_errors: int = 0
    auth_failures: int = 0  # frames dropped by the SecOC check (MAC, signature, freshness, length)
    unattributed_answers: int = 0  # controller answers with id 0 (to a frame that failed its check)
    stale_heartbeats: int = 0  # crane heartbeats whose counter did not advance (frozen sender)
    conflicts: int = 0  # answers that contradicted an earlier one (reconciled; see CraneLink.notes)
    foreign_answers: int = 0  # acks / outcomes naming a command id this link never sent (dropped)
    unsigned_dropped: int = 0  # CAN: crane frames whose signature frame never came in time (lost)
    orphan_signatures: int = 0  # CAN: signature frames with no frame of their kind waiting (late / lost)



class CraneLink(Receiving, Reconciling, abc.ABC):
    """Laptop side of the crane link. Use as a context manager; ``close()`` is safe twice.

    Backends implement :meth:`_transmit` (send one protected frame) and :meth:`_close_transport`,
    and feed every crane -> laptop frame to :meth:`_deliver`.
    """

    backend_name = "abstract"
    #: re-synchronise the rolling counters after heartbeat-timeout silence (heartbeat-driven
    #: backends); backends with a presence signal call :meth:`_mark_alive` / :meth:`_mark_lost`
    _resync_on_silence = True
    #: crane heartbeat counter advance accepted between two heartbeats (lost frames) [-]
    _max_heartbeat_gap = 64
    #: a link to a crane needs a SecOC key unless the operator opts out (``insecure``); only a
    #: twin on a private in-process bus may run without one
    _requires_key = True
    #: the crane's signature travels in the frame's own payload (Zenoh), not in a frame of its own (CAN)
    _inline_signatures = False

    def __init__(self, config: LinkConfig | None = None, *, clock: Callable[[], float] = time.time):
        from field.link.codec import CounterMonitor, Encoder

        self.config = config or LinkConfig()
        self.guard = CommandGuard(self.config.safety, clock)
        self.stats = LinkStats()
        from field.link.signing import load_answer_check

        self._answer_check = load_answer_check(self.config, clock, self.backend_name, self._requires_key,
                                               inline=self._inline_signatures)
        self._secoc = self._answer_check.secoc
        self._issued: set[int] = set()  # command ids this link sent: answers to others are foreign
        self._encoder = Encoder(first_counter=secrets.randbits(8))
        self._counters = CounterMonitor(max_delta=8)  # laptop side: drop duplicates, count jumps
        self._cond = threading.Condition()
        self._answers: dict[int, list[Ack]] = {}  # every Ack per command id, in arrival order
        self._outcomes: dict[int, Outcome] = {}
        self._told: dict[int, str] = {}  # what send_grasp / execute told the operator per id
        self.notes: dict[int, list[str]] = {}  # reconciled conflicts per command id
        self._status_replies: dict[int, ControllerStatus] = {}
        self._pending_status: set[int] = set()
        self._latest_status: ControllerStatus | None = None
        self._last_heartbeat_mono: float | None = None
        self._crane_heartbeat: int | None = None
        self._last_rx_mono: float | None = None
        self._last_crane_state: ControllerState | None = None
        self._request_id = secrets.randbits(31) + 1
        self._failure: BaseException | None = None
        self.last_estop_error: BaseException | None = None  # the last error sending an e-stop frame
        self._closed = False
        self._close_lock = threading.Lock()

    # ---- public API ----------------------------------------------------------------------

    def new_command_id(self) -> int:
        """A fresh command id never used on this link."""
        return self.guard.new_command_id()

    @property
    def laptops_heard(self) -> int:
        """How many laptops the controller last said it hears (more than 1: a second laptop)."""
        st = self._latest_status
        return 0 if st is None else st.laptops

    def send_grasp(self, cmd: GraspCommand, timeout_s: float = 1.0) -> Ack:
        """Send one grasp command and wait for the controller's decision about it.

        Returns the accepting :class:`Ack`. Raises :class:`CommandRejected` (reason code; local
        checks: duplicate id, stale pile data), :class:`ProtocolError` (a value out of wire
        range; nothing sent), :class:`LinkTimeout` (no decision within ``timeout_s``; ``.status``
        is the controller status learned afterwards, ``None`` if unreachable). Never re-sends.
        The first answer naming the command is the decision (answers to corrupted frames name
        no command); an Outcome for it overrides a rejection (the controller ran it).
        :meth:`execute` follows the command to its end.
        """
        if not isinstance(cmd, GraspCommand):
            raise ValueError(f"send_grasp takes a GraspCommand, got {type(cmd).__name__}")
        _check_timeout(timeout_s)
        self._check_usable()
        self.guard.reserve(cmd)  # burns the id: never sent twice
        kind, data = self._wire(cmd)
        self._check_controller_reachable(cmd.command_id)
        with self._cond:
            self._issued.add(cmd.command_id)
        self._send(kind, data)
        ack = self._await_decision(cmd.command_id, timeout_s)
        if ack is None:
            self._tell(cmd.command_id, "no answer")
            status = self._status_or_none()
            raise LinkTimeout(
                f"no acknowledgement for command {cmd.command_id} within {timeout_s:.3f} s; "
                f"{describe_fate(cmd.command_id, status)}. It will not be re-sent.",
                command_id=cmd.command_id,
                status=status,
            )
        self._tell(cmd.command_id, "accepted" if ack.accepted else "rejected")
        if not ack.accepted:
            raise CommandRejected(
                f"controller rejected command {cmd.command_id}: {ack.reason.name} "
                f"({REASON_HELP.get(ack.reason, '')}){self._second_laptop_hint()}",
                reason=ack.reason,
                command_id=cmd.command_id,
            )
        return ack

    def execute(self, cmd: GraspCommand, ack_timeout_s: float = 1.0, outcome_timeout_s: float = 30.0) -> CommandFate:
        """Send ``cmd`` and follow it to the controller's final state — what the operator is told.

        Never raises for what the controller did (a rejection, a lost acknowledgement, a lost
        outcome): the :class:`CommandFate` says it, settled by a status query whenever two answers
        disagree. Raises :class:`ProtocolError` (nothing sent) and :class:`LinkError` when the
        link itself fails.
        """
        cid = cmd.command_id
        try:
            self.send_grasp(cmd, ack_timeout_s)
        except CommandRejected as exc:
            if exc.local:
                return CommandFate(cid, False, reason=exc.reason, local=True, summary=str(exc))
            return self._confirm_rejection(cid, exc)
        except LinkTimeout as exc:
            if exc.status is None:
                sent = self._told.get(cid) != "not sent"
                return CommandFate(cid, None if sent else False, local=not sent, summary=str(exc), notes=self._notes(cid))
            if not _runs_or_ran(cid, exc.status):
                return self._settle_unanswered(cmd, outcome_timeout_s)
            self._note(cid, "its acknowledgement was lost; the controller reports it running")
        return self._follow(cid, outcome_timeout_s)

    def fate(self, command_id: int, *, query: bool = True) -> CommandFate:
        """What is known now about ``command_id`` (late answers included); ``query`` asks the
        controller's status too."""
        with self._cond:
            out = self._outcomes.get(command_id)
            ack = self._decision(command_id)
        status = self._status_or_none() if query else self._latest_status
        if out is None and status is not None and status.last_outcome is not None \
                and status.last_outcome.command_id == command_id:
            out = status.last_outcome
        notes = self._notes(command_id)
        if out is not None:
            return CommandFate(command_id, True, out, summary=f"finished: {out.outcome_class.name}", notes=notes)
        if (ack is not None and ack.accepted) or (status is not None and status.current_command_id == command_id):
            return CommandFate(command_id, True, summary="accepted, outcome not known yet", notes=notes)
        if ack is not None:
            return CommandFate(command_id, False, reason=ack.reason, summary=f"rejected: {ack.reason.name}", notes=notes)
        if status is None:
            return CommandFate(command_id, None, summary="no answer and no status: UNKNOWN", notes=notes)
        return CommandFate(command_id, False, summary=describe_fate(command_id, status), notes=notes)

    def wait_outcome(self, command_id: int, timeout_s: float = 30.0) -> Outcome:
        """Wait for the outcome of an accepted command.

        If the outcome frame is lost, the outcome is recovered from a status query (the status
        carries the last finished command). Raises :class:`LinkTimeout` (``.status`` attached)
        when neither arrives within ``timeout_s`` or the controller vanished.
        """
        _check_timeout(timeout_s)
        self._check_usable()
        deadline = time.monotonic() + timeout_s
        next_probe = time.monotonic() + max(self.config.heartbeat_timeout_s, 0.2)
        while True:
            out = self._wait_for_outcome(command_id, deadline)
            if out is not None:
                return out
            if time.monotonic() >= deadline:
                break
            now = time.monotonic()
            if now >= next_probe and not self.controller_alive():
                next_probe = now + max(self.config.heartbeat_timeout_s, 0.2)
                out = self._probe_vanished(command_id)
                if out is not None:
                    return out
        status = self._status_or_none()
        if status is not None and status.last_outcome is not None and status.last_outcome.command_id == command_id:
            return status.last_outcome
        raise LinkTimeout(
            f"no outcome for command {command_id} within {timeout_s:.3f} s; "
            f"{describe_fate(command_id, status)}",
            command_id=command_id,
            status=status,
        )

    def status(self, timeout_s: float | None = None) -> ControllerStatus:
        """Query the controller's status. Raises :class:`LinkTimeout` when it does not answer."""
        from field.link.codec import StatusRequest

        timeout_s = self.config.status_timeout_s if timeout_s is None else timeout_s
        _check_timeout(timeout_s)
        self._check_usable()
        with self._cond:
            self._request_id = (self._request_id % 0xFFFFFFFF) + 1
            rid = self._request_id
            self._pending_status.add(rid)
        try:
            self._send(*self._wire(StatusRequest(rid)))
            return self._await_status(rid, timeout_s)
        finally:
            with self._cond:
                self._pending_status.discard(rid)

    def abort(self, timeout_s: float = 1.0) -> ControllerStatus:
        """Emergency stop: send the e-stop frame and confirm the controller is in ESTOP.

        Re-sends the e-stop until confirmed (e-stops are idempotent). Raises
        :class:`LinkTimeout` when not confirmed within ``timeout_s`` — then USE THE PHYSICAL
        E-STOP; it names the last error sending the e-stop frame (chained as its cause, kept in
        :attr:`last_estop_error`, logged at its first occurrence). Works on a link that has
        failed, but not after ``close()``.
        """
        from field.link.codec import EStopRequest

        if self._closed:
            raise LinkClosed("link is closed; use the physical e-stop or open a new link")
        deadline = time.monotonic() + timeout_s
        last: ControllerStatus | None = None
        sent = failed = 0
        while True:
            if self._send_estop(EStopRequest(source=1)):
                sent += 1
            else:
                failed += 1
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                last = self.status(timeout_s=min(self.config.status_timeout_s, max(left, 0.01)))
            except LinkError:
                last = None
            if last is not None and last.state is ControllerState.ESTOP:
                return last
            if time.monotonic() >= deadline:
                break
        error = self.last_estop_error if failed else None
        why = (f"; the e-stop frame failed to send {failed} of {sent + failed} times, last error: "
               f"{type(error).__name__}: {error}" if error is not None else f"; e-stop frame sent {sent} times")
        raise LinkTimeout(
            f"e-stop NOT confirmed within {timeout_s:.2f} s (last status: {last}){why}; USE THE PHYSICAL "
            f"E-STOP on the crane",
            status=last,
        ) from error

    def _send_estop(self, msg: Any) -> bool:
        """One e-stop frame; False when it failed (the error kept in :attr:`last_estop_error`)."""
        try:
            self._transmit(*self._wire(msg))
        except Exception as exc:
            self.stats.bus_errors += 1
            previous, self.last_estop_error = self.last_estop_error, exc
            if previous is None or (type(previous), str(previous)) != (type(exc), str(exc)):
                log.error("could not send the e-stop frame on the %s link: %s: %s (retrying until the "
                          "deadline)", self.backend_name, type(exc).__name__, exc)
            return False
        self.stats.frames_sent += 1
        return True

    def controller_alive(self) -> bool:
        """True while the controller's heartbeat is fresh (advancing, in sequence)."""
        t = self._last_heartbeat_mono
        return t is not None and time.monotonic() - t < self.config.heartbeat_timeout_s

    def wait_for_controller(self, timeout_s: float) -> bool:
        """Wait until the controller shows a sign of life AND answers a status query (its
        request paths are routed) that says it hears a live laptop (it accepts commands only from
        one: this laptop's heartbeat or token reached it); returns whether it did within
        ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self.controller_alive():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.05))
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            try:
                if self.status(timeout_s=min(self.config.status_timeout_s, left)).laptops >= 1:
                    return True
            except LinkTimeout:
                continue
            time.sleep(min(self.config.heartbeat_period_s, max(left, 0.0)))

    def _await_controller(self) -> None:
        """Open-time handshake: raise :class:`LinkError` (and close) when no controller answers."""
        try:
            found = not self.config.require_controller or self.wait_for_controller(self.config.connect_timeout_s)
        except LinkError:  # the link failed while opening (a bus error, too many frames failing their check)
            self.close()
            raise
        if not found:
            self.close()
            hint = self._auth_hint()
            heard = self._latest_status is not None and self.controller_alive()
            raise LinkError(
                f"the crane controller answered but hears no live laptop heartbeat from this laptop within "
                f"{self.config.connect_timeout_s:.1f} s (it refuses unsupervised commands); check that this "
                f"laptop's frames reach the crane{hint}" if heard else
                f"no crane controller answered on the {self.backend_name} link within "
                f"{self.config.connect_timeout_s:.1f} s; check that it runs, the URL / endpoint and "
                f"the credentials{hint}"
            )

    @property
    def authenticated(self) -> bool:
        """Whether frames carry SecOC MACs (False only with the explicit ``insecure`` opt-out or a twin)."""
        return self._secoc is not None

    @property
    def answers_signed(self) -> bool:
        """Whether the crane's answers must carry its signature (the laptop holds its public key)."""
        return self._answer_check.verifier is not None

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Stop heartbeats, close the bus / session. Safe to call twice."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        try:
            self._close_transport()
        finally:
            with self._cond:
                self._cond.notify_all()

    def __enter__(self) -> "CraneLink":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {'closed' if self._closed else 'open'}>"

    # ---- backend hooks -------------------------------------------------------------------

    @abc.abstractmethod
    def _transmit(self, kind: str, data: bytes) -> None:
        """Send one protected laptop -> crane frame; raise on transport errors."""

    @abc.abstractmethod
    def _close_transport(self) -> None:
        """Release the bus / session (called once)."""

    # ---- helpers -------------------------------------------------------------------------

    def _wire(self, msg: Any) -> tuple[str, bytes]:
        """``(kind, frame bytes)`` of ``msg``: E2E, then SecOC when a key is configured."""
        kind, data = self._encoder.encode(msg)
        return kind, data if self._secoc is None else self._secoc.secure(kind, data)

    def _check_controller_reachable(self, command_id: int) -> None:
        if not self.controller_alive() and self._status_or_none() is None:
            self._tell(command_id, "not sent")
            raise LinkTimeout(
                f"command {command_id} NOT sent: no sign of life from the controller for "
                f"{self.config.heartbeat_timeout_s:.2f} s and no status answer; check the crane "
                f"and the link, then send a new command",
                command_id=command_id,
                status=None,
            )

    def _wait_for_outcome(self, command_id: int, deadline: float) -> Outcome | None:
        """The outcome, from its frame or the latest status, waiting until ``deadline`` at most
        one poll period."""
        with self._cond:
            self._raise_if_failed()
            out = self._outcomes.get(command_id)
            st = self._latest_status
            if out is None and st is not None and st.last_outcome is not None and st.last_outcome.command_id == command_id:
                out = st.last_outcome
            if out is None and (left := deadline - time.monotonic()) > 0:
                self._cond.wait(min(left, 0.05))
            return out

    def _probe_vanished(self, command_id: int) -> Outcome | None:
        """The controller went quiet while ``command_id`` ran: ask it directly before giving up."""
        status = self._status_or_none()
        if status is None:
            raise LinkTimeout(
                f"controller vanished while command {command_id} was running (no heartbeat "
                f"for {self.config.heartbeat_timeout_s:.2f} s, no status answer); its final "
                f"state is UNKNOWN - check the crane on site",
                command_id=command_id,
                status=None,
            )
        if status.last_outcome is not None and status.last_outcome.command_id == command_id:
            return status.last_outcome
        if status.current_command_id != command_id:
            raise LinkTimeout(
                f"controller restarted or moved on: it is not running command {command_id} "
                f"and reports no outcome for it; {describe_fate(command_id, status)}",
                command_id=command_id,
                status=status,
            )
        return None

    def _await_status(self, rid: int, timeout_s: float) -> ControllerStatus:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while rid not in self._status_replies:
                self._raise_if_failed()
                left = deadline - time.monotonic()
                if left <= 0:
                    raise LinkTimeout(
                        f"controller did not answer a status query within {timeout_s:.3f} s; it is "
                        f"unreachable - check the crane and the link",
                        status=None,
                    )
                self._cond.wait(min(left, 0.05))
            return self._status_replies.pop(rid)

    def _send(self, kind: str, data: bytes) -> None:
        try:
            self._transmit(kind, data)
        except LinkError:
            raise
        except Exception as exc:
            self.stats.bus_errors += 1
            raise LinkError(
                f"could not send {kind} on the {self.backend_name} link: {exc}; check the bus / "
                f"session and the crane's connection"
            ) from exc
        self.stats.frames_sent += 1

    def _status_or_none(self, attempts: int = 3) -> ControllerStatus | None:
        """The controller's status, asked up to ``attempts`` times (one lost frame is no reason
        to call its state UNKNOWN); None when it never answers."""
        for _ in range(attempts):
            try:
                return self.status()
            except LinkTimeout:
                continue
            except LinkError:
                return None
        return None

    def _check_usable(self) -> None:
        if self._closed:
            raise LinkClosed(f"the {self.backend_name} link is closed; open a new one with open_link()")
        self._raise_if_failed()

    def _raise_if_failed(self) -> None:
        if self._failure is not None:
            raise LinkError(
                f"the {self.backend_name} link failed: {self._failure}; close it and open a new one"
            ) from self._failure

    @staticmethod
    def _prune(d: dict, keep: int = 4096) -> None:
        while len(d) > keep:
            d.pop(next(iter(d)))


def open_link(url_or_config: "str | LinkURL | Mapping[str, Any]", config: LinkConfig | None = None, **backend_kwargs: Any) -> CraneLink:
    """Open a crane link chosen by URL (see the module docstring for the forms).

    ``url_or_config`` is a URL, or a mapping (e.g. read from a JSON file) with ``"url"`` plus
    :class:`LinkConfig` fields (``"safety"`` as a nested mapping). ``config`` gives the common
    options (URL query parameters override them); ``backend_kwargs`` go to the backend (e.g.
    ``bus=`` an already open python-can bus). Raises :class:`LinkError` when the backend cannot
    open or (``config.require_controller``) no controller answers within ``connect_timeout_s``.
    """
    if isinstance(url_or_config, Mapping):
        d = dict(url_or_config)
        if "url" not in d:
            raise ValueError(f"a link config mapping needs a 'url' key, got keys {sorted(d)}")
        url_or_config = d.pop("url")
        from synth.common.configs import config_from_dict

        base = asdict(config or LinkConfig())  # the given options, overridden by the mapping's
        config = config_from_dict(LinkConfig, {**base, **d, "safety": {**base["safety"], **d.get("safety", {})}},
                                  "link config")
    url = url_or_config if isinstance(url_or_config, LinkURL) else LinkURL.parse(url_or_config)
    cls = load_entry(BACKENDS, url.scheme, "link backend")
    return cls.from_url(url, config, **backend_kwargs)


def open_controller_transport(url_or_config: str | LinkURL, **kwargs: Any) -> Any:
    """The crane-side transport for a link URL (used by :func:`field.controller.run_controller`)."""
    url = url_or_config if isinstance(url_or_config, LinkURL) else LinkURL.parse(url_or_config)
    cls = load_entry(CONTROLLER_TRANSPORTS, url.scheme, "controller transport")
    return cls.from_url(url, **kwargs)
