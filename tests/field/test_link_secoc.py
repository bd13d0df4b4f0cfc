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
from field.errors import AuthenticationError, ControllerError, KeyFileError, LinkError
from field.link import ControllerState, OutcomeClass, RejectReason, open_link
from field.link.base import LinkConfig, LinkURL
from field.link.can_backend import CanControllerTransport, CanLink
from field.link.codec import EStopRequest, Encoder, LaptopHeartbeat, StatusRequest, decode, frame_id
from field.link.messages import Ack, ControllerStatus, Outcome
from field.link.secoc import SecOC, generate_key_file, load_key, secured_length
from tests.field.conftest import signing_key_of
from tests.field.helpers import wait_until
from tests.field.test_link_codec import MESSAGES

LINK = LinkConfig(heartbeat_timeout_s=1.0, status_timeout_s=1.0, connect_timeout_s=10.0)


@pytest.fixture
def key(tmp_path):
    """A SecOC key, and beside it the crane's signing key pair (``signing_key_of``; + .pub)."""
    from field.link.signing import generate_signing_key
    from tests.field.conftest import signing_key_of

    path = generate_key_file(tmp_path / "link.key")
    generate_signing_key(signing_key_of(path))
    return path


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

    def make(delay_s: float = 0.05, laptop_key=None, connect_timeout_s: float = LINK.connect_timeout_s):
        channel = f"secoc-{uuid.uuid4().hex[:8]}"
        ex = FixedOutcomeExecutor(delay_s=delay_s)
        ctl = CraneController(ControllerConfig(secoc_key_path=str(key), signing_key_path=str(signing_key_of(key)),
                                               no_journal=True), ex)
        tr = CanControllerTransport(bus=can.Bus(interface="virtual", channel=channel, fd=True))
        tr.start(ctl)
        ctl.start()
        rogue = can.Bus(interface="virtual", channel=channel, fd=True)
        made.append((ctl, tr, rogue))
        cfg = replace(LINK, secoc_key_path=str(laptop_key or key), crane_key_path=f"{signing_key_of(key)}.pub",
                      connect_timeout_s=connect_timeout_s)
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
    """What the link does NOT guarantee without keys (insecure=1): E2E is integrity, not origin -
    a forged outcome for a command the laptop did send is believed."""
    channel = f"nokey-{uuid.uuid4().hex[:8]}"
    rogue = can.Bus(interface="virtual", channel=channel, fd=True)
    link = CanLink(config=LinkConfig(require_controller=False, insecure=True), bus=can.Bus(interface="virtual", channel=channel, fd=True))
    try:
        link._issued.add(99)  # as if it had sent command 99
        rogue.send(frame(*Encoder().encode(Outcome(99, OutcomeClass.SUCCESS, 3, 999))))
        assert wait_until(lambda: 99 in link._outcomes)
    finally:
        link.close()
        rogue.shutdown()


@pytest.mark.safety_case(error="insertion", link="can", measure="the laptop takes answers only for command ids it sent",
                         reaction="dropped and counted (stats.foreign_answers), never a decision")
def test_answers_to_command_ids_the_laptop_never_sent_are_dropped_and_counted():
    """An acknowledgement or outcome naming an id this laptop never issued is never taken for a
    decision (even without keys): dropped and counted in ``stats.foreign_answers``."""
    channel = f"foreign-{uuid.uuid4().hex[:8]}"
    rogue = can.Bus(interface="virtual", channel=channel, fd=True)
    link = CanLink(config=LinkConfig(require_controller=False, insecure=True), bus=can.Bus(interface="virtual", channel=channel, fd=True))
    try:
        enc = Encoder()
        rogue.send(frame(*enc.encode(Ack(77, True))))
        rogue.send(frame(*enc.encode(Outcome(77, OutcomeClass.SUCCESS, 3, 999))))
        assert wait_until(lambda: link.stats.foreign_answers == 2)
        assert 77 not in link._answers and 77 not in link._outcomes
        assert link.fate(77, query=False).executed is not True
    finally:
        link.close()
        rogue.shutdown()


@pytest.mark.safety_case(error="insertion", link="both", measure="authenticated frames by default",
                         reaction="a link or controller without a key is refused unless insecure=1 / --insecure-link")
def test_a_link_without_a_key_is_refused_unless_the_operator_opts_out():
    with pytest.raises(LinkError, match="no SecOC key.*insecure=1"):
        open_link("can://virtual/no-key-ch")
    with pytest.raises(ControllerError, match="needs a SecOC key"):
        CraneController(ControllerConfig(no_journal=True), FixedOutcomeExecutor())
    assert LinkURL.parse("can://virtual/x?insecure=1").pop_link_config()[0].insecure
    with open_link("twin://") as twin:  # a private in-process bus needs none, and says so
        assert not twin.authenticated


@pytest.mark.safety_case(keys="both ends need the same key", link="can",
                         reaction="a crane with another key is not reached: the link refuses to open")
@pytest.mark.safety_case(error="masquerade", link="can",
                         measure="SecOC-style MAC (HMAC-SHA256/64 over id, frame, freshness) with the pre-shared "
                                 "key",
                         reaction="a crane with another key is not reached: the link refuses to open")
def test_a_crane_with_another_key_is_not_reached(keyed_pair, tmp_path):
    link, *_ = keyed_pair(laptop_key=generate_key_file(tmp_path / "wrong.key"), connect_timeout_s=2.0)
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


