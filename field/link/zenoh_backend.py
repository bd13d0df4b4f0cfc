"""Zenoh backend of the crane link (eclipse-zenoh 1.x), laptop side and crane side.

Key expressions, under a configurable prefix (default ``loggrasp/<crane>``)::

    <prefix>/grasp/cmd       queryable on the crane: get(payload=GraspCommand frame) -> reply Ack frame
    <prefix>/grasp/ack       the crane also puts every Ack here (monitoring / recording)
    <prefix>/grasp/status    queryable on the crane: get(payload=StatusRequest) -> reply Status;
                             the crane also puts unsolicited Status frames here (laptop subscribes)
    <prefix>/grasp/outcome   crane puts Outcome frames (laptop subscribes)
    <prefix>/grasp/estop     laptop puts EStop frames (REAL_TIME priority, express, blocking)
    <prefix>/grasp/heartbeat crane puts CraneHeartbeat frames each period (monitoring)
    <prefix>/alive/controller, <prefix>/alive/laptop/<zid>   liveliness tokens

Request/acknowledge uses a **queryable** (``session.get``): the reply goes to the requester
only, the query has its own timeout, and an unreachable or unauthorised crane simply produces no
reply (-> ``LinkTimeout``). Payloads are exactly the CAN FD frame bytes (same DBC codec, same
AUTOSAR E2E protection; a signed crane answer is its frame followed by the crane's 64-byte
Ed25519 signature, :mod:`field.link.signing`). Presence uses liveliness tokens: a killed peer's token disappears at
once, a hung one after the transport lease (``lease_ms``, default 1000 ms via
``transport/link/tx/lease``).

URLs: ``zenoh://127.0.0.1:7447/crane1`` (the laptop connects to, the controller listens on
``tcp/127.0.0.1:7447``) and/or ``zenoh://crane1?config=PATH`` (a JSON5 Zenoh config file used
as given: user/password auth in ``transport/auth/usrpwd``, ``access_control`` rules...). When the
URL names an endpoint, multicast scouting and gossip are switched off and only that endpoint is
used. Parameters: ``prefix``, ``lease_ms``, ``config`` (+ the common link options; ``record=x.blf``
writes every payload as the CAN FD frame it is, so CAN and Zenoh sessions read back alike),
``ros2=on|off`` and ``ros_domain_id=N`` (default ``ROS_DOMAIN_ID``, else 0): the laptop also
publishes the plan and the sent grasp as ROS 2 messages on rmw_zenoh key expressions
(:mod:`field.ros2`, topics under ``/<prefix>``), so a ROS 2 crane stack subscribes without a bridge.
"""

from __future__ import annotations

import json
import logging
import re
import threading
from dataclasses import dataclass
from typing import Any

from field.errors import LinkError
from field.link.base import CraneLink, LinkConfig, LinkURL, track_resource, untrack_resource

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class ZenohKeys:
    prefix: str

    @property
    def cmd(self) -> str:
        return f"{self.prefix}/grasp/cmd"

    @property
    def ack(self) -> str:
        return f"{self.prefix}/grasp/ack"

    @property
    def status(self) -> str:
        return f"{self.prefix}/grasp/status"

    @property
    def outcome(self) -> str:
        return f"{self.prefix}/grasp/outcome"

    @property
    def estop(self) -> str:
        return f"{self.prefix}/grasp/estop"

    @property
    def heartbeat(self) -> str:
        return f"{self.prefix}/grasp/heartbeat"

    @property
    def alive_controller(self) -> str:
        return f"{self.prefix}/alive/controller"

    @property
    def alive_laptop(self) -> str:
        return f"{self.prefix}/alive/laptop"


