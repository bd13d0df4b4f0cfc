"""The defects of issue 16, one test (or a few) each: every one of these failed on the code before
the fix (see the commit messages) and passes after it.

1 e-stop in the acceptance window   2 frozen laptop heartbeat     3 answers to corrupted frames
5 burned ids and staleness           6 extended ids, reserved bits 8 the commanding laptop
(4, the Zenoh roles, is in test_link_zenoh_acl.py; 7, authenticated frames, in test_link_secoc.py.)
"""

from __future__ import annotations

import random
import threading
import time
from dataclasses import replace

import can
import pytest

from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
from field.errors import CommandRejected, ControllerError, ProtocolError
from field.link import ControllerState, OutcomeClass, RejectReason
from field.link.base import CraneLink, LinkConfig
from field.link.can_backend import CanLink, ProxyBus
from field.link.codec import EStopRequest, Encoder, LaptopHeartbeat, decode, encode, frame_id
from field.link.messages import Ack, GraspCommand, Outcome
from tests.field.helpers import SupervisingLaptop, can_pairs, wait_until

LINK = LinkConfig(insecure=True, heartbeat_timeout_s=1.0, status_timeout_s=1.0, connect_timeout_s=10.0)


# --- a CAN pair, and frames injected by a third node ----------------------------------------


@pytest.fixture
def pair():
    with can_pairs("safety", LINK) as make:
        yield make


def can_frame(kind: str, data: bytes, *, extended: bool = False) -> can.Message:
    return can.Message(arbitration_id=frame_id(kind), is_extended_id=extended, is_fd=True, data=data, check=True)


def outcome_of(published: list, command_id: int) -> Outcome | None:
    return next((m for m in published if isinstance(m, Outcome) and m.command_id == command_id), None)


# --- 1: an e-stop just after the acceptance ---------------------------------------------------


@pytest.mark.safety_case(abort="e-stop in the acceptance window", link="both",
                         reaction="the grasp never runs to SUCCESS: refused ESTOP or ABORTED")
def test_estop_in_the_acceptance_window_aborts_the_grasp(make_cmd):
    """The e-stop arrives while the controller sends the acceptance (the window between marking
    the command executing and starting it): the grasp must not run to SUCCESS."""
    ex = FixedOutcomeExecutor(delay_s=4.0)
    ctl = CraneController(ControllerConfig(no_journal=True, insecure_link=True), ex)
    published: list = []
    ctl.attach(lambda k, d: published.append(decode(k, d).message))
    estop = Encoder().encode(EStopRequest())

    def reply(kind: str, data: bytes) -> None:
        if kind == "Ack" and decode(kind, data).message.accepted:
            ctl.on_frame(*estop, lambda k, d: None)

    t0 = time.monotonic()
    try:
        with SupervisingLaptop(ctl) as laptop:
            ctl.on_frame(*laptop.encode(make_cmd(1)), reply)
            assert wait_until(lambda: outcome_of(published, 1) is not None)
        assert outcome_of(published, 1).outcome_class is OutcomeClass.ABORTED
        assert time.monotonic() - t0 < 3.0  # stopped, not run for its 4 s
        assert ctl.state is ControllerState.ESTOP
    finally:
        ctl.close()


def _race(send_grasp, send_estop, controller: CraneController, make_cmd, new_id, tries: int) -> list[str]:
    """``tries`` commands each raced by an e-stop; the fate of each (never SUCCESS)."""
    fates = []
    rng = random.Random(16)
    for _ in range(tries):
        go = threading.Event()
        t = threading.Thread(target=lambda: (go.wait(5), time.sleep(rng.uniform(0, 0.003)), send_estop()))
        t.start()
        cmd = make_cmd(new_id())
        go.set()
        fates.append(send_grasp(cmd))
        t.join(5)
        assert wait_until(lambda: _reset(controller))  # the local reset on the crane, between tries
    return fates


def _reset(controller: CraneController) -> bool:
    try:
        controller.reset_estop()
        return True
    except ControllerError:  # the aborted grasp is still winding down
        return False


