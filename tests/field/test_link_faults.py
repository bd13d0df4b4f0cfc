"""Fault injection on the CAN link (in-process virtual bus, FaultyBus on both ends): a command is
never executed twice, never when stale or out of sequence, and the final state is always known.

Timing margins hold on a loaded 2-core machine: a timeout a test expects is 1 s, an executor that
must still run when a status query comes is 3-6 s, and waits for something that should happen
end as soon as it does (wait_until, or a status query as a barrier behind the frames in flight)."""

from __future__ import annotations

import time

import can
import pytest

from field.errors import CommandRejected, LinkError, LinkTimeout
from field.link import ControllerState, OutcomeClass, RejectReason
from field.link.base import LinkConfig
from tests.field.helpers import can_pairs, lost_command_is_known_not_executed, wait_until


@pytest.fixture
def pair():
    with can_pairs("faults", LinkConfig(insecure=True, heartbeat_timeout_s=1.0, status_timeout_s=1.0)) as make:
        yield make


@pytest.mark.safety_case(error="loss", link="can",
                         measure="acknowledgement timeout, then a status query",
                         reaction="the operator is told NOT executing; the id is burned; the next command runs")
def test_dropped_command_frame(pair, make_cmd):
    p = pair()
    p.lbus.arm("drop", "GraspCommand")
    lost_command_is_known_not_executed(p.link, p.executor, make_cmd)


def test_dropped_ack_final_state_known(pair, make_cmd):
    p = pair(delay_s=3.0)
    p.cbus.arm("drop", "Ack")
    cmd = make_cmd(p.link.new_command_id())
    with pytest.raises(LinkTimeout) as ei:
        p.link.send_grasp(cmd, timeout_s=1.0)
    assert ei.value.status.current_command_id == cmd.command_id  # the operator learns it IS running
    assert "IS executing" in str(ei.value)
    assert p.link.wait_outcome(cmd.command_id, 10.0).outcome_class is OutcomeClass.SUCCESS
    assert p.executor.executed == [cmd.command_id]


@pytest.mark.safety_case(error="unintended repetition", link="can",
                         measure="E2E profile: CRC over data id + payload, 4-bit alive counter (counter: a copy "
                                 "repeats the last value); command ids burned",
                         reaction="the copy is dropped; the command runs once")
def test_duplicated_command_frame_executes_once(pair, make_cmd):
    p = pair()
    p.lbus.arm("duplicate", "GraspCommand")
    cmd = make_cmd(p.link.new_command_id())
    assert p.link.send_grasp(cmd, timeout_s=5.0).accepted
    p.link.wait_outcome(cmd.command_id, 10.0)
    p.link.status()  # a barrier: the controller handled the copy before this query
    assert p.executor.executed == [cmd.command_id]
    assert p.controller.rejections == []  # the copy was recognised by its counter and dropped


@pytest.mark.safety_case(error="corruption", link="can",
                         measure="E2E profile: CRC over data id + payload, 4-bit alive counter (CRC)",
                         reaction="rejected CRC and answered for command id 0 (for nobody); not executed; status "
                                  "query: NOT executing")
@pytest.mark.parametrize("byte", [20, 5])  # inside the northing / inside the command id
def test_corrupted_command_frame_is_answered_for_nobody(pair, make_cmd, byte):
    """The controller answers a frame that failed its CRC with id 0: the laptop never takes it
    for the answer to its command, and learns from the status that nothing runs."""
    p = pair()
    p.lbus.arm("corrupt", "GraspCommand", byte=byte)
    cmd = make_cmd(p.link.new_command_id())
    with pytest.raises(LinkTimeout) as ei:
        p.link.send_grasp(cmd, timeout_s=1.0)
    assert ei.value.status.state is ControllerState.IDLE and "NOT executing" in str(ei.value)
    assert p.controller.rejections == [(0, RejectReason.CRC)]
    assert wait_until(lambda: p.link.stats.unattributed_answers == 1)
    assert p.executor.executed == []


@pytest.mark.safety_case(error="incorrect sequence", link="can",
                         measure="E2E profile: CRC over data id + payload, 4-bit alive counter (counter)",
                         reaction="the overtaken, late command is rejected COUNTER and never executed")
