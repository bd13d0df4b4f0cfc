"""Every controller check on its own, at its boundaries: width, height window, staleness, future
skew, heading, reach, target count (pure functions), then duplicate and burned ids (the
controller)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from field.controller import (
    ControllerConfig,
    CraneController,
    FixedOutcomeExecutor,
    ReachEnvelope,
    check_age,
    check_command,
    check_heading,
    check_reach,
    check_target_count,
    check_width,
)
from field.link.codec import Encoder, decode
from field.link.messages import Ack, GraspCommand, RejectReason
from tests.field.helpers import SupervisingLaptop

NOW_S = 1_800_000_000.0  # a fixed crane clock [s]
CFG = ControllerConfig()
R = CFG.reach
OK = RejectReason.NONE


def cmd(*, de_mm: int = 5000, dn_mm: int = 0, dz_mm: int = 0, heading: int = 3000, width: int = 900, logs: int = 2,
        age_ms: int = 0, command_id: int = 1) -> GraspCommand:
    """A command relative to the default crane base, valid unless a field is moved."""
    return GraspCommand(command_id, int(R.base_easting_m * 1000) + de_mm, int(R.base_northing_m * 1000) + dn_mm,
                        int(R.base_height_m * 1000) + dz_mm, heading, width, logs, int(NOW_S * 1000) - age_ms)


@pytest.mark.parametrize("width, reason", [(299, RejectReason.WIDTH_RANGE), (300, OK), (1550, OK),
                                           (1551, RejectReason.WIDTH_RANGE), (0, RejectReason.WIDTH_RANGE)])
def test_width(width, reason):
    assert check_width(cmd(width=width), CFG) is reason


@pytest.mark.parametrize("dz_mm, reason", [(-6001, RejectReason.OUT_OF_REACH), (-6000, OK), (0, OK), (3000, OK),
                                           (3001, RejectReason.OUT_OF_REACH)])
def test_height_window(dz_mm, reason):
    c = cmd(dz_mm=dz_mm)
    assert R.horizontal_ok(c)  # only the height is at stake
    assert check_reach(c, CFG) is reason
    assert R.height_ok(c) is (reason is OK)


@pytest.mark.parametrize("age_ms, reason", [(30_001, RejectReason.STALE), (30_000, OK), (0, OK)])
def test_staleness(age_ms, reason):
    assert check_age(cmd(age_ms=age_ms), CFG, NOW_S) is reason


@pytest.mark.parametrize("ahead_ms, reason", [(2_001, RejectReason.STALE), (2_000, OK), (1, OK)])
def test_future_skew(ahead_ms, reason):
    assert check_age(cmd(age_ms=-ahead_ms), CFG, NOW_S) is reason


def test_staleness_limits_are_the_config_s():
    tight = ControllerConfig(max_pile_age_s=1.0, max_future_skew_s=0.0)
    assert check_age(cmd(age_ms=1_001), tight, NOW_S) is RejectReason.STALE
    assert check_age(cmd(age_ms=-1), tight, NOW_S) is RejectReason.STALE
    assert check_age(cmd(age_ms=0), tight, NOW_S) is OK


@pytest.mark.parametrize("heading, reason", [(0, OK), (17999, OK), (18000, RejectReason.HEADING_RANGE),
                                             (35999, RejectReason.HEADING_RANGE)])
def test_heading(heading, reason):
    assert check_heading(cmd(heading=heading), CFG) is reason


def test_heading_window_is_configurable():
    cfg = ControllerConfig(min_heading_cdeg=1000, max_heading_cdeg=2000)
    assert [check_heading(cmd(heading=h), cfg) for h in (999, 1000, 2000, 2001)] == [
        RejectReason.HEADING_RANGE, OK, OK, RejectReason.HEADING_RANGE]


@pytest.mark.parametrize("de_mm, dn_mm, reason", [
    (1999, 0, RejectReason.OUT_OF_REACH), (2000, 0, OK), (10_000, 0, OK), (10_001, 0, RejectReason.OUT_OF_REACH),
    (0, -9_999, OK), (7_000, 7_000, OK), (8_000, 8_000, RejectReason.OUT_OF_REACH),  # 9.9 m / 11.3 m diagonal
])
def test_reach(de_mm, dn_mm, reason):
    c = cmd(de_mm=de_mm, dn_mm=dn_mm)
    assert R.height_ok(c)  # only the horizontal reach is at stake
    assert check_reach(c, CFG) is reason


@pytest.mark.parametrize("logs, reason", [(0, RejectReason.MALFORMED), (1, OK), (12, OK), (13, RejectReason.MALFORMED)])
def test_target_count(logs, reason):
    assert check_target_count(cmd(logs=logs), CFG) is reason


def test_first_failing_check_wins():
    bad = cmd(age_ms=60_000, width=10, heading=20000, logs=0, de_mm=50_000)
    assert check_command(bad, CFG, NOW_S) is RejectReason.STALE
    assert check_command(replace(bad, plan_timestamp_ms=int(NOW_S * 1000)), CFG, NOW_S) is RejectReason.WIDTH_RANGE
    assert check_command(cmd(), CFG, NOW_S) is OK
    assert ReachEnvelope().contains(cmd())


# --- ids: duplicate and burned ---------------------------------------------------------------


class Crane:
    """A controller fed frames like a laptop would (one encoder: counters always in sequence)."""

    def __init__(self):
        self.ex = FixedOutcomeExecutor(delay_s=0.0)
        self.ctl = CraneController(ControllerConfig(no_journal=True, insecure_link=True), self.ex, clock=lambda: NOW_S)
        self.laptop = SupervisingLaptop(self.ctl)  # a heartbeat before each command: supervised
        self.enc = self.laptop.enc
        self.laptop.beat()

    def send(self, c: GraspCommand, data: bytes | None = None) -> Ack:
        out: list = []
        self.laptop.beat()
        kind, frame = self.enc.encode(c)
        self.ctl.on_frame(kind, frame if data is None else data, lambda k, d: out.append(decode(k, d).message))
        if self.ctl._worker is not None:
            self.ctl._worker.join(5)
        (ack,) = out
        return ack

    def close(self):
        self.ctl.close()


@pytest.fixture
def crane():
    c = Crane()
    yield c
    c.close()


def test_an_executed_id_is_never_run_again(crane):
    assert crane.send(cmd(command_id=5)).accepted
    assert crane.send(cmd(command_id=5)) == Ack(5, True)  # an identical copy: the same answer, no run
    assert crane.send(cmd(command_id=5, width=800)) == Ack(5, False, RejectReason.DUPLICATE_ID)
    assert crane.ex.executed == [5]


def test_a_rejected_id_is_burned(crane):
    assert crane.send(cmd(command_id=6, width=10)) == Ack(6, False, RejectReason.WIDTH_RANGE)
    assert crane.send(cmd(command_id=6)) == Ack(6, False, RejectReason.DUPLICATE_ID)  # now valid, still refused
    assert crane.send(cmd(command_id=6, width=10)) == Ack(6, False, RejectReason.WIDTH_RANGE)  # its own answer
    assert crane.ex.executed == [] and crane.ctl.seen(6)


def test_a_frame_that_failed_its_crc_burns_nothing(crane):
    c = cmd(command_id=7)
    kind, frame = Encoder().encode(c)
    bad = bytearray(frame)
    bad[30] ^= 0x40
    assert crane.send(c, bytes(bad)) == Ack(0, False, RejectReason.CRC)  # answered for nobody
    assert not crane.ctl.seen(7)
    assert crane.send(c).accepted  # the intact frame is the first the controller saw of id 7


def test_id_zero_is_malformed(crane):
    from e2e.p05 import e2e_p05_protect

    from field.link.codec import data_id

    kind, frame = crane.enc.encode(cmd(command_id=1))
    zero = bytearray(frame)
    zero[4:8] = bytes(4)  # id 0 (the encoder refuses it: the DBC range starts at 1)
    e2e_p05_protect(zero, data_id(kind), increment_counter=False)
    assert crane.send(cmd(command_id=2), bytes(zero)) == Ack(0, False, RejectReason.MALFORMED)
    assert crane.ex.executed == []