def _grasp_fate(link):
    def run(cmd: GraspCommand) -> str:
        try:
            link.send_grasp(cmd, timeout_s=5.0)
        except CommandRejected as exc:
            return exc.reason.name
        return link.wait_outcome(cmd.command_id, 10.0).outcome_class.name

    return run


@pytest.mark.safety_case(abort="e-stop racing a command", link="can",
                         reaction="20 races: every e-stop refuses or aborts the command")
def test_estop_racing_a_command_is_never_lost_on_can(pair, make_cmd):
    p = pair(delay_s=0.5)
    node = p.node()
    estop = lambda: node.send(can_frame(*Encoder().encode(EStopRequest(2))))  # noqa: E731 - a second sender
    fates = _race(_grasp_fate(p.link), estop, p.controller, make_cmd, p.link.new_command_id, tries=20)
    assert set(fates) <= {"ABORTED", "ESTOP"}, fates


@pytest.mark.safety_case(abort="e-stop racing a command", link="zenoh",
                         reaction="20 races: every e-stop refuses or aborts the command")
def test_estop_racing_a_command_is_never_lost_on_zenoh(port, make_cmd):
    import json

    import zenoh

    from field.link import open_link
    from field.link.base import LinkURL
    from field.link.zenoh_backend import ZenohControllerTransport, ZenohKeys, ZenohTarget

    url = f"zenoh://127.0.0.1:{port}/crane-race?insecure=1"
    u = LinkURL.parse(url)
    ctl = CraneController(ControllerConfig(no_journal=True, insecure_link=True), FixedOutcomeExecutor(delay_s=0.5))
    transport = ZenohControllerTransport(ZenohTarget.from_url(u, u.pop_link_config()[1]))
    transport.start(ctl)
    ctl.start()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    second = zenoh.open(conf)  # a second session sends the e-stops
    try:
        with open_link(url, LINK) as link:
            key = ZenohKeys("loggrasp/crane-race").estop
            estop = lambda: second.put(key, Encoder().encode(EStopRequest(2))[1])  # noqa: E731
            fates = _race(_grasp_fate(link), estop, ctl, make_cmd, link.new_command_id, tries=20)
    finally:
        second.close()
        ctl.close()
        transport.close()
    assert set(fates) <= {"ABORTED", "ESTOP"}, fates


@pytest.mark.safety_case(abort="executor stop on abort", link="both",
                         reaction="the pybullet twin stops within one simulation step and reports the log it holds")
def test_pybullet_twin_stops_at_once_and_reports_the_log_it_holds():
    """The twin's executor asks should_abort every simulation step: an abort in the hold phase
    stops the trial there and reports ABORTED with the one log in the air (never 0 logs)."""
    import itertools

    from field.executor import PybulletTrialExecutor
    from synth.geometry.grasp import Grasp
    from synth.scene.pile import Georeference
    from tests.synth.physics.test_trial_abort import one_log_pile

    geo = Georeference(64.1, 20.0, 50.0)
    ex = PybulletTrialExecutor(replace(one_log_pile(), georef=geo))
    cmd = GraspCommand.from_pile_grasp(3, Grasp(0.0, 0.0, 0.0, 0.6), 0.0, geo, 1, time.time())
    assert ex.execute(cmd, lambda: False).outcome_class is OutcomeClass.SUCCESS
    full = ex.last_result
    steps = round((full.sim_time_s - full.phase_s["hold"] / 2) / ex.config.physics.dt_s)
    calls = itertools.count(1)
    out = ex.execute(cmd, lambda: next(calls) >= steps)
    assert out.outcome_class is OutcomeClass.ABORTED and out.logs_grasped == 1
    assert ex.last_result.aborted_in == "hold" and ex.last_result.sim_time_s < full.sim_time_s


# --- 2: a frozen laptop heartbeat -----------------------------------------------------------