@dataclass(frozen=True)
class ZenohTarget:
    """What a ``zenoh://`` URL says: crane name, endpoint, config file, prefix, lease."""

    crane: str
    endpoint: str | None  # "tcp/127.0.0.1:7447" or None (config file decides)
    config_path: str | None
    prefix: str
    lease_ms: int
    ros2: bool = True  # publish the plan and the sent grasp as ROS 2 messages (field.ros2)
    ros_domain_id: int = 0  # ROS 2 domain of those messages [-]

    @classmethod
    def from_url(cls, url: LinkURL, query: dict[str, str]) -> "ZenohTarget":
        q = dict(query)
        endpoint = None
        if ":" in url.netloc or url.path:
            host = url.netloc
            if ":" not in host:
                raise ValueError(f"zenoh URL endpoint needs HOST:PORT, got {host!r} (e.g. zenoh://127.0.0.1:7447/crane1)")
            endpoint = f"tcp/{host}"
            crane = url.path.strip("/")
        else:
            crane = url.netloc
        if not crane or "/" in crane or "*" in crane:
            raise ValueError(f"zenoh URL needs a crane name without '/' or '*', got {crane!r}")
        prefix = q.pop("prefix", f"loggrasp/{crane}").strip("/")
        try:
            lease_ms = int(q.pop("lease_ms", "1000"))
        except ValueError as exc:
            raise ValueError(f"lease_ms must be an integer [ms]: {exc}") from exc
        config_path = q.pop("config", None)
        ros2 = q.pop("ros2", "on")
        if ros2 not in ("on", "off"):
            raise ValueError(f"ros2 must be on or off, got {ros2!r}")
        from field.ros2 import domain_id_from_env

        domain = q.pop("ros_domain_id", None)
        if domain is not None and (not domain.isdigit() or int(domain) > 232):
            raise ValueError(f"ros_domain_id must be a whole number 0-232, got {domain!r}")
        domain_id = domain_id_from_env() if domain is None else int(domain)
        if q:
            raise ValueError(f"unknown zenoh:// parameters {sorted(q)}")
        if endpoint is None and config_path is None:
            raise ValueError("a zenoh:// URL needs an endpoint (zenoh://HOST:PORT/crane) or ?config=PATH")
        return cls(crane, endpoint, config_path, prefix, lease_ms, ros2 == "on", domain_id)

    def zenoh_config(self, role: str) -> Any:
        """A ``zenoh.Config`` for ``role`` ``"laptop"`` (client, connects) or ``"controller"``
        (peer, listens)."""
        import zenoh

        try:
            conf = zenoh.Config.from_file(self.config_path) if self.config_path else zenoh.Config()
        except Exception as exc:
            raise LinkError(f"cannot read Zenoh config {self.config_path}: {exc}") from exc
        if self.endpoint is not None:
            if role == "laptop":
                conf.insert_json5("mode", '"client"')
                conf.insert_json5("connect/endpoints", json.dumps([self.endpoint]))
                conf.insert_json5("listen/endpoints", "[]")
            else:
                conf.insert_json5("mode", '"peer"')
                conf.insert_json5("listen/endpoints", json.dumps([self.endpoint]))
                conf.insert_json5("connect/endpoints", "[]")
            conf.insert_json5("scouting/multicast/enabled", "false")
            conf.insert_json5("scouting/gossip/enabled", "false")
        conf.insert_json5("transport/link/tx/lease", str(self.lease_ms))
        return conf


def _open_session(conf: Any, what: str) -> Any:
    import zenoh

    try:
        session = zenoh.open(conf)
    except Exception as exc:
        raise LinkError(
            f"cannot open the Zenoh session for the {what}: {exc}. Check that the controller runs, "
            f"the endpoint, and the credentials in the config file"
        ) from exc
    track_resource(session, f"zenoh session ({what})", session.close)
    return session


def _close_session(session: Any) -> None:
    try:
        session.close()
    except Exception:
        pass  # close after a hang can time out; the session is gone either way
    finally:
        untrack_resource(session)


def _sender(query: Any) -> str | None:
    """The commanding laptop a query names in its attachment (its session id), or None."""
    att = query.attachment
    zid = att.to_bytes().decode("ascii", errors="replace") if att is not None else ""
    return f"zenoh:{zid}" if re.fullmatch(r"[0-9a-f]{1,64}", zid) else None


def _payload(sample_or_query: Any) -> bytes:
    p = sample_or_query.payload
    return b"" if p is None else p.to_bytes()


# --- laptop side ----------------------------------------------------------------------------


