"""The crane controller twin, without a transport: validation, journal, faults, e-stop."""

from __future__ import annotations

import json
import threading
import time

import pytest

from field.controller import (
    EXECUTORS,
    ControllerConfig,
    ControllerJournal,
    CraneController,
    FixedOutcomeExecutor,
    ReachEnvelope,
    make_executor,
    read_execution_log,
    run_controller,
)
from field.errors import ControllerError
from field.link.codec import EStopRequest, Encoder, StatusRequest, decode
from field.link.messages import Ack, ControllerState, ControllerStatus, Outcome, OutcomeClass, RejectReason
from tests.field.helpers import SupervisingLaptop, wait_until


class Feeder:
    """Sends frames into a controller like a laptop would (a fresh heartbeat before each: a
    supervising laptop) and collects its answers."""

    def __init__(self, ctl: CraneController):
        self.ctl = ctl
        self.laptop = SupervisingLaptop(ctl)
        self.enc = self.laptop.enc
        self.laptop.beat()
        self.published: list = []
        ctl.attach(lambda k, d: self.published.append(decode(k, d).message))

    def send(self, msg) -> list:
        replies: list = []
        self.laptop.beat()
        kind, data = self.enc.encode(msg)
        self.ctl.on_frame(kind, data, lambda k, d: replies.append(decode(k, d).message))
        return replies

    def grasp(self, cmd) -> Ack:
        (ack,) = self.send(cmd)
        return ack

    def wait_idle(self, timeout_s: float = 3.0) -> None:
        w = self.ctl._worker
        if w is not None:
            w.join(timeout_s)


def test_config_validation():
    with pytest.raises(ValueError, match="reach"):
        ReachEnvelope(min_reach_m=5.0, max_reach_m=3.0)
    with pytest.raises(ValueError, match="dz"):
        ReachEnvelope(min_dz_m=1.0, max_dz_m=0.0)
    with pytest.raises(ValueError, match="width"):
        ControllerConfig(min_width_mm=2000)
    with pytest.raises(ValueError, match="heading"):
        ControllerConfig(max_heading_cdeg=40000)
    with pytest.raises(ValueError):
        ControllerConfig(max_pile_age_s=0)
    with pytest.raises(ValueError):
        FixedOutcomeExecutor(delay_s=-1)


def test_accept_execute_and_report(make_cmd):
    ex = FixedOutcomeExecutor(delay_s=0.0, outcome_class="collision", logs_grasped=1, balance_cos_milli=700)
    ctl = CraneController(ControllerConfig(no_journal=True, insecure_link=True), ex)
    f = Feeder(ctl)
    cmd = make_cmd(11, logs=3)
    assert f.grasp(cmd) == Ack(11, True)
    f.wait_idle()
    assert Outcome(11, OutcomeClass.COLLISION, 1, 700) in f.published
    (st,) = f.send(StatusRequest(5))
    assert st == ControllerStatus(ControllerState.DONE, 0, 0, Outcome(11, OutcomeClass.COLLISION, 1, 700), 5, laptops=1)
    assert f.grasp(cmd) == Ack(11, True)  # an identical copy: the same answer, no second run
    from dataclasses import replace

    assert f.grasp(replace(cmd, heading_cdeg=100)) == Ack(11, False, RejectReason.DUPLICATE_ID)  # id reused
    assert ex.executed == [11]


def test_reach_envelope_boundaries(make_cmd):
    ctl = CraneController(ControllerConfig(reach=ReachEnvelope(min_reach_m=2.0, max_reach_m=10.0), no_journal=True, insecure_link=True), FixedOutcomeExecutor(0.0))
    f = Feeder(ctl)
    cases = [(1.99, RejectReason.OUT_OF_REACH), (10.01, RejectReason.OUT_OF_REACH), (9.99, RejectReason.NONE)]
    for i, (de, reason) in enumerate(cases, start=1):
        ack = f.grasp(make_cmd(i, de=de))
        assert ack.reason is reason, de
        f.wait_idle()
    # diagonal: 7 m east + 7 m north = 9.9 m, inside; 8 + 8 = 11.3 m, outside
    assert f.grasp(make_cmd(10, de=7.0, dn=7.0)).accepted
    f.wait_idle()
    assert f.grasp(make_cmd(11, de=8.0, dn=8.0)).reason is RejectReason.OUT_OF_REACH