class Heartbeats:
    """Feeds laptop heartbeats into a controller every 50 ms from a thread (``frames()`` gives
    the next frame)."""

    def __init__(self, ctl: CraneController, frames):
        self.ctl, self.frames = ctl, frames
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.05):
            self.ctl.on_frame("LaptopHeartbeat", self.frames(), lambda k, d: None)

    def __enter__(self) -> "Heartbeats":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(5)


def _heartbeat_case(make_cmd, frozen: str) -> Outcome:
    """Establish a laptop with good heartbeats, accept a 6 s grasp, then feed ``frozen``
    heartbeats: "none" (good ones go on), "same-frame" or "same-counter" (fresh E2E counter)."""
    ctl = CraneController(ControllerConfig(laptop_timeout_s=1.0, no_journal=True, insecure_link=True), FixedOutcomeExecutor(delay_s=6.0))
    published: list = []
    ctl.attach(lambda k, d: published.append(decode(k, d).message))
    ctl.start()
    enc, hb = Encoder(), [1000]

    def good() -> bytes:
        hb[0] += 1
        return enc.encode(LaptopHeartbeat(hb[0]))[1]

    last = [good()]
    for _ in range(3):
        last[0] = good()
        ctl.on_frame("LaptopHeartbeat", last[0], lambda k, d: None)
    feed = {"none": good, "same-frame": lambda: last[0],
            "same-counter": lambda: enc.encode(LaptopHeartbeat(hb[0]))[1]}[frozen]
    try:
        with Heartbeats(ctl, feed):
            ctl.on_frame(*enc.encode(make_cmd(7)), lambda k, d: None)
            assert wait_until(lambda: outcome_of(published, 7) is not None, timeout_s=15.0)
        return outcome_of(published, 7)
    finally:
        ctl.close()


@pytest.mark.safety_case(abort="laptop heartbeat frozen (stuck sender)", link="can",
                         reaction="the running grasp aborts within the laptop timeout, not at its end")
@pytest.mark.safety_case(error="unintended repetition", link="can",
                         measure="heartbeat counters must advance by 1-8 (application + E2E counter)",
                         reaction="a frozen (repeated) heartbeat stream is not a live laptop: the running grasp is "
                                  "aborted")
@pytest.mark.parametrize("frozen", ["same-frame", "same-counter"])
def test_frozen_laptop_heartbeat_aborts_the_grasp(make_cmd, frozen):
    t0 = time.monotonic()
    out = _heartbeat_case(make_cmd, frozen)
    assert out.outcome_class is OutcomeClass.ABORTED
    assert time.monotonic() - t0 < 5.0  # lost after the 1 s laptop timeout, not at the 6 s end


def test_in_sequence_heartbeats_keep_the_grasp_alive(make_cmd):
    assert _heartbeat_case(make_cmd, "none").outcome_class is OutcomeClass.SUCCESS


# --- 3: answers to corrupted frames, late copies, contradicting answers ----------------------


