"""Soak: thousands of commands with random drops, duplicates, corruption, delays and reordering
in both directions, over the virtual CAN bus and over Zenoh on loopback.

For every command the operator's final state (:meth:`CraneLink.execute`, what the trial tells
the operator) must equal the controller's: executed exactly once if and only if the operator
is told it ran, with the same outcome; never executed when rejected or when the operator was
told it was not. Commands run on several independent lanes (a laptop and a controller each) at
once, so the waits on lost frames overlap.

Counts: ``LOGGRASP_SOAK_CAN_N`` (default 10000) and ``LOGGRASP_SOAK_ZENOH_N`` (default 2000;
``LOGGRASP_SOAK_ZENOH_N=10000`` for the full run, about 4 minutes here). Loopback only.
"""

from __future__ import annotations

import collections
import os
import random
import threading
import time
import uuid
from dataclasses import dataclass, field

import can
import pytest

from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
from field.link.base import CommandFate, CraneLink, LinkConfig
from field.link.can_backend import CanControllerTransport, CanLink
from field.link.faults import CHAOS_ACTIONS, ChaosChannel, FaultPlan, FaultyBus
from field.link.messages import GraspCommand

CAN_N = int(os.environ.get("LOGGRASP_SOAK_CAN_N", "10000"))
ZENOH_N = int(os.environ.get("LOGGRASP_SOAK_ZENOH_N", "2000"))
LANES = 8
P_FAULT = {"drop": 0.006, "duplicate": 0.006, "corrupt": 0.006, "delay": 0.006, "reorder": 0.006}
TO_CRANE = ("GraspCommand", "StatusRequest")
TO_LAPTOP = ("Ack", "Outcome", "Status")
LINK = LinkConfig(insecure=True, heartbeat_timeout_s=1.0, status_timeout_s=0.5, connect_timeout_s=20.0)
ACK_TIMEOUT_S = 0.5


@dataclass
class Lane:
    """One laptop and one controller with faults injected on both sides."""

    link: CraneLink
    controller: CraneController
    executor: FixedOutcomeExecutor
    closers: list = field(default_factory=list)
    fates: list[CommandFate] = field(default_factory=list)
    commands: list[GraspCommand] = field(default_factory=list)

    def run(self, n: int, rng: random.Random, make_cmd) -> None:
        for _ in range(n):
            cmd = make_cmd(self.link.new_command_id(), **_variant(rng))
            self.commands.append(cmd)
            self.fates.append(self.link.execute(cmd, ack_timeout_s=ACK_TIMEOUT_S, outcome_timeout_s=10.0))

    def close(self) -> None:
        for c in reversed(self.closers):
            c()


def _variant(rng: random.Random) -> dict:
    """Mostly executable commands; some the controller must refuse."""
    x = rng.random()
    if x < 0.08:
        return {"de": 50.0}  # out of reach
    if x < 0.12:
        return {"width_m": 2.0}  # wider than the grapple
    if x < 0.15:
        return {"age_s": 10.0}  # stale for the controller (5 s), fine for the laptop (30 s)
    return {"logs": rng.randint(1, 4)}


def _controller(seed: int) -> tuple[CraneController, FixedOutcomeExecutor]:
    ex = FixedOutcomeExecutor(delay_s=0.0)
    return CraneController(ControllerConfig(max_pile_age_s=5.0, laptop_timeout_s=2.0, no_journal=True, insecure_link=True), ex), ex


def can_lane(seed: int) -> Lane:
    channel = f"soak-{uuid.uuid4().hex[:8]}"
    ctl, ex = _controller(seed)
    cbus = FaultyBus(can.Bus(interface="virtual", channel=channel, fd=True), FaultPlan(seed, P_FAULT, TO_LAPTOP))
    tr = CanControllerTransport(bus=cbus)
    tr.start(ctl)
    ctl.start()
    lbus = FaultyBus(can.Bus(interface="virtual", channel=channel, fd=True), FaultPlan(seed + 1, P_FAULT, TO_CRANE))
    link = CanLink(config=LINK, bus=lbus)
    lane = Lane(link, ctl, ex, [ctl.close, tr.close, link.close])
    lane.injected = [cbus.chaos_injected, lbus.chaos_injected]
    link._await_controller()
    return lane