@pytest.mark.safety_case(keys="MAC failures counted; past a threshold the controller goes to a safe state", link="both",
                         reaction="FAULT: commands refused, the running grasp aborted, local reset")
def test_mac_failures_past_the_threshold_put_the_controller_in_its_safe_state(key, tmp_path, make_cmd):
    """More than ``max_mac_failures`` frames with a bad MAC within the window: FAULT - the running
    grasp aborts and commands are refused until a local reset. Stale frames (a clock, a replay)
    do not count."""
    ex = FixedOutcomeExecutor(delay_s=5.0)
    ctl = CraneController(ControllerConfig(secoc_key_path=str(key), signing_key_path=str(signing_key_of(key)),
                                           no_journal=True, max_mac_failures=3), ex)
    published: list = []
    ctl.attach(lambda k, d: published.append(k))
    ctl.start()
    laptop = SecOC.from_key_file(key)
    forger = SecOC.from_key_file(generate_key_file(tmp_path / "forger.key"))
    enc, hb, acks = Encoder(), [100], []
    on = lambda k, d: acks.append(decode(k, laptop.verify(k, d[:secured_length(k)])).message)  # noqa: E731

    def beat() -> None:
        hb[0] += 1
        ctl.on_frame("LaptopHeartbeat", laptop.secure(*enc.encode(LaptopHeartbeat(hb[0]))), on)

    try:
        beat(), beat()
        ctl.on_frame("GraspCommand", laptop.secure(*enc.encode(make_cmd(5))), on)
        assert acks[-1].accepted
        stale = SecOC.from_key_file(key, clock=lambda: time.time() - 60).secure(*Encoder().encode(StatusRequest(1)))
        for _ in range(10):
            ctl.on_frame("StatusRequest", stale, on)  # stale, not forged: no fault
        assert ctl.state is ControllerState.EXECUTING
        for i in range(4):  # forged: the 4th passes the limit of 3
            beat()
            ctl.on_frame("StatusRequest", forger.secure(*Encoder().encode(StatusRequest(i + 1))), on)
        assert ctl.state is ControllerState.FAULT and "failed their MAC" in ctl.fault_cause
        assert wait_until(lambda: ctl._run is None) and ex.aborted == [5]
        beat()
        ctl.on_frame("GraspCommand", laptop.secure(*enc.encode(make_cmd(6))), on)
        assert acks[-1] == Ack(6, False, RejectReason.FAULT)
    finally:
        ctl.close()


# --- key ids (rotation) and per-direction keys ------------------------------------------------


def _key_file(path, lines: list[str]):
    path.write_text("".join(f"{ln}\n" for ln in lines))
    os.chmod(path, 0o600)
    return path


@pytest.mark.safety_case(keys="key ids in the frames (rotation without downtime)", link="both",
                         reaction="both keys accepted during the overlap; a key id not held is dropped")
def test_a_rotated_key_id_is_accepted_during_the_overlap(tmp_path):
    """Step 2 of a rotation: the laptop already sends with key 2, the crane still with key 1; both
    hold both, so every frame passes in both directions. A node that holds only key 1 drops a
    frame made with key 2 (its key id is unknown there), and says so."""
    old, new = os.urandom(32).hex(), os.urandom(32).hex()
    laptop = SecOC.from_key_file(_key_file(tmp_path / "laptop.key", [f"2 {new}", f"1 {old}"]))
    crane = SecOC.from_key_file(_key_file(tmp_path / "crane.key", [f"1 {old}", f"2 {new}"]))
    stale_node = SecOC.from_key_file(_key_file(tmp_path / "old.key", [f"1 {old}"]))
    cmd_kind, cmd = Encoder().encode(StatusRequest(7))
    ack_kind, ack = Encoder().encode(Ack(7, True))
    assert laptop.key_id == 2 and crane.key_id == 1
    assert crane.verify(cmd_kind, laptop.secure(cmd_kind, cmd)) == cmd  # sent with the new key
    assert laptop.verify(ack_kind, crane.secure(ack_kind, ack)) == ack  # answered with the old one
    with pytest.raises(AuthenticationError, match="key id 2") as info:
        stale_node.verify(cmd_kind, laptop.secure(cmd_kind, cmd))
    assert info.value.check == "key_id"
    assert load_key(tmp_path / "laptop.key") == bytes.fromhex(new)  # the sending key is the first


@pytest.mark.safety_case(keys="one MAC key per direction, derived from the key file", link="both",
                         reaction="a MAC made for one direction is not the other's")
def test_the_two_directions_use_different_mac_keys_from_one_file(key):
    """Per-direction keys (derived from the file's key): a MAC computed for a laptop -> crane frame
    is not the MAC of the same bytes crane -> laptop. (Frame ids already differ per kind; this
    keeps the directions apart even if a kind's id were reused. It does not stop a holder of the
    file from making crane frames: see docs/link-safety.md.)"""
    secoc = SecOC.from_key_file(key)
    fv = (int(time.time() * 1000) << 16).to_bytes(8, "little")
    from field.link.secoc import _direction_key

    raw = load_key(key)
    assert _direction_key(raw, "laptop->crane") != _direction_key(raw, "crane->laptop") != raw
    assert secoc._keys[(0, "laptop->crane")] == _direction_key(raw, "laptop->crane")
    assert secoc._mac("StatusRequest", b"pdu", fv) != secoc._mac("CraneHeartbeat", b"pdu", fv)