class CorruptFirstCopy(ProxyBus):
    """Sends every grasp command twice: first a copy with a flipped bit, then the original."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == frame_id("GraspCommand"):
            bad = bytearray(msg.data)
            bad[20] ^= 0x01  # inside the northing: the id bytes are intact
            self.inner.send(can_frame("GraspCommand", bytes(bad)), timeout)
        self.inner.send(msg, timeout)


@pytest.mark.safety_case(error="corruption", link="can",
                         measure="E2E profile: CRC over data id + payload, 4-bit alive counter (CRC): an answer "
                                 "names an id only if the frame passed its check",
                         reaction="a corrupted copy is answered for nobody; the intact command is accepted and runs"
                                  " once")
def test_a_corrupted_copy_does_not_hide_the_intact_one(pair, make_cmd):
    p = pair(laptop_bus=CorruptFirstCopy)
    cmd = make_cmd(p.link.new_command_id())
    assert p.link.send_grasp(cmd, timeout_s=5.0).accepted  # was: "rejected CRC" while the crane ran it
    assert p.link.wait_outcome(cmd.command_id, 10.0).success
    assert p.executor.executed == [cmd.command_id]


def test_a_lost_acceptance_and_a_late_copy_still_read_accepted(pair, make_cmd):
    """The acceptance is lost; another node's frame moves the command counter on; then a late
    copy of the command arrives: it must not draw DUPLICATE_ID for a command that runs."""
    p = pair(delay_s=3.0)
    node, spy = p.node(), p.node()
    p.cbus.arm("drop", "Ack")
    cmd = make_cmd(p.link.new_command_id())
    answer: list = []
    t = threading.Thread(target=lambda: answer.append(_try_send(p.link, cmd)))
    t.start()
    copy = _wait_for_frame(spy, "GraspCommand")
    assert wait_until(lambda: p.executor.executed == [cmd.command_id])
    other = make_cmd(p.link.new_command_id())  # e.g. a second laptop's command, another counter
    node.send(can_frame(*Encoder(first_counter=copy.data[2] + 100).encode(other)))
    node.send(copy)  # the late copy
    t.join(10)
    assert answer == ["accepted"], answer
    assert p.link.wait_outcome(cmd.command_id, 10.0).success
    assert p.executor.executed == [cmd.command_id]


def _try_send(link, cmd) -> str:
    try:
        return "accepted" if link.send_grasp(cmd, timeout_s=8.0).accepted else "?"
    except CommandRejected as exc:
        return exc.reason.name


def _wait_for_frame(bus: can.BusABC, kind: str, timeout_s: float = 10.0) -> can.Message:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = bus.recv(0.1)
        if msg is not None and msg.arbitration_id == frame_id(kind):
            return can_frame(kind, bytes(msg.data))
    raise AssertionError(f"no {kind} frame seen")


@pytest.mark.safety_case(error="unacceptable delay", link="can",
                         measure="acknowledgement timeout, then revocation of the id",
                         reaction="the operator is told it did not run; the late frame is rejected DUPLICATE_ID, "
                                  "never executed")
def test_a_command_delayed_past_its_timeout_never_runs_after_the_operator_was_told_it_did_not(pair, make_cmd):
    """The command frame is held on the way past the acknowledgement timeout: the operator is
    told it does not run, and when the frame finally arrives it must not run (its id was revoked)."""
    p = pair()
    p.lbus.arm("hold", "GraspCommand")
    cmd = make_cmd(p.link.new_command_id())
    fate = p.link.execute(cmd, ack_timeout_s=1.0)
    assert fate.executed is False and "revoked" in fate.summary
    assert p.lbus.release() == 1  # the late frame arrives
    assert wait_until(lambda: (cmd.command_id, RejectReason.DUPLICATE_ID) in p.controller.rejections)
    assert p.executor.executed == []
    assert p.link.fate(cmd.command_id).executed is False


class NullLink(CraneLink):  # no transport: frames are fed by hand
    def _transmit(self, kind, data):
        pass

    def _close_transport(self):
        pass


def test_an_outcome_overrides_a_contradicting_rejection():
    link = NullLink(LinkConfig(insecure=True))
    link._issued.update({55, 56})  # as if it had sent both commands
    enc = Encoder()
    link._deliver(*enc.encode(Ack(55, False, RejectReason.BUSY)))
    link._deliver(*enc.encode(Outcome(55, OutcomeClass.SUCCESS, 2, 990)))
    fate = link.fate(55, query=False)
    assert fate.executed and fate.outcome.outcome_class is OutcomeClass.SUCCESS
    link._deliver(*enc.encode(Ack(56, True)))
    link._deliver(*enc.encode(Ack(56, False, RejectReason.CRC)))  # a contradicting second answer
    assert link.stats.conflicts == 1 and "contradicting" in link.notes[56][0]
    assert link.fate(56, query=False).executed  # the first answer stands; the conflict is on record


# --- 5: burned ids and one staleness limit ---------------------------------------------------


def test_an_id_rejected_busy_stays_burned_across_a_restart(tmp_path, make_cmd):
    cfg = ControllerConfig(journal_path=str(tmp_path / "journal"), insecure_link=True)
    ctl = CraneController(cfg, FixedOutcomeExecutor(delay_s=2.0))
    laptop = SupervisingLaptop(ctl)
    laptop.beat(), laptop.beat()
    enc = laptop.enc
    answers: list = []
    on = lambda k, d: answers.append(decode(k, d).message)  # noqa: E731
    slow, second = make_cmd(1), make_cmd(2)
    ctl.on_frame(*enc.encode(slow), on)
    ctl.on_frame(*enc.encode(second), on)
    assert answers == [Ack(1, True), Ack(2, False, RejectReason.BUSY)]
    ctl.close()
    ex = FixedOutcomeExecutor(delay_s=0.0)
    again = CraneController(cfg, ex)  # restarted from the journal
    again.on_frame(*Encoder().encode(replace(second, plan_timestamp_ms=int(time.time() * 1000))), on)
    assert answers[-1] == Ack(2, False, RejectReason.DUPLICATE_ID) and ex.executed == []
    again.close()


def test_one_staleness_limit_in_seconds_everywhere():
    from field.link.safety import SafetyConfig
    from field.trial import TrialOptions

    limits = {SafetyConfig().max_pile_age_s, ControllerConfig().max_pile_age_s, TrialOptions().max_pile_age_s}
    assert len(limits) == 1 and limits.pop() <= 60.0, limits  # laptop, controller, field trial agree


def test_crane_sim_defaults_journal_every_id_and_use_the_staleness_limit(monkeypatch, tmp_path):
    """``loggrasp crane-sim`` with no --journal burns ids persistently, and with no
    --max-pile-age uses the link's staleness limit."""
    from typer.testing import CliRunner

    import field.controller
    from field.cli import app
    from field.demo import DEMO_DATA

    seen: dict = {}

    def fake_run(link, executor, stop, config, **kw):
        seen["config"] = config
        return field.controller.CraneController(field.controller.ControllerConfig(no_journal=True, insecure_link=True)).status()

    monkeypatch.setattr(field.controller, "run_controller", fake_run)
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    res = CliRunner().invoke(app, ["crane-sim", "--link", "can://virtual/x", "--insecure-link", "--pile",
                                   str(DEMO_DATA / "truth" / "pile.json")])
    assert res.exit_code == 0, res.output
    cfg = seen["config"]
    assert cfg.journal_path is not None and cfg.max_pile_age_s == ControllerConfig().max_pile_age_s