def test_journal_never_executes_twice_across_restarts(tmp_path, make_cmd):
    journal = tmp_path / "journal.json"
    cfg = ControllerConfig(journal_path=str(journal), insecure_link=True)
    ex1 = FixedOutcomeExecutor(delay_s=0.0)
    ctl1 = CraneController(cfg, ex1)
    f1 = Feeder(ctl1)
    assert f1.grasp(make_cmd(21)).accepted
    f1.wait_idle()
    # a command the controller "crashes" in: accepted (journaled), never finished
    blocker = threading.Event()

    def hang(cmd):
        blocker.wait(5)
        return Outcome(cmd.command_id, OutcomeClass.SUCCESS, 1, 1000)

    ctl1.executor = hang
    assert f1.grasp(make_cmd(22)).accepted
    head = json.loads(journal.read_text().splitlines()[0])
    assert head["format"] == "loggrasp.controller_journal" and head["version"].startswith("2.")
    # restart from the journal while 22 is still "running" (= the old process died)
    ex2 = FixedOutcomeExecutor(delay_s=0.0)
    ctl2 = CraneController(cfg, ex2)
    f2 = Feeder(ctl2)
    st = ctl2.status()
    assert st.last_outcome == Outcome(22, OutcomeClass.ABORTED, 0, 0)  # the final state is known
    assert f2.grasp(make_cmd(21)).reason is RejectReason.DUPLICATE_ID
    assert f2.grasp(make_cmd(22)).reason is RejectReason.DUPLICATE_ID
    assert ex2.executed == []
    blocker.set()
    f1.wait_idle()


def test_journal_version_checked(tmp_path):
    p = tmp_path / "j.json"
    p.write_text(json.dumps({"format": "loggrasp.controller_journal", "version": "3.0"}) + "\n")
    with pytest.raises(ControllerError, match="version"):
        ControllerJournal(p)
    p.write_text("{not json")
    with pytest.raises(ControllerError, match="unreadable"):
        ControllerJournal(p)


def test_journal_reads_version_1_and_survives_a_torn_last_line(tmp_path):
    p = tmp_path / "j.json"
    p.write_text(json.dumps({"format": "loggrasp.controller_journal", "version": "1.0", "entries": [
        {"command_id": 5, "status": "done", "outcome": {"outcome_class": "SUCCESS", "logs_grasped": 2,
                                                        "balance_cos_milli": 990}}]}))
    ids, last = ControllerJournal(p).recover()
    assert set(ids) == {5} and last == Outcome(5, OutcomeClass.SUCCESS, 2, 990)
    assert json.loads(p.read_text().splitlines()[0])["version"].startswith("2.")  # rewritten as 2.x
    j = ControllerJournal(p)
    j.record_rejected(6, RejectReason.BUSY)
    with open(p, "a") as f:
        f.write('{"command_id": 7, "sta')  # the controller died mid-line
    assert ControllerJournal(p).recover()[0] == {5: (None, RejectReason.NONE), 6: (None, RejectReason.BUSY)}


def test_executor_failure_is_a_fault_until_reset(make_cmd):
    def broken(cmd):
        raise RuntimeError("hydraulics")

    ctl = CraneController(ControllerConfig(no_journal=True, insecure_link=True), broken)
    f = Feeder(ctl)
    assert f.grasp(make_cmd(31)).accepted
    f.wait_idle()
    assert ctl.state is ControllerState.FAULT
    assert ctl.fault_cause == "executor failed on command 31: RuntimeError: hydraulics"  # the cause is kept
    assert Outcome(31, OutcomeClass.ABORTED, 0, 0) in f.published
    assert f.grasp(make_cmd(32)).reason is RejectReason.FAULT
    ctl.executor = FixedOutcomeExecutor(delay_s=0.0)
    ctl.reset_fault()
    assert ctl.fault_cause is None
    assert f.grasp(make_cmd(33)).accepted


def test_estop_is_fail_safe_and_latched(make_cmd):
    ex = FixedOutcomeExecutor(delay_s=5.0)
    ctl = CraneController(ControllerConfig(no_journal=True, insecure_link=True), ex)
    f = Feeder(ctl)
    assert f.grasp(make_cmd(41)).accepted
    kind, data = Encoder().encode(EStopRequest())
    bad = bytearray(data)
    bad[6] ^= 0xFF  # corrupted e-stop frame: still stops
    t = time.monotonic()
    ctl.on_frame(kind, bytes(bad), lambda k, d: None)
    f.wait_idle()
    assert time.monotonic() - t < 1.0  # the executor was aborted, not waited for
    assert ctl.state is ControllerState.ESTOP
    assert Outcome(41, OutcomeClass.ABORTED, 2, 985) in f.published
    assert f.grasp(make_cmd(42)).reason is RejectReason.ESTOP
    ctl.reset_estop()  # local reset only
    assert f.grasp(make_cmd(43)).accepted
    ctl.close()


def test_corrupted_status_request_is_ignored():
    ctl = CraneController(ControllerConfig(no_journal=True, insecure_link=True), FixedOutcomeExecutor())
    kind, data = Encoder().encode(StatusRequest(1))
    replies: list = []
    ctl.on_frame(kind, data[:-1] + bytes([data[-1] ^ 1]), lambda k, d: replies.append(k))
    assert replies == []
    ctl.on_frame(kind, data, lambda k, d: replies.append(k))
    assert replies == ["Status"]


