"""Authenticated frames (defect 7): a MAC and a freshness value on every frame, a pre-shared key
from a file only its owner can read; forged, replayed and late frames are dropped."""

from __future__ import annotations

import logging
import os
import time
import uuid
from dataclasses import replace

import can
import pytest

from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
from field.errors import AuthenticationError, KeyFileError, LinkError
from field.link import ControllerState, OutcomeClass, open_link
from field.link.base import LinkConfig
from field.link.can_backend import CanControllerTransport, CanLink
from field.link.codec import EStopRequest, Encoder, decode, frame_id
from field.link.messages import ControllerStatus, Outcome
from field.link.secoc import SecOC, generate_key_file, load_key, secured_length
from tests.field.helpers import wait_until
from tests.field.test_link_codec import MESSAGES

LINK = LinkConfig(heartbeat_timeout_s=1.0, status_timeout_s=1.0, connect_timeout_s=10.0)


@pytest.fixture
def key(tmp_path):
    return generate_key_file(tmp_path / "link.key")


def frame(kind: str, data: bytes) -> can.Message:
    return can.Message(arbitration_id=frame_id(kind), is_extended_id=False, is_fd=True, data=data, check=True)


# --- the frame format -----------------------------------------------------------------------


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_secured_round_trip_every_frame(key, msg):
    tx, rx = SecOC.from_key_file(key), SecOC.from_key_file(key)
    kind, data = Encoder().encode(msg)
    secured = tx.secure(kind, data)
    assert len(secured) == secured_length(kind) <= 64
    assert decode(kind, rx.verify(kind, secured)).message == msg


@pytest.mark.safety_case(error="corruption", link="both",
                         measure="SecOC-style MAC (HMAC-SHA256/64 over id, frame, freshness) with the pre-shared "
                                 "key",
                         reaction="every bit flip of an authenticated frame fails its MAC: dropped")