def test_reordered_late_command_is_never_executed(pair, make_cmd):
    p = pair()
    a = make_cmd(p.link.new_command_id())
    p.lbus.arm("hold", "GraspCommand")
    with pytest.raises(LinkTimeout):
        p.link.send_grasp(a, timeout_s=1.0)
    b = make_cmd(p.link.new_command_id())
    assert p.link.send_grasp(b, timeout_s=5.0).accepted  # b overtakes a
    p.link.wait_outcome(b.command_id, 10.0)
    assert p.lbus.release() == 1  # a arrives late, out of sequence
    assert wait_until(lambda: (a.command_id, RejectReason.COUNTER) in p.controller.rejections)
    assert p.executor.executed == [b.command_id]


@pytest.mark.safety_case(error="corruption", link="can",
                         measure="E2E profile: CRC over data id + payload, 4-bit alive counter (CRC) on the crane's"
                                 " answers",
                         reaction="the corrupted acknowledgement is counted and dropped; the status query tells the"
                                  " operator the command IS executing")
@pytest.mark.safety_case(error="unintended repetition", link="can",
                         measure="E2E profile: CRC over data id + payload, 4-bit alive counter (counter) on the "
                                 "crane's answers",
                         reaction="the copied acknowledgement is dropped as a duplicate")
def test_corrupted_and_duplicated_answers(pair, make_cmd):
    p = pair(delay_s=3.0)
    p.cbus.arm("corrupt", "Ack")
    cmd = make_cmd(p.link.new_command_id())
    with pytest.raises(LinkTimeout) as ei:
        p.link.send_grasp(cmd, timeout_s=1.0)
    assert p.link.stats.crc_errors == 1
    assert ei.value.status.current_command_id == cmd.command_id
    p.link.wait_outcome(cmd.command_id, 10.0)
    p.executor.delay_s = 0.05
    p.lbus.arm("duplicate", "Ack", direction="rx")
    cmd2 = make_cmd(p.link.new_command_id())
    assert p.link.send_grasp(cmd2, timeout_s=5.0).accepted
    p.link.wait_outcome(cmd2.command_id, 10.0)
    assert p.link.stats.duplicates_dropped == 1
    assert p.executor.executed == [cmd.command_id, cmd2.command_id]


@pytest.mark.safety_case(error="loss", link="can",
                         measure="outcome deadline, then a status query (the last outcome)",
                         reaction="the final state is recovered from the controller's status")
def test_lost_outcome_recovered_from_status(pair, make_cmd):
    p = pair()
    p.cbus.arm("drop", "Outcome")
    p.cbus.arm("drop", "Status")  # the unsolicited status after the outcome is lost too
    cmd = make_cmd(p.link.new_command_id(), logs=4)
    p.link.send_grasp(cmd, timeout_s=5.0)
    out = p.link.wait_outcome(cmd.command_id, 2.0)  # recovered by the status query at the deadline
    assert out.command_id == cmd.command_id and out.logs_grasped == 4


@pytest.mark.safety_case(error="loss", link="can",
                         measure="crane heartbeat timeout + status query before sending",
                         reaction="nothing is sent to a mute crane (LinkTimeout: NOT sent)")
def test_crane_heartbeat_loss(pair, make_cmd):
    p = pair()
    p.cbus.arm("drop", "CraneHeartbeat", count=None)
    assert wait_until(lambda: not p.link.controller_alive())
    cmd = make_cmd(p.link.new_command_id())
    assert p.link.send_grasp(cmd, timeout_s=5.0).accepted  # the status query proves it is there
    p.link.wait_outcome(cmd.command_id, 10.0)
    p.cbus.arm("drop", None, count=None)  # now the crane is mute
    assert wait_until(lambda: not p.link.controller_alive())
    cmd2 = make_cmd(p.link.new_command_id())
    with pytest.raises(LinkTimeout, match="NOT sent") as ei:
        p.link.send_grasp(cmd2, timeout_s=1.0)
    assert ei.value.status is None
    assert p.executor.executed == [cmd.command_id]