# --- 6: frame format and reserved bytes -----------------------------------------------------


@pytest.mark.safety_case(error="insertion", link="can",
                         measure="only 11-bit CAN FD frames of the DBC are link frames",
                         reaction="an extended-id frame on a link id is ignored on both sides")
@pytest.mark.safety_case(error="addressing", link="can",
                         measure="frame format and id checked (the DBC's VFrameFormat)",
                         reaction="a frame of another protocol on the same ids is not taken as a link frame")
def test_extended_id_frames_are_not_link_frames(pair, make_cmd):
    p = pair()
    p.link._issued.update({777, 778})  # as if the laptop had sent them: answers for its commands
    node = p.node()
    cmd = make_cmd(p.link.new_command_id())
    node.send(can_frame(*p.link._encoder.encode(cmd), extended=True))  # ext. 0x100, next counter
    node.send(can_frame(*Encoder().encode(EStopRequest()), extended=True))  # ext. 0x10
    enc = Encoder()
    node.send(can_frame(*enc.encode(Outcome(777, OutcomeClass.SUCCESS, 2, 990)), extended=True))
    node.send(can_frame(*enc.encode(Outcome(778, OutcomeClass.FEWER, 1, 900))))  # a standard frame after them: once it is in, the others were seen
    assert wait_until(lambda: 778 in p.link._outcomes)
    time.sleep(0.2)  # the controller's notifier runs on its own thread
    assert 777 not in p.link._outcomes
    assert p.executor.executed == [] and p.controller.state is ControllerState.IDLE