def test_every_bit_flip_fails_authentication(key):
    tx, rx = SecOC.from_key_file(key), SecOC.from_key_file(key)
    kind, data = Encoder().encode(MESSAGES[0])
    secured = tx.secure(kind, data)
    for i in range(len(secured) * 8):
        bad = bytearray(secured)
        bad[i // 8] ^= 1 << (i % 8)
        with pytest.raises(AuthenticationError):
            rx.verify(kind, bytes(bad))


@pytest.mark.safety_case(error="unintended repetition", link="both",
                         measure="SecOC-style MAC (HMAC-SHA256/64 over id, frame, freshness) with the pre-shared "
                                 "key: freshness value seen before",
                         reaction="a replayed authenticated frame is dropped")
@pytest.mark.safety_case(error="unacceptable delay", link="both",
                         measure="SecOC-style MAC (HMAC-SHA256/64 over id, frame, freshness) with the pre-shared "
                                 "key: freshness window 2 s",
                         reaction="a frame 5 s old is dropped")
@pytest.mark.safety_case(error="masquerade", link="both",
                         measure="SecOC-style MAC (HMAC-SHA256/64 over id, frame, freshness) with the pre-shared "
                                 "key",
                         reaction="a frame made with another key, or without one, is dropped")
def test_replayed_late_and_foreign_frames_fail(key, tmp_path):
    rx = SecOC.from_key_file(key)
    kind, data = Encoder().encode(MESSAGES[0])
    secured = SecOC.from_key_file(key).secure(kind, data)
    rx.verify(kind, secured)
    with pytest.raises(AuthenticationError, match="seen before"):
        rx.verify(kind, secured)  # a replay (or a bus-level duplicate)
    late = SecOC.from_key_file(key, clock=lambda: time.time() - 5.0).secure(kind, data)  # 5 s old
    with pytest.raises(AuthenticationError, match="freshness"):
        rx.verify(kind, late)
    other = SecOC.from_key_file(generate_key_file(tmp_path / "other.key")).secure(kind, data)
    with pytest.raises(AuthenticationError, match="MAC"):
        rx.verify(kind, other)
    with pytest.raises(AuthenticationError, match="MAC"):
        rx.verify(kind, data)  # a plain grasp command (64 bytes either way)
    kind, data = Encoder().encode(MESSAGES[1])
    with pytest.raises(AuthenticationError, match="without the key"):
        rx.verify(kind, data)  # a plain 16-byte Ack where a 32-byte authenticated one is expected


# --- the key file ---------------------------------------------------------------------------


@pytest.mark.safety_case(keys="key file rules", link="both",
                         reaction="a missing, short or group/other-readable key file is refused with the fix (chmod"
                                  " 600)")
def test_key_file_rules(tmp_path):
    path = generate_key_file(tmp_path / "k")
    assert os.stat(path).st_mode & 0o777 == 0o600 and len(load_key(path)) == 32
    with pytest.raises(KeyFileError, match="never overwritten"):
        generate_key_file(path)
    os.chmod(path, 0o644)
    with pytest.raises(KeyFileError, match="chmod 600") as ei:
        load_key(path)
    assert str(path) in str(ei.value)
    with pytest.raises(KeyFileError, match="cannot be read"):
        load_key(tmp_path / "missing")
    short = tmp_path / "short"
    short.write_text("00ff\n")
    os.chmod(short, 0o600)
    with pytest.raises(KeyFileError, match="at least"):
        load_key(short)
    with pytest.raises(KeyFileError, match="chmod 600"):  # refused at link open, before any frame
        open_link(f"twin://?secoc_key={path}")


@pytest.mark.safety_case(keys="the key is never shown", link="both",
                         reaction="no log line, message or repr holds the key")
def test_the_key_is_never_logged_or_shown(key, caplog, make_cmd):
    secret = key.read_text().strip()
    caplog.set_level(logging.DEBUG)
    with open_link(f"twin://?delay_ms=10&secoc_key={key}") as link:
        assert secret not in repr(link._secoc) and secret not in repr(link.config)
        cmd = make_cmd(link.new_command_id())
        link.send_grasp(cmd, timeout_s=5.0)
        link.wait_outcome(cmd.command_id, 10.0)
    assert all(secret not in r.getMessage() for r in caplog.records)


# --- a keyed link ---------------------------------------------------------------------------


@pytest.fixture
def keyed_pair(key):
    """A CAN pair with the same key on both ends, and a rogue node without it."""
    made = []

    def make(delay_s: float = 0.05, laptop_key=None):
        channel = f"secoc-{uuid.uuid4().hex[:8]}"
        ex = FixedOutcomeExecutor(delay_s=delay_s)
        ctl = CraneController(ControllerConfig(secoc_key_path=str(key)), ex)
        tr = CanControllerTransport(bus=can.Bus(interface="virtual", channel=channel, fd=True))
        tr.start(ctl)
        ctl.start()
        rogue = can.Bus(interface="virtual", channel=channel, fd=True)
        made.append((ctl, tr, rogue))
        cfg = replace(LINK, secoc_key_path=str(laptop_key or key))
        link = CanLink(config=cfg, bus=can.Bus(interface="virtual", channel=channel, fd=True))
        made.append((link,))
        return link, ctl, ex, rogue

    yield make
    for items in made:
        for obj in items:
            (obj.shutdown if isinstance(obj, can.BusABC) else obj.close)()


@pytest.mark.safety_case(error="insertion", link="can",
                         measure="SecOC-style MAC (HMAC-SHA256/64 over id, frame, freshness) with the pre-shared "
                                 "key",
                         reaction="E2E-valid frames inserted without the MAC (outcome, status, a command with the "
                                  "laptop's next counter) are dropped on both sides; never run")
@pytest.mark.safety_case(error="masquerade", link="can",
                         measure="SecOC-style MAC (HMAC-SHA256/64 over id, frame, freshness) with the pre-shared "
                                 "key",
                         reaction="a keyless node posing as the crane or the laptop is not believed; the real "
                                  "outcome stands")
def test_forged_frames_are_dropped_on_both_sides(keyed_pair, make_cmd):
    link, ctl, ex, rogue = keyed_pair(delay_s=2.0)
    link._await_controller()
    cmd = make_cmd(link.new_command_id())
    assert link.send_grasp(cmd, timeout_s=5.0).accepted
    enc = Encoder()
    # a forged "success" for the running command: E2E-valid, no MAC
    rogue.send(frame(*enc.encode(Outcome(cmd.command_id, OutcomeClass.SUCCESS, 2, 999))))
    rogue.send(frame(*enc.encode(ControllerStatus(ControllerState.DONE, 0, 1, Outcome(cmd.command_id, 0, 2, 999)))))
    assert wait_until(lambda: link.stats.auth_failures >= 2)
    assert cmd.command_id not in link._outcomes
    # a forged command with the laptop's own next counter: dropped, never answered or run
    forged = make_cmd(link.new_command_id())
    rogue.send(frame(*link._encoder.encode(forged)))
    assert wait_until(lambda: ctl.auth_failures >= 1)
    out = link.wait_outcome(cmd.command_id, 10.0)  # the real outcome, from the crane
    assert out.outcome_class is OutcomeClass.SUCCESS and out.balance_cos_milli == 985
    assert ex.executed == [cmd.command_id] and not ctl.seen(forged.command_id)
    # fail-safe: an e-stop frame stops the crane even without a valid MAC
    rogue.send(frame(*enc.encode(EStopRequest())))
    assert wait_until(lambda: ctl.state is ControllerState.ESTOP)


@pytest.mark.safety_case(gap="CAN without keys: integrity, not origin", link="can",
                         reaction="a forged, E2E-valid SUCCESS outcome is believed by a keyless laptop")
def test_without_keys_a_forged_outcome_is_believed(make_cmd):
    """What the link does NOT guarantee without keys: E2E is integrity, not origin."""
    channel = f"nokey-{uuid.uuid4().hex[:8]}"
    rogue = can.Bus(interface="virtual", channel=channel, fd=True)
    link = CanLink(config=LinkConfig(require_controller=False), bus=can.Bus(interface="virtual", channel=channel, fd=True))
    try:
        rogue.send(frame(*Encoder().encode(Outcome(99, OutcomeClass.SUCCESS, 3, 999))))
        assert wait_until(lambda: 99 in link._outcomes)
    finally:
        link.close()
        rogue.shutdown()


@pytest.mark.safety_case(keys="both ends need the same key", link="can",
                         reaction="a crane with another key is not reached: the link refuses to open")
@pytest.mark.safety_case(error="masquerade", link="can",
                         measure="SecOC-style MAC (HMAC-SHA256/64 over id, frame, freshness) with the pre-shared "
                                 "key",
                         reaction="a crane with another key is not reached: the link refuses to open")
def test_a_crane_with_another_key_is_not_reached(keyed_pair, tmp_path):
    link, *_ = keyed_pair(laptop_key=generate_key_file(tmp_path / "wrong.key"))
    with pytest.raises(LinkError, match="SecOC key"):
        link._await_controller()


def test_twin_and_recording_with_a_key(key, tmp_path, make_cmd):
    from field.link.can_backend import decode_recording

    rec = tmp_path / "s.blf"
    with open_link(f"twin://?delay_ms=10&secoc_key={key}&record={rec}") as link:
        cmd = make_cmd(link.new_command_id())
        assert link.send_grasp(cmd, timeout_s=5.0).accepted
        assert link.wait_outcome(cmd.command_id, 10.0).success
        assert link.controller.auth_failures == 0 and link.stats.auth_failures == 0
    msgs = [m for _, _, m in decode_recording(rec, secoc_key=key)]
    assert cmd in msgs  # a keyed recording reads back with its key (MACs checked)