@pytest.mark.safety_case(abort="laptop heartbeats lost", link="can",
                         reaction="ABORTED within the 1 s laptop timeout (not at the 6 s end); a new session works")
@pytest.mark.safety_case(error="loss", link="can",
                         measure="laptop heartbeat timeout on the controller (1 s)",
                         reaction="the running grasp is aborted (ABORTED outcome) within the laptop timeout")
def test_laptop_heartbeat_loss_aborts_the_running_grasp(pair, make_cmd):
    p = pair(delay_s=6.0, laptop_timeout_s=1.0)
    cmd = make_cmd(p.link.new_command_id())
    p.link.send_grasp(cmd, timeout_s=5.0)
    p.lbus.arm("drop", "LaptopHeartbeat", count=None)
    t = time.monotonic()
    out = p.link.wait_outcome(cmd.command_id, 15.0)
    assert out.outcome_class is OutcomeClass.ABORTED and time.monotonic() - t < 4.0  # not the 6 s end
    p.lbus.disarm()
    assert wait_until(lambda: p.controller.status().laptops == 1)  # heartbeats back: a new session
    nxt = make_cmd(p.link.new_command_id())
    p.executor.delay_s = 0.05
    assert p.link.send_grasp(nxt, timeout_s=5.0).accepted
    p.link.wait_outcome(nxt.command_id, 10.0)
    assert p.executor.executed == [cmd.command_id, nxt.command_id]


def test_frozen_laptop_heartbeat_means_unsupervised(pair, make_cmd):
    """A stuck sender (FaultyBus 'freeze': its first heartbeat frame again and again) is no
    supervision: the controller counts no live laptop and refuses commands UNSUPERVISED."""
    p = pair(laptop_timeout_s=0.5)
    p.lbus.arm("freeze", "LaptopHeartbeat", count=None)
    assert wait_until(lambda: p.controller.status().laptops == 0)
    cmd = make_cmd(p.link.new_command_id())
    with pytest.raises(CommandRejected) as ei:
        p.link.send_grasp(cmd, timeout_s=5.0)
    assert ei.value.reason is RejectReason.UNSUPERVISED
    p.lbus.disarm()
    assert wait_until(lambda: p.controller.status().laptops == 1)
    assert p.executor.executed == []
    with pytest.raises(ValueError, match="sent frames only"):
        p.lbus.arm("freeze", "LaptopHeartbeat", direction="rx")


def test_bus_errors(pair, make_cmd):
    p = pair()
    p.lbus.arm("error", "GraspCommand")
    cmd = make_cmd(p.link.new_command_id())
    with pytest.raises(LinkError) as ei:
        p.link.send_grasp(cmd, timeout_s=1.0)
    assert type(ei.value) is LinkError and isinstance(ei.value.__cause__, can.CanError)
    assert p.link.guard.used(cmd.command_id)  # burned: never sent later by accident
    nxt = make_cmd(p.link.new_command_id())
    assert p.link.send_grasp(nxt, timeout_s=5.0).accepted
    p.link.wait_outcome(nxt.command_id, 10.0)
    # a receive error is unrecoverable for this link: every call says so
    p.lbus.arm("error", None, direction="rx")
    assert wait_until(lambda: p.link._failure is not None)
    with pytest.raises(LinkError, match="failed"):
        p.link.status()
    assert p.link.stats.bus_errors >= 1
    assert p.executor.executed == [nxt.command_id]


@pytest.mark.safety_case(error="unacceptable delay", link="can",
                         measure="pile-data age limit checked on the crane's own clock",
                         reaction="rejected STALE; never executed")
def test_stale_on_the_crane_clock_is_never_executed(pair, make_cmd):
    p = pair(max_pile_age_s=1.0)
    cmd = make_cmd(p.link.new_command_id(), age_s=2.0)  # fine for the laptop (30 s), stale for the crane
    with pytest.raises(CommandRejected) as ei:
        p.link.send_grasp(cmd, timeout_s=1.0)
    assert ei.value.reason is RejectReason.STALE
    assert p.executor.executed == []
