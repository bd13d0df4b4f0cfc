"""IEC 61784-3 transmission errors that had no test on a link (issue 39's safety case), each with
its safe reaction: on Zenoh the faults test_link_faults.py injects on CAN, on a laptop whose sends
go through an armed fault channel, to an in-process crane controller over Zenoh on 127.0.0.1 (no
scouting); on both links a frame protected for another message kind. Each test is a cell of
docs/safety-case.md (scripts/safety_case.py)."""

from __future__ import annotations

import collections
import threading
from typing import Iterator

import pytest

from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
from field.errors import LinkTimeout
from field.link import ControllerState, RejectReason
from field.link.base import LinkConfig, LinkURL
from tests.field.helpers import lost_command_is_known_not_executed, wait_until

LINK = LinkConfig(insecure=True, heartbeat_timeout_s=1.0, status_timeout_s=1.0, connect_timeout_s=20.0)
E2E = "E2E profile: CRC over data id + payload, and a 4-bit alive counter"


def _flip(data: bytes, byte: int) -> bytes:
    return data[:byte] + bytes([data[byte] ^ 0x08]) + data[byte + 1:]


class ZenohPair:
    """A laptop (ZenohLink whose sends can be armed with a fault) and a crane controller."""

    def __init__(self, port: int, delay_s: float = 0.05):
        from field.link.zenoh_backend import ZenohControllerTransport, ZenohLink, ZenohTarget

        class ArmedZenohLink(ZenohLink):
            def __init__(self, target, config):
                self.armed: list[tuple[str, str, int]] = []  # (action, kind, byte), one frame each
                self.held: list[tuple[str, bytes]] = []
                self.lock = threading.Lock()
                self.received: collections.Counter = collections.Counter()  # frames delivered, by kind
                super().__init__(target, config)

            def _deliver(self, kind: str, data: bytes) -> None:
                self.received[kind] += 1
                ZenohLink._deliver(self, kind, data)

            def _transmit(self, kind: str, data: bytes) -> None:
                with self.lock:
                    fault = next((f for f in self.armed if f[1] == kind), None)
                    if fault is not None:
                        self.armed.remove(fault)
                action = fault[0] if fault else None
                if action == "drop":
                    return
                if action == "hold":
                    self.held.append((kind, data))
                    return
                ZenohLink._transmit(self, kind, _flip(data, fault[2]) if action == "corrupt" else data)
                if action == "duplicate":
                    ZenohLink._transmit(self, kind, data)

        url = LinkURL.parse(f"zenoh://127.0.0.1:{port}/safety")
        target = ZenohTarget.from_url(url, url.pop_link_config()[1])
        self.executor = FixedOutcomeExecutor(delay_s=delay_s)
        self.controller = CraneController(ControllerConfig(laptop_timeout_s=1.0, no_journal=True, insecure_link=True),
                                          self.executor)
        self.transport = ZenohControllerTransport(target)
        self.transport.start(self.controller)
        self.controller.start()
        self.link = ArmedZenohLink(target, LINK)
        self.link._await_controller()

    def arm(self, action: str, kind: str = "GraspCommand", byte: int = 20) -> None:
        with self.link.lock:
            self.link.armed.append((action, kind, byte))

    def release(self) -> int:
        """Send the held frames now (late); how many."""
        from field.link.zenoh_backend import ZenohLink

        held, self.link.held = self.link.held, []
        for kind, data in held:
            ZenohLink._transmit(self.link, kind, data)
        return len(held)

    def close(self) -> None:
        self.link.close()
        self.controller.close()
        self.transport.close()


@pytest.fixture
def zpair(port) -> Iterator:
    made: list[ZenohPair] = []

    def make(delay_s: float = 0.05) -> ZenohPair:
        made.append(ZenohPair(port, delay_s))
        return made[-1]

    yield make
    for p in made:
        p.close()


@pytest.mark.safety_case(error="corruption", link="zenoh", measure=E2E + " (CRC)",
                         reaction="frame rejected CRC, answered for command id 0 (for nobody); not executed; the "
                                  "laptop's status query says NOT executing")
def test_zenoh_corrupted_command_is_answered_for_nobody(zpair, make_cmd):
    p = zpair()
    p.arm("corrupt", byte=20)
    cmd = make_cmd(p.link.new_command_id())
    with pytest.raises(LinkTimeout) as ei:
        p.link.send_grasp(cmd, timeout_s=1.0)
    assert ei.value.status.state is ControllerState.IDLE and "NOT executing" in str(ei.value)
    assert p.controller.rejections == [(0, RejectReason.CRC)]
    assert p.executor.executed == []


@pytest.mark.safety_case(error="unintended repetition", link="zenoh",
                         measure=E2E + " (counter: a copy repeats the last value); command ids burned in the journal",
                         reaction="the copy is dropped unanswered (counter); were it not, its id is known and it "
                                  "gets the same answer (journal); the command runs once")