class ZenohLink(CraneLink):
    backend_name = "zenoh"
    _resync_on_silence = False  # liveliness tells when the controller (re)appears
    _inline_signatures = True  # a crane answer's payload is its frame followed by the crane's signature
    query_timeout_s = 10.0  # zenoh-level query lifetime; the link's own deadlines are shorter

    def __init__(self, target: ZenohTarget, config: LinkConfig | None = None):
        super().__init__(config)
        import zenoh

        self.target = target
        self.keys = ZenohKeys(target.prefix)
        self._present = False
        self._zenoh = zenoh
        self._ros2: Any = None
        self._recorder = None
        if self.config.record_path:  # the same python-can writers as the CAN backend
            from field.link.can_backend import LockedWriter

            self._recorder = LockedWriter(self.config.record_path)
        self._session = _open_session(target.zenoh_config("laptop"), "laptop")
        try:
            s = self._session
            self._subs = [
                s.declare_subscriber(self.keys.outcome, lambda smp: self._deliver("Outcome", _payload(smp))),
                s.declare_subscriber(self.keys.status, lambda smp: self._deliver("Status", _payload(smp))),
                s.liveliness().declare_subscriber(self.keys.alive_controller, self._on_alive, history=True),
            ]
            # one token per laptop session, so one laptop leaving does not hide another
            self._token = s.liveliness().declare_token(f"{self.keys.alive_laptop}/{s.zid()}")
        except BaseException:
            _close_session(self._session)
            raise

    @classmethod
    def from_url(cls, url: LinkURL, config: LinkConfig | None = None) -> "ZenohLink":
        cfg, q = url.pop_link_config(config)
        link = cls(ZenohTarget.from_url(url, q), cfg)
        link._await_controller()
        return link

    def _on_alive(self, sample: Any) -> None:
        if sample.kind == self._zenoh.SampleKind.PUT:
            self._present = True
            self._mark_alive()
        else:
            self._present = False
            self._mark_lost()

    def controller_alive(self) -> bool:
        return self._present

    def ros2_publisher(self) -> Any:
        """The :class:`field.ros2.Ros2Publisher` on this link's session (made on first use, closed
        with the link), or None when the URL says ``ros2=off``."""
        if not self.target.ros2:
            return None
        if self._ros2 is None:
            from field.ros2 import Ros2Publisher

            self._ros2 = Ros2Publisher(self._session, self.target.prefix, self.target.ros_domain_id)
        return self._ros2

    def _reply_to(self, kind: str) -> Any:
        def on_reply(reply: Any) -> None:
            ok = reply.ok
            if ok is not None:
                self._deliver(kind, _payload(ok))

        return on_reply

    def _record(self, kind: str, data: bytes, is_rx: bool) -> None:
        if self._recorder is not None:
            import time as _time

            import can

            from field.link.codec import frame_id
            from field.link.signing import carriage_frames

            for k, frame in carriage_frames(kind, data):  # a signed answer: as its two CAN FD frames
                self._recorder.on_message_received(can.Message(
                    timestamp=_time.time(), arbitration_id=frame_id(k), is_extended_id=False, is_fd=True,
                    data=frame, is_rx=is_rx, check=False))

    def _deliver(self, kind: str, data: bytes) -> None:
        self._record(kind, data, True)
        super()._deliver(kind, data)

    def _transmit(self, kind: str, data: bytes) -> None:
        z = self._zenoh
        self._record(kind, data, False)
        if kind == "GraspCommand":  # the attachment names this laptop: the controller's commanding peer
            # every reply, unconsolidated: another queryable on the key (a misconfigured ACL) cannot hide the
            # crane's own answer behind one of its own - the laptop checks each (signature) and keeps the crane's
            self._session.get(self.keys.cmd, self._reply_to("Ack"), payload=data, timeout=self.query_timeout_s,
                              priority=z.Priority.INTERACTIVE_HIGH, congestion_control=z.CongestionControl.BLOCK,
                              attachment=str(self._session.zid()).encode(), consolidation=z.ConsolidationMode.NONE)
        elif kind == "StatusRequest":
            self._session.get(self.keys.status, self._reply_to("Status"), payload=data, timeout=self.query_timeout_s,
                              consolidation=z.ConsolidationMode.NONE)
        elif kind == "EStop":
            self._session.put(self.keys.estop, data, priority=z.Priority.REAL_TIME,
                              congestion_control=z.CongestionControl.BLOCK, express=True)
        else:
            raise LinkError(f"the zenoh link does not send {kind} frames")

    def _close_transport(self) -> None:
        if self._ros2 is not None:
            self._ros2.close()
        try:
            self._token.undeclare()
        except Exception:
            pass
        _close_session(self._session)
        if self._recorder is not None:
            self._recorder.stop()


# --- crane side -----------------------------------------------------------------------------