def zenoh_lane(seed: int, port: int) -> Lane:
    from field.link.base import LinkURL
    from field.link.zenoh_backend import ZenohControllerTransport, ZenohLink, ZenohTarget

    class ChaosZenohLink(ZenohLink):
        """Faults on the laptop's sends (commands, status queries) and on what it receives."""

        def __init__(self, target, config):
            self.tx = ChaosChannel(FaultPlan(seed + 1, P_FAULT, TO_CRANE), lambda k, d: ZenohLink._transmit(self, k, d))
            self.rx = ChaosChannel(FaultPlan(seed, P_FAULT, TO_LAPTOP), lambda k, d: ZenohLink._deliver(self, k, d))
            super().__init__(target, config)

        def _transmit(self, kind, data):
            self.tx.push(kind, data)

        def _deliver(self, kind, data):
            self.rx.push(kind, data)

        def _close_transport(self):
            self.tx.close()
            self.rx.close()
            super()._close_transport()

    url = LinkURL.parse(f"zenoh://127.0.0.1:{port}/soak-{seed}")
    target = ZenohTarget.from_url(url, url.pop_link_config()[1])
    ctl, ex = _controller(seed)
    tr = ZenohControllerTransport(target)
    tr.start(ctl)
    ctl.start()
    link = ChaosZenohLink(target, LINK)
    lane = Lane(link, ctl, ex, [ctl.close, tr.close, link.close])
    lane.injected = [link.tx.injected, link.rx.injected]
    link._await_controller()
    return lane


def soak(lanes: list[Lane], n: int, make_cmd) -> dict:
    per = [n // len(lanes) + (1 if i < n % len(lanes) else 0) for i in range(len(lanes))]
    errors: list[BaseException] = []

    def run(lane: Lane, k: int, seed: int) -> None:
        try:
            lane.run(k, random.Random(seed), make_cmd)
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(lane, k, i)) for i, (lane, k) in enumerate(zip(lanes, per))]
    t0 = time.monotonic()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    time.sleep(0.5)  # late frames (delays, reorders) land before the final check
    return check(lanes, time.monotonic() - t0)


def check(lanes: list[Lane], elapsed_s: float) -> dict:
    """Every command's final state for the operator equals the controller's."""
    tally: collections.Counter = collections.Counter()
    faults: collections.Counter = collections.Counter()
    for lane in lanes:
        executed = lane.executor.executed
        assert len(executed) == len(set(executed)), "a command ran twice"
        assert set(executed) <= {c.command_id for c in lane.commands}, "a command nobody sent ran"
        for cmd, fate in zip(lane.commands, lane.fates):
            final = fate
            if fate.executed is None or (fate.executed and fate.outcome is None):
                final = lane.link.fate(cmd.command_id)  # settled after the fact (late answers, a status)
                tally["settled afterwards"] += 1
            ran = cmd.command_id in executed
            assert final.executed is not None, f"final state UNKNOWN: {final}"
            assert final.executed == ran, f"operator told {final.final_state}, the crane {'ran' if ran else 'did not run'} it: {final}"
            if ran:
                assert final.outcome == lane.controller.outcome_of(cmd.command_id), final
            if fate.reason is not None:  # rejected: never run
                assert not ran, final
            tally[final.final_state] += 1
            tally["with notes"] += bool(final.notes)
        for counter in lane.injected:
            for (action, _), k in counter.items():
                faults[action] += k
    assert all(faults[a] > 0 for a in CHAOS_ACTIONS), faults
    return {"commands": sum(len(lane.commands) for lane in lanes), "elapsed_s": round(elapsed_s, 1),
            "states": dict(tally), "faults": dict(faults)}


@pytest.fixture
def lanes():
    made: list[Lane] = []
    yield made
    for lane in made:
        lane.close()


@pytest.mark.timeout(900)
def test_soak_can_virtual(lanes, make_cmd, record_property):
    lanes.extend(can_lane(1000 + 10 * i) for i in range(LANES))
    report = soak(lanes, CAN_N, make_cmd)
    record_property("soak_can", report)
    print("soak can-virtual:", report)
    assert report["commands"] == CAN_N


@pytest.mark.timeout(900)
def test_soak_zenoh(lanes, make_cmd, record_property):
    from tests.field.conftest import free_port

    lanes.extend(zenoh_lane(2000 + 10 * i, free_port()) for i in range(LANES))
    report = soak(lanes, ZENOH_N, make_cmd)
    record_property("soak_zenoh", report)
    print("soak zenoh:", report)
    assert report["commands"] == ZENOH_N