def test_executor_registry_and_log(tmp_path, make_cmd):
    assert {"fixed", "pybullet"} <= set(EXECUTORS)
    module, _, attr = EXECUTORS["pybullet"].partition(":")
    import importlib

    assert callable(getattr(importlib.import_module(module), attr))
    with pytest.raises(ControllerError, match="unknown executor"):
        make_executor("pybullet-not-registered")
    log = tmp_path / "exec.jsonl"
    ex = make_executor("fixed", delay_s=0.0, log_path=str(log))
    ex(make_cmd(51))
    ex(make_cmd(52))
    assert read_execution_log(log) == [51, 52]
    log.write_text('{"format": "other"}\n')
    with pytest.raises(ControllerError):
        read_execution_log(log)


def test_run_controller_serves_until_stopped(make_cmd):
    import uuid

    from field.link import open_link

    url = f"can://virtual/rc-{uuid.uuid4().hex[:8]}?insecure=1"
    stop, ready = threading.Event(), threading.Event()
    result: list = []
    th = threading.Thread(target=lambda: result.append(run_controller(url, "fixed", stop, ready_event=ready)))
    th.start()
    try:
        assert ready.wait(5)
        with open_link(url) as link:
            cmd = make_cmd(link.new_command_id())
            link.send_grasp(cmd)
            assert link.wait_outcome(cmd.command_id, 2.0).success
    finally:
        stop.set()
        th.join(5)
    assert not th.is_alive()
    assert result[0].last_outcome.command_id == cmd.command_id



def test_a_controller_in_a_thread_that_cannot_serve_is_a_link_error_with_its_cause():
    from field.controller import controller_in_thread
    from field.errors import LinkError

    with pytest.raises(LinkError, match="could not serve can://virtual/ctl-bad: unknown executor 'warp'") as e:
        with controller_in_thread("can://virtual/ctl-bad", "warp", ControllerConfig(), start_timeout_s=5.0):
            pass
    assert e.value.__cause__ is not None


def test_a_controller_in_a_thread_serves_for_the_block_and_stops_after(make_cmd):
    import uuid

    from field.controller import controller_in_thread
    from field.errors import LinkError
    from field.link import open_link
    from field.link.base import LinkConfig

    url = f"can://virtual/ctl-{uuid.uuid4().hex[:8]}?insecure=1"
    with controller_in_thread(url, "fixed", ControllerConfig(), start_timeout_s=10.0):
        with open_link(url) as link:
            assert link.send_grasp(make_cmd(link.new_command_id())).accepted
    with pytest.raises(LinkError):  # nobody serves the channel after the block
        open_link(url, LinkConfig(insecure=True, connect_timeout_s=0.3)).close()


# --- exactly once across restarts, by default ------------------------------------------------------


def _serve(url: str, executor: FixedOutcomeExecutor) -> tuple[threading.Event, threading.Thread, CraneController]:
    """``run_controller(url, executor)`` with its defaults on a thread; (stop, thread, its controller)."""
    stop, ready, served = threading.Event(), threading.Event(), []
    th = threading.Thread(target=run_controller, args=(url, executor, stop), daemon=True,
                          kwargs={"ready_event": ready, "on_serve": served.append})
    th.start()
    assert ready.wait(10) and served
    return stop, th, served[0]


def test_a_controller_built_by_run_controller_with_defaults_never_runs_a_replayed_frame_after_a_restart(make_cmd):
    url = f"can://virtual/journal-{time.monotonic_ns()}?insecure=1"
    first = FixedOutcomeExecutor(delay_s=0.0)
    stop, th, ctl = _serve(url, first)
    laptop = SupervisingLaptop(ctl)
    laptop.beat(), laptop.beat()
    frame = laptop.encode(make_cmd(31))
    acks: list = []
    ctl.on_frame(*frame, lambda k, d: acks.append(decode(k, d).message))
    assert acks == [Ack(31, True)] and wait_until(lambda: first.executed == [31])
    stop.set(), th.join(10)
    again = FixedOutcomeExecutor(delay_s=0.0)
    stop, th, ctl = _serve(url, again)  # restarted with the same defaults
    try:
        laptop = SupervisingLaptop(ctl)
        laptop.beat(), laptop.beat()
        ctl.on_frame(*frame, lambda k, d: acks.append(decode(k, d).message))  # the recorded frame, replayed
        time.sleep(0.2)
        assert again.executed == [] and ctl.seen(31)
    finally:
        stop.set(), th.join(10)


def test_a_controller_without_a_journal_must_opt_out_and_says_so(caplog):
    with pytest.raises(ControllerError, match="no_journal=True"):
        CraneController(ControllerConfig(insecure_link=True), FixedOutcomeExecutor())
    with pytest.raises(ValueError, match="not both"):
        ControllerConfig(journal_path="j.jsonl", no_journal=True)
    CraneController(ControllerConfig(no_journal=True, insecure_link=True), FixedOutcomeExecutor()).close()
    assert any("journal OFF (no_journal=True)" in r.getMessage() for r in caplog.records)