def _with_reserved_bit(kind: str, data: bytes, byte: int, mask: int) -> bytes:
    from e2e.p05 import e2e_p05_protect

    from field.link.codec import data_id

    b = bytearray(data)
    b[byte] |= mask
    e2e_p05_protect(b, data_id(kind), increment_counter=False)  # a correct CRC over the bad byte
    return bytes(b)


def test_reserved_bits_are_malformed_on_both_sides(make_cmd):
    ctl = CraneController(ControllerConfig(no_journal=True, insecure_link=True), FixedOutcomeExecutor(delay_s=0.0))
    answers: list = []
    kind, data = Encoder().encode(make_cmd(9))
    ctl.on_frame(kind, _with_reserved_bit(kind, data, 60, 0x01), lambda k, d: answers.append(decode(k, d).message))
    assert answers == [Ack(9, False, RejectReason.MALFORMED)]  # E2E passed: the id may be named
    kind, data = encode(Ack(9, True), 0)
    with pytest.raises(ProtocolError, match="reserved") as ei:
        decode(kind, _with_reserved_bit(kind, data, 8, 0x02))  # bit 65 of the Ack is reserved
    assert ei.value.reason is RejectReason.MALFORMED
    ctl.close()


# --- 8: the commanding laptop --------------------------------------------------------------


@pytest.mark.safety_case(abort="commanding laptop lost, another alive", link="can",
                         reaction="the grasp aborts")
@pytest.mark.safety_case(error="loss", link="can",
                         measure="heartbeat stream of the commanding laptop supervised",
                         reaction="the grasp aborts when its laptop is lost, whoever else is alive")
def test_losing_the_commanding_laptop_aborts_although_another_one_is_alive(pair, make_cmd):
    p = pair(delay_s=6.0)
    other = CanLink(config=LINK, bus=can.Bus(interface="virtual", channel=p.channel, fd=True))
    try:
        other._await_controller()
        cmd = make_cmd(p.link.new_command_id())
        assert p.link.send_grasp(cmd, timeout_s=5.0).accepted
        t0 = time.monotonic()
        p.lbus.arm("drop", "LaptopHeartbeat", count=None)  # the commanding laptop goes quiet
        out = p.link.wait_outcome(cmd.command_id, 15.0)
        assert out.outcome_class is OutcomeClass.ABORTED and time.monotonic() - t0 < 5.0
    finally:
        other.close()


def test_a_second_laptop_is_reported(pair, caplog):
    p = pair()
    other = CanLink(config=LINK, bus=can.Bus(interface="virtual", channel=p.channel, fd=True))
    try:
        other._await_controller()
        assert wait_until(lambda: p.link.status().laptops == 2)
        assert any("second laptop" in r.getMessage() for r in caplog.records)
    finally:
        other.close()
    assert wait_until(lambda: p.link.status().laptops == 1)  # it went: one again after the timeout


@pytest.mark.safety_case(abort="commanding laptop lost, another alive", link="zenoh",
                         reaction="the grasp aborts")
@pytest.mark.safety_case(error="loss", link="zenoh",
                         measure="liveliness token of the commanding laptop",
                         reaction="the grasp aborts when its laptop's token goes, whoever else is connected")
def test_commanding_zenoh_laptop_leaving_aborts_while_another_is_connected(port, controller_process, make_cmd):
    from field.link import open_link

    url = f"zenoh://127.0.0.1:{port}/crane-c?insecure=1"
    controller_process(url, executor={"delay_by_target_logs": {"9": 6.0}})
    with open_link(url, LINK) as watcher:
        with open_link(url, LINK) as commander:
            slow = make_cmd(commander.new_command_id(), logs=9)
            assert commander.send_grasp(slow, timeout_s=5.0).accepted
        t0 = time.monotonic()  # the commanding laptop left; the watcher stays
        assert wait_until(lambda: (watcher.status().last_outcome or Outcome(0, 0, 0, 0)).command_id == slow.command_id)
        assert watcher.status().last_outcome.outcome_class is OutcomeClass.ABORTED
        assert time.monotonic() - t0 < 5.0