def test_zenoh_duplicated_command_executes_once(zpair, make_cmd):
    p = zpair()
    p.arm("duplicate")
    cmd = make_cmd(p.link.new_command_id())
    assert p.link.send_grasp(cmd, timeout_s=5.0).accepted
    p.link.wait_outcome(cmd.command_id, 10.0)
    p.link.status()  # a barrier: the controller handled the copy before this query
    assert p.executor.executed == [cmd.command_id] and p.controller.rejections == []
    assert p.link.received["Ack"] == 1  # the copy was recognised by its counter and not answered


@pytest.mark.safety_case(error="incorrect sequence", link="zenoh", measure=E2E + " (counter)",
                         reaction="the overtaken, late command is rejected COUNTER and never executed")
def test_zenoh_reordered_late_command_is_never_executed(zpair, make_cmd):
    p = zpair()
    a = make_cmd(p.link.new_command_id())
    p.arm("hold")
    with pytest.raises(LinkTimeout):
        p.link.send_grasp(a, timeout_s=1.0)
    b = make_cmd(p.link.new_command_id())
    assert p.link.send_grasp(b, timeout_s=5.0).accepted  # b overtakes a
    p.link.wait_outcome(b.command_id, 10.0)
    assert p.release() == 1  # a arrives late, out of sequence
    assert wait_until(lambda: (a.command_id, RejectReason.COUNTER) in p.controller.rejections)
    assert p.executor.executed == [b.command_id]


@pytest.mark.safety_case(error="loss", link="zenoh",
                         measure="acknowledgement timeout, then a status query (the controller's own state)",
                         reaction="the operator is told NOT executing; the id is burned (never re-sent); the next "
                                  "command runs")
def test_zenoh_dropped_command_is_known_not_executed(zpair, make_cmd):
    p = zpair()
    p.arm("drop")
    lost_command_is_known_not_executed(p.link, p.executor, make_cmd)


@pytest.mark.safety_case(error="unacceptable delay", link="zenoh",
                         measure="acknowledgement timeout, then revocation of the id (the command again with 0 target "
                                 "logs, refused by definition, burns it); pile-age limit on the crane's clock",
                         reaction="the operator is told it did not run; the late frame is rejected DUPLICATE_ID and "
                                  "never executed")
def test_zenoh_command_delayed_past_its_timeout_never_runs(zpair, make_cmd):
    p = zpair()
    p.arm("hold")
    cmd = make_cmd(p.link.new_command_id())
    fate = p.link.execute(cmd, ack_timeout_s=1.0)
    assert fate.executed is False and "revoked" in fate.summary
    assert p.release() == 1  # the late frame arrives
    assert wait_until(lambda: (cmd.command_id, RejectReason.DUPLICATE_ID) in p.controller.rejections)
    assert p.executor.executed == []


def misaddressed_command(cmd, encoder) -> bytes:
    """A command frame E2E-protected under another message kind's data id (an Outcome's): the
    same length and layout, a valid CRC, but meant for another receiver."""
    from e2e.p05 import e2e_p05_protect

    from field.link.codec import data_id

    _, frame = encoder.encode(cmd)
    data = bytearray(frame)
    e2e_p05_protect(data, data_id("Outcome"), increment_counter=False)
    return bytes(data)


@pytest.mark.safety_case(error="addressing", link="zenoh",
                         measure="the E2E data id of each message kind is inside the CRC; a key expression per "
                                 "message kind and crane",
                         reaction="a frame protected for another message kind, at the command key, is rejected CRC; "
                                  "never executed")
def test_zenoh_frame_of_another_kind_at_the_command_key_is_rejected(zpair, make_cmd):
    from field.link.zenoh_backend import ZenohLink

    p = zpair()
    cmd = make_cmd(p.link.new_command_id())
    ZenohLink._transmit(p.link, "GraspCommand", misaddressed_command(cmd, p.link._encoder))
    assert wait_until(lambda: len(p.controller.rejections) == 1)
    assert p.controller.rejections == [(0, RejectReason.CRC)]
    assert p.executor.executed == [] and not p.controller.seen(cmd.command_id)


@pytest.mark.safety_case(error="addressing", link="can",
                         measure="the E2E data id of each message kind is inside the CRC (one CAN id per kind)",
                         reaction="a frame protected for another message kind, on the command id, is rejected CRC; "
                                  "never executed")
def test_can_frame_of_another_kind_on_the_command_id_is_rejected(make_cmd):
    import can

    from field.link.codec import Encoder, frame_id
    from tests.field.helpers import can_pairs

    with can_pairs("addressing", LINK) as make:
        p = make()
        cmd = make_cmd(p.link.new_command_id())
        p.node().send(can.Message(arbitration_id=frame_id("GraspCommand"), is_extended_id=False, is_fd=True,
                                  data=misaddressed_command(cmd, Encoder())))
        assert wait_until(lambda: len(p.controller.rejections) == 1)
        assert p.controller.rejections == [(0, RejectReason.CRC)]
        assert p.executor.executed == [] and not p.controller.seen(cmd.command_id)
