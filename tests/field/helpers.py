"""Small helpers of the field tests (import as ``tests.field.helpers``)."""

from __future__ import annotations

import json
import os
import time
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import resources
from typing import Callable, Iterator

#: how long a test waits for something that should happen "at once" [s]: generous, so that a
#: loaded 2-core machine never fails a test that is right (the wait ends as soon as it holds)
PATIENCE_S = 10.0


def wait_until(predicate: Callable[[], bool], timeout_s: float = PATIENCE_S, poll_s: float = 0.01) -> bool:
    """Poll ``predicate`` until it is true (returns True) or ``timeout_s`` passed (False)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)


# --- Zenoh roles (the shipped field/link/zenoh_acl.json5) ----------------------------------

PASSWORDS = {"crane": "crane-secret", "operator": "op-secret", "observer": "obs-secret"}


def shipped_acl(tmp_path, *, connect: str | None = None) -> str:
    """The shipped config with this test's user file (and, for a crane behind a router, the
    router to connect to); returns the path of the JSON file (JSON is JSON5)."""
    import zenoh

    users = tmp_path / "users.txt"
    users.write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    os.chmod(users, 0o600)
    conf = zenoh.Config.from_file(str(resources.files("field.link").joinpath("zenoh_acl.json5")))
    conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users)))
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps(PASSWORDS["crane"]))
    if connect is not None:  # the crane behind a router: the router enforces the roles
        for key, value in (("mode", '"client"'), ("connect/endpoints", json.dumps([connect])),
                           ("access_control/enabled", "false"),
                           ("listen/endpoints", "[]"), ("scouting/multicast/enabled", "false"),
                           ("scouting/gossip/enabled", "false")):
            conf.insert_json5(key, value)
    path = tmp_path / ("crane-client.json" if connect else "crane-node.json")
    path.write_text(str(conf))
    return str(path)


def credentials(tmp_path, user: str) -> str:
    path = tmp_path / f"{user}.json"
    path.write_text(json.dumps({"transport": {"auth": {"usrpwd": {"user": user, "password": PASSWORDS[user]}}}}))
    return str(path)


# --- a laptop and a crane controller on one virtual CAN bus ---------------------------------


@dataclass
class CanPair:
    """A CanLink (laptop) and a CraneController (crane) on one in-process virtual CAN channel."""

    channel: str
    link: "CanLink"
    lbus: "can.BusABC"  # laptop side (a FaultyBus unless the test wrapped it otherwise)
    cbus: "FaultyBus"  # crane side
    controller: "CraneController"
    executor: "FixedOutcomeExecutor"
    transport: "CanControllerTransport"
    nodes: list = field(default_factory=list)

    def node(self) -> "can.BusABC":
        """Another node on the bus (closed at teardown)."""
        import can

        bus = can.Bus(interface="virtual", channel=self.channel, fd=True)
        self.nodes.append(bus)
        return bus


@contextmanager
def can_pairs(prefix: str, link_config: "LinkConfig") -> Iterator[Callable[..., CanPair]]:
    """``make(delay_s=0.05, laptop_bus=None, **controller_config) -> CanPair``: each pair on a fresh
    channel, FaultyBus on both ends (``laptop_bus(raw_bus)`` wraps the laptop's instead), the
    controller's laptop timeout 1 s unless given; every pair closed at the end."""
    import can

    from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
    from field.link.can_backend import CanControllerTransport, CanLink
    from field.link.faults import FaultyBus

    made: list[CanPair] = []

    def make(delay_s: float = 0.05, laptop_bus=None, **cfg) -> CanPair:
        channel = f"{prefix}-{uuid.uuid4().hex[:8]}"
        cbus = FaultyBus(can.Bus(interface="virtual", channel=channel, fd=True))
        executor = FixedOutcomeExecutor(delay_s=delay_s)
        controller = CraneController(ControllerConfig(**{"laptop_timeout_s": 1.0, "no_journal": "journal_path" not in cfg,
                                                        "insecure_link": "secoc_key_path" not in cfg, **cfg}), executor)
        transport = CanControllerTransport(bus=cbus, heartbeat_period_s=controller.config.heartbeat_period_s)
        transport.start(controller)
        controller.start()
        raw = can.Bus(interface="virtual", channel=channel, fd=True)
        lbus = laptop_bus(raw) if laptop_bus is not None else FaultyBus(raw)
        link = CanLink(config=link_config, bus=lbus)
        link._await_controller()
        p = CanPair(channel, link, lbus, cbus, controller, executor, transport)
        made.append(p)
        return p

    try:
        yield make
    finally:
        for p in made:
            p.link.close()
            p.controller.close()
            p.transport.close()
            for bus in p.nodes:
                bus.shutdown()


# --- a supervising laptop for a controller driven frame by frame ---------------------------


class SupervisingLaptop:
    """The laptop side a :class:`CraneController` needs before it accepts a command: fresh,
    in-sequence heartbeats (every ``period_s`` from a thread, two at once on entry, so the laptop
    is live as the block starts). ``encode(msg)`` encodes commands on the same encoder;
    ``pause()`` stops the heartbeat (the laptop goes silent)."""

    def __init__(self, ctl: "CraneController", period_s: float = 0.05, first_heartbeat: int = 1000):
        import threading

        from field.link.codec import Encoder

        self.ctl, self.period_s = ctl, period_s
        self.enc = Encoder()
        self._hb = first_heartbeat
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True, name="supervising-laptop")

    def beat(self) -> None:
        from field.link.codec import LaptopHeartbeat

        with self._lock:
            self._hb += 1
            frame = self.enc.encode(LaptopHeartbeat(self._hb))
        self.ctl.on_frame(*frame, lambda k, d: None)

    def encode(self, msg) -> tuple[str, bytes]:
        return self.enc.encode(msg)

    def pause(self) -> None:
        self._paused.set()

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            if not self._paused.is_set():
                self.beat()

    def __enter__(self) -> "SupervisingLaptop":
        self.beat()
        self.beat()
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(5)


def lost_command_is_known_not_executed(link, executor, make_cmd, timeout_s: float = 1.0) -> None:
    """A command whose frame was lost: the acknowledgement times out and the status query tells
    the operator NOT executing; its id is burned (never re-sent); the next command runs once."""
    import pytest

    from field.errors import CommandRejected, LinkTimeout
    from field.link import ControllerState

    cmd = make_cmd(link.new_command_id())
    with pytest.raises(LinkTimeout) as ei:
        link.send_grasp(cmd, timeout_s=timeout_s)
    assert ei.value.status is not None and ei.value.status.state is ControllerState.IDLE
    assert "NOT executing" in str(ei.value)
    with pytest.raises(CommandRejected):  # never re-sent with the same id
        link.send_grasp(cmd)
    nxt = make_cmd(link.new_command_id())
    assert link.send_grasp(nxt, timeout_s=5.0).accepted  # one lost frame is within the counter tolerance
    link.wait_outcome(nxt.command_id, 10.0)
    assert executor.executed == [nxt.command_id]