class ZenohControllerTransport:
    """Crane side over Zenoh: queryables for commands and status, liveliness, publications."""

    recheck_timeout_s = 1.0  # how long a laptop token's re-check waits for the network's answer [s]

    def __init__(self, target: ZenohTarget, heartbeat_period_s: float = 0.05):
        self.target = target
        self.keys = ZenohKeys(target.prefix)
        self.heartbeat_period_s = heartbeat_period_s
        self.heartbeat_failures = 0  # heartbeat puts that failed (each logged as a run) [-]
        self.controller: Any = None
        self._session: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._laptop_lock = threading.Lock()
        self._laptop_events: dict[str, int] = {}  # token events seen per laptop peer [-]

    @classmethod
    def from_url(cls, url: LinkURL, *, heartbeat_period_s: float = 0.05) -> "ZenohControllerTransport":
        _, q = url.pop_link_config()
        return cls(ZenohTarget.from_url(url, q), heartbeat_period_s)

    def start(self, controller: Any) -> None:
        import zenoh

        self._zenoh = zenoh
        self.controller = controller
        controller.attach(self.send)
        self._session = _open_session(self.target.zenoh_config("controller"), "controller")
        s = self._session
        try:
            self._entities = [
                s.declare_queryable(self.keys.cmd, self._on_command),
                s.declare_queryable(self.keys.status, self._on_status_query),
                s.declare_subscriber(self.keys.estop, lambda smp: controller.on_frame("EStop", _payload(smp), self.send)),
                s.liveliness().declare_subscriber(f"{self.keys.alive_laptop}/**", self._on_laptop, history=True),
            ]
            self._token = s.liveliness().declare_token(self.keys.alive_controller)
        except BaseException:
            _close_session(s)
            raise
        self._thread = threading.Thread(target=self._heartbeat_loop, name="zenoh-controller-heartbeat", daemon=True)
        self._thread.start()

    def _on_command(self, query: Any) -> None:
        def reply(kind: str, data: bytes) -> None:
            if kind == "Ack":
                query.reply(query.key_expr, data)
            self.send(kind, data)

        self.controller.on_frame("GraspCommand", _payload(query), reply, peer=_sender(query))

    def _on_status_query(self, query: Any) -> None:
        self.controller.on_frame("StatusRequest", _payload(query), lambda kind, data: query.reply(query.key_expr, data))

    def _on_laptop(self, sample: Any) -> None:
        """A laptop's liveliness token came or went: ``alive/laptop/<zid>`` is peer ``zenoh:<zid>``. A
        token gone aborts that laptop's grasp at once, then :meth:`_recheck_laptop` asks whether it is
        really gone."""
        key = str(sample.key_expr)
        peer = f"zenoh:{key.rsplit('/', 1)[-1]}"
        with self._laptop_lock:
            event = self._laptop_events[peer] = self._laptop_events.get(peer, 0) + 1
            if sample.kind == self._zenoh.SampleKind.PUT:
                self.controller.peer_present(peer)
                return
            self.controller.peer_gone(peer)
        threading.Thread(target=self._recheck_laptop, args=(key, peer, event), daemon=True,
                         name="zenoh-laptop-recheck").start()

    def _recheck_laptop(self, key: str, peer: str, event: int) -> None:
        """After laptop ``peer``'s token was undeclared: if the network still holds it (a resumed
        transport's undeclaration delivered after the same token's re-declaration), the laptop is
        present again, so that a live laptop is not refused as unsupervised until it reconnects. Its
        aborted grasp stays aborted; a token event newer than ``event`` wins over this answer."""
        if self._closed:
            return
        try:
            replies = self._session.liveliness().get(key, timeout=self.recheck_timeout_s)
            live = any(r.ok is not None and str(r.ok.key_expr) == key for r in replies)
        except Exception as exc:  # a closing session: the undeclaration stands (the safe side)
            log.warning("zenoh liveliness re-check of %s failed: %s: %s", key, type(exc).__name__, exc)
            return
        with self._laptop_lock:
            if live and not self._closed and self._laptop_events.get(peer) == event:
                log.warning("laptop %s: its liveliness token was undeclared but is live; supervised again", peer)
                self.controller.peer_present(peer)

    def _heartbeat_loop(self) -> None:
        """Put the crane's heartbeat each period. A failed put is not fatal (the laptop's own
        staleness check covers a silent crane) but is logged with its cause: the first failure of
        a run of them as a warning, and the recovery with how many were lost."""
        failed = 0
        while not self._stop.wait(self.heartbeat_period_s):
            try:
                self._session.put(self.keys.heartbeat, self.controller.heartbeat_frame())
            except Exception as exc:
                if not failed:
                    log.warning("zenoh heartbeat put on %s failed: %s: %s", self.keys.heartbeat,
                                type(exc).__name__, exc, exc_info=True)
                failed += 1
                self.heartbeat_failures += 1
                continue
            if failed:
                log.warning("zenoh heartbeats on %s resumed after %d failed puts", self.keys.heartbeat, failed)
                failed = 0

    def send(self, kind: str, data: bytes) -> None:
        if self._closed or self._session is None:
            return
        key = {"Ack": self.keys.ack, "Outcome": self.keys.outcome, "Status": self.keys.status}.get(kind)
        if key is not None:
            self._session.put(key, data, congestion_control=self._zenoh.CongestionControl.BLOCK)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)
        if self._session is not None:
            _close_session(self._session)
