"""Signed crane answers (issue 39): a holder of a laptop's key file - its SecOC key and the
crane's public key - cannot make a crane frame the laptop accepts, on CAN and on Zenoh; a
signature made for another frame is refused; a frame whose signature never comes is never acted
on (a lost frame for every path above it); the keys are refused when they are the wrong ones."""

from __future__ import annotations

import json
import os
import secrets
import time
import uuid
from dataclasses import replace

import can
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
from field.errors import CommandRejected, ControllerError, KeyFileError, LinkError
from field.link import ControllerState, OutcomeClass, RejectReason, open_link
from field.link.base import LinkConfig
from field.link.can_backend import make_frame
from field.link.codec import SIGNATURE_KIND, CraneHeartbeat, Encoder, decode
from field.link.messages import Ack, ControllerStatus, Outcome
from field.link.secoc import SecOC, generate_key_file
from field.link.signing import (
    SIG_BYTES,
    AnswerCheck,
    AnswerSigner,
    AnswerVerifier,
    carriage_frames,
    generate_signing_key,
    load_public_key,
    load_signing_key,
)
from tests.field.conftest import free_port
from tests.field.helpers import can_pairs, wait_until

LINK = LinkConfig(heartbeat_timeout_s=1.0, status_timeout_s=1.0, connect_timeout_s=10.0)


@pytest.fixture
def keys(tmp_path):
    """(SecOC key file, crane signing key, crane public key): one crane's keys."""
    key = generate_key_file(tmp_path / "link.key")
    sign, pub = generate_signing_key(tmp_path / "crane.sign")
    return key, sign, pub


class LaptopKeyHolder:
    """Whoever holds a laptop's key file: the SecOC key (so the crane -> laptop MAC comes out
    right) and the crane's PUBLIC key - but not the crane's signing key. Its best forgeries carry
    random bytes or a signature by an Ed25519 key of its own."""

    def __init__(self, key_path):
        self.secoc = SecOC.from_key_file(key_path)
        self.enc = Encoder(first_counter=200)
        self.own = AnswerSigner(Ed25519PrivateKey.generate(), "the forger's own key")

    def forge(self, msg, how: str = "own key") -> tuple[str, bytes]:
        kind, plain = self.enc.encode(msg)
        secured = self.secoc.secure(kind, plain)
        signature = self.own.sign(kind, secured) if how == "own key" else secrets.token_bytes(SIG_BYTES)
        return kind, secured + signature


@pytest.fixture
def signed_pairs(keys):
    key, sign, pub = keys
    # a signature frame may wait 2 s for its held-back data frame (a slow test machine)
    with can_pairs("signed", replace(LINK, secoc_key_path=str(key), crane_key_path=str(pub),
                                     signature_wait_s=2.0)) as make:
        yield lambda **kw: make(secoc_key_path=str(key), signing_key_path=str(sign), **kw)


def send_on_can(bus, kind: str, data: bytes) -> None:
    for k, frame in carriage_frames(kind, data):
        bus.send(make_frame(k, frame))


# --- masquerade: a laptop's key file cannot make crane frames --------------------------------


@pytest.mark.safety_case(error="masquerade", link="can",
                         measure="crane -> laptop frames signed (Ed25519, a key only the crane holds; the signature "
                                 "frame after each data frame), verified with the crane's public key",
                         reaction="a holder of a laptop's key file (SecOC key + crane public key) forges an "
                                  "acknowledgement, outcome and status with the right MAC: not believed, counted; "
                                  "the crane's real answers stand")
def test_a_laptop_key_file_cannot_make_crane_answers_on_can(signed_pairs, keys, make_cmd):
    p = signed_pairs(delay_s=2.0)
    link, forger = p.link, LaptopKeyHolder(keys[0])
    rogue = p.node()
    # a forged acceptance of a command the crane rejects (its real answer held back until the forgery is in)
    wide = make_cmd(link.new_command_id(), width_m=2.0)
    p.cbus.arm("hold", kind="Ack", direction="tx")
    with link._cond:
        link._issued.add(wide.command_id)  # so that a forged answer to it is not dropped as foreign
    p.link._send(*link._wire(wide))
    assert wait_until(lambda: p.controller.seen(wide.command_id))
    failed = link.stats.auth_failures
    send_on_can(rogue, *forger.forge(Ack(wide.command_id, True)))
    send_on_can(rogue, *forger.forge(Ack(wide.command_id, True), how="random"))
    assert wait_until(lambda: link.stats.auth_failures >= failed + 2)
    assert link._decision(wide.command_id) is None  # the forged acceptances were never taken
    p.cbus.release()
    assert wait_until(lambda: link._decision(wide.command_id) is not None)
    assert link._decision(wide.command_id).reason is RejectReason.WIDTH_RANGE
    # a forged SUCCESS outcome and DONE status for a running command
    cmd = make_cmd(link.new_command_id())
    assert link.send_grasp(cmd, timeout_s=5.0).accepted
    failed = link.stats.auth_failures
    send_on_can(rogue, *forger.forge(Outcome(cmd.command_id, OutcomeClass.SUCCESS, 2, 999)))
    send_on_can(rogue, *forger.forge(ControllerStatus(ControllerState.DONE, 0, 1, Outcome(cmd.command_id, 0, 2, 999))))
    send_on_can(rogue, *forger.forge(CraneHeartbeat(7, ControllerState.IDLE), how="random"))
    assert wait_until(lambda: link.stats.auth_failures >= failed + 3)
    assert cmd.command_id not in link._outcomes
    out = link.wait_outcome(cmd.command_id, 10.0)  # the real one, from the crane
    assert out.outcome_class is OutcomeClass.SUCCESS and out.balance_cos_milli == 985
    assert p.executor.executed == [cmd.command_id]


@pytest.mark.safety_case(error="masquerade", link="zenoh",
                         measure="crane -> laptop payloads signed (Ed25519, a key only the crane holds; frame | "
                                 "signature), verified with the crane's public key",
                         reaction="a rogue session holding a laptop's key file answers a command (its own queryable) "
                                  "and puts an outcome and a status with the right MAC: not believed, counted; the "
                                  "crane's real rejection and outcome stand")
def test_a_laptop_key_file_cannot_make_crane_answers_on_zenoh(keys, make_cmd):
    import zenoh

    from field.controller import controller_in_thread
    from field.link.zenoh_backend import ZenohKeys

    key, sign, pub = keys
    port = free_port()
    url = f"zenoh://127.0.0.1:{port}/crane-sig?secoc_key={key}&signing_key={sign}&crane_key={pub}"
    config = ControllerConfig(no_journal=True, laptop_timeout_s=1.0)
    forger, zkeys = LaptopKeyHolder(key), ZenohKeys("loggrasp/crane-sig")
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    with controller_in_thread(url, FixedOutcomeExecutor(delay_s=2.0), config), open_link(url, LINK) as link:
        rogue = zenoh.open(conf)
        try:
            # its own queryable on the command key: it "accepts" every command, with the right MAC
            queryable = rogue.declare_queryable(zkeys.cmd, lambda q: q.reply(
                q.key_expr, forger.forge(Ack(int.from_bytes(bytes(q.payload.to_bytes()[4:8]), "little"), True))[1]))
            time.sleep(0.5)
            wide = make_cmd(link.new_command_id(), width_m=2.0)
            with pytest.raises(CommandRejected) as ei:  # the crane's own answer, beside the forged one
                link.send_grasp(wide, timeout_s=3.0)
            assert ei.value.reason is RejectReason.WIDTH_RANGE
            assert wait_until(lambda: link.stats.auth_failures >= 1)  # the forged acceptance, dropped
            queryable.undeclare()
            cmd = make_cmd(link.new_command_id())
            assert link.send_grasp(cmd, timeout_s=5.0).accepted
            failed = link.stats.auth_failures
            rogue.put(zkeys.outcome, forger.forge(Outcome(cmd.command_id, OutcomeClass.SUCCESS, 2, 999))[1])
            rogue.put(zkeys.status, forger.forge(ControllerStatus(ControllerState.DONE, 0, 1,
                                                                  Outcome(cmd.command_id, 0, 2, 999)), "random")[1])
            assert wait_until(lambda: link.stats.auth_failures >= failed + 2)
            assert cmd.command_id not in link._outcomes
            out = link.wait_outcome(cmd.command_id, 10.0)
            assert out.outcome_class is OutcomeClass.SUCCESS and out.balance_cos_milli == 985
        finally:
            rogue.close()


# --- the CAN carriage: pairing a signature frame with its data frame --------------------------


def _genuine(keys, *msgs):
    """Signed frames (frame | signature) of ``msgs`` as the crane makes them, and a laptop's check."""
    key, sign, pub = keys
    crane = SecOC.from_key_file(key)
    signer, enc = AnswerSigner.from_file(sign), Encoder()
    out = []
    for msg in msgs:
        kind, plain = enc.encode(msg)
        secured = crane.secure(kind, plain)
        out.append((kind, secured, signer.sign(kind, secured)))
    check = AnswerCheck(SecOC.from_key_file(key), AnswerVerifier.from_file(pub), inline=False, wait_s=0.5)
    return out, check


@pytest.mark.safety_case(error="masquerade", link="can",
                         measure="a signature frame verifies only against the data frame it was made for",
                         reaction="a genuine signature frame of another data frame (or of another kind) is refused "
                                  "and counted; the data frame still waits for its own")
def test_a_signature_frame_for_another_data_frame_is_refused(keys):
    (a_kind, a, a_sig), (b_kind, b, b_sig), (o_kind, o, o_sig) = _genuine(keys, Ack(5, True), Ack(6, False, RejectReason.BUSY),
                                                                          Outcome(5, OutcomeClass.SUCCESS, 2, 999))[0]
    check = _genuine(keys)[1]
    assert check.unwrap(a_kind, a) == (None, None)  # held: never acted on before its signature
    plain, why = check.on_signature(a_kind, b_sig)  # the crane's genuine signature - of another Ack
    assert plain is None and why is not None and why.check == "signature"
    plain, why = check.on_signature(a_kind, o_sig)  # an Outcome's signature under the Ack signature identifier
    assert plain is None and why.check == "signature"
    plain, why = check.on_signature(a_kind, a_sig)  # its own: released, once
    assert why is None and decode(a_kind, plain).message == Ack(5, True)
    assert check.on_signature(a_kind, a_sig) == (None, None)  # again: nothing waits for it (held, then an orphan)


def test_a_signature_frame_may_come_before_its_data_frame_but_not_twice(keys):
    """A signature frame overtaken by its data frame's delay still pairs within the wait; a
    replayed pair is refused by freshness."""
    (kind, a, a_sig), = _genuine(keys, Ack(5, True))[0]
    check = _genuine(keys)[1]
    assert check.on_signature(kind, a_sig) == (None, None)
    plain, why = check.unwrap(kind, a)
    assert why is None and plain is not None
    check.unwrap(kind, a)
    plain, why = check.on_signature(kind, a_sig)
    assert plain is None and why.check == "freshness"


def test_an_unpaired_data_frame_expires_and_is_counted(keys):
    (kind, a, a_sig), = _genuine(keys, Ack(5, True))[0]
    clock, laptop = [0.0], _genuine(keys)[1]
    check = AnswerCheck(laptop.secoc, laptop.verifier, inline=False, wait_s=0.25, clock=lambda: clock[0])
    check.unwrap(kind, a)
    clock[0] = 0.3  # its signature frame comes too late
    assert check.on_signature(kind, a_sig) == (None, None)
    assert check.unsigned_dropped == 1
    clock[0] = 0.6
    check.unwrap(kind, a)  # an expired signature pairs with nothing
    assert check.orphan_signatures == 1


@pytest.mark.safety_case(error="loss", link="can",
                         measure="a crane frame is acted on only once its signature frame verifies",
                         reaction="an acknowledgement whose signature frame is lost is never acted on: the laptop "
                                  "times out and the status query tells the operator the command runs; an outcome "
                                  "whose signature is lost is recovered from the (signed) status")
def test_a_data_frame_whose_signature_never_arrives_is_never_acted_on(signed_pairs, make_cmd):
    p = signed_pairs(delay_s=0.3)
    link = p.link
    p.cbus.arm("drop", kind=SIGNATURE_KIND["Ack"], direction="tx")
    p.cbus.arm("drop", kind=SIGNATURE_KIND["Outcome"], direction="tx")
    cmd = make_cmd(link.new_command_id())
    fate = link.execute(cmd, ack_timeout_s=0.5, outcome_timeout_s=10.0)
    assert link._decision(cmd.command_id) is None  # the Ack arrived, authentic MAC and all, and was never taken
    assert cmd.command_id not in link._outcomes  # nor the Outcome: the status told it
    assert fate.executed is True and fate.outcome.outcome_class is OutcomeClass.SUCCESS
    assert any("acknowledgement was lost" in n for n in fate.notes)
    assert wait_until(lambda: link.stats.unsigned_dropped >= 2)
    assert p.executor.executed == [cmd.command_id]


@pytest.mark.safety_case(error="loss", link="can",
                         measure="a crane heartbeat counts only once its signature frame verifies",
                         reaction="crane heartbeats whose signature frames are lost do not keep the crane alive for "
                                  "the laptop: the controller counts as lost until they come again")
def test_unsigned_heartbeats_do_not_keep_the_crane_alive(signed_pairs):
    p = signed_pairs()
    assert wait_until(p.link.controller_alive)
    p.cbus.arm("drop", kind=SIGNATURE_KIND["CraneHeartbeat"], direction="tx", count=None)
    assert wait_until(lambda: not p.link.controller_alive(), timeout_s=5.0)
    p.cbus.disarm()
    assert wait_until(p.link.controller_alive, timeout_s=5.0)


@pytest.mark.safety_case(keys="a forged crane signature is an authentication failure", link="both",
                         reaction="dropped and counted in the laptop's auth_failures like a failed MAC "
                                  "(check='signature')")
def test_a_forged_signature_counts_as_an_authentication_failure(keys):
    key, _, pub = keys
    forger = LaptopKeyHolder(key)
    kind, data = forger.forge(Ack(5, True))
    inline = AnswerCheck(SecOC.from_key_file(key), AnswerVerifier.from_file(pub), inline=True, wait_s=0.5)
    plain, why = inline.unwrap(kind, data)
    assert plain is None and why.check == "signature"
    plain, why = inline.unwrap(kind, data[:-SIG_BYTES])  # no signature at all
    assert plain is None and why.check == "length"


@pytest.mark.safety_case(keys="forged crane frames counted; past a threshold the laptop's link fails", link="can",
                         reaction="more than max_auth_failures crane frames failing their MAC or signature within "
                                  "the window: the link fails (LinkError naming the forger), the laptop stops "
                                  "commanding; stale frames do not count")
def test_forged_signatures_past_the_threshold_fail_the_link(keys, make_cmd):
    key, sign, pub = keys
    cfg = replace(LINK, secoc_key_path=str(key), crane_key_path=str(pub), max_auth_failures=3)
    with can_pairs("threshold", cfg) as make:
        p = make(secoc_key_path=str(key), signing_key_path=str(sign))
        forger, rogue = LaptopKeyHolder(key), p.node()
        stale = SecOC.from_key_file(key, clock=lambda: time.time() - 60)
        for i in range(10):  # stale frames with genuine signatures: a clock or a replay, not a forger
            kind, plain = Encoder().encode(CraneHeartbeat(i, ControllerState.IDLE))
            secured = stale.secure(kind, plain)
            send_on_can(rogue, kind, secured + AnswerSigner.from_file(sign).sign(kind, secured))
        assert wait_until(lambda: p.link.stats.auth_failures >= 10)
        assert p.link.status().state is ControllerState.IDLE
        for i in range(3):  # forged: the 4th passes the limit of 3
            send_on_can(rogue, *forger.forge(Outcome(1000 + i, OutcomeClass.SUCCESS, 2, 999)))
        assert wait_until(lambda: p.link.stats.auth_failures >= 13)
        assert p.link.status().state is ControllerState.IDLE
        send_on_can(rogue, *forger.forge(Outcome(2000, OutcomeClass.SUCCESS, 2, 999)))
        assert wait_until(lambda: p.link._failure is not None)
        with pytest.raises(LinkError, match="forging the crane's answers"):
            p.link.send_grasp(make_cmd(p.link.new_command_id()))


@pytest.mark.parametrize("mismatch", ["another crane's public key", "a crane that does not sign"])
def test_a_laptop_with_the_wrong_crane_key_does_not_open_and_says_why(keys, tmp_path, mismatch):
    from field.link.can_backend import CanControllerTransport, CanLink

    key, sign, pub = keys
    channel = f"mismatch-{uuid.uuid4().hex[:8]}"
    signing = None if mismatch == "a crane that does not sign" else str(sign)
    ctl = CraneController(ControllerConfig(secoc_key_path=str(key), signing_key_path=signing, no_journal=True,
                                           insecure_link=signing is None), FixedOutcomeExecutor())
    tr = CanControllerTransport(bus=can.Bus(interface="virtual", channel=channel, fd=True))
    tr.start(ctl)
    ctl.start()
    laptop_pub = generate_signing_key(tmp_path / "other.sign")[1] if signing else pub
    cfg = replace(LINK, secoc_key_path=str(key), crane_key_path=str(laptop_pub), connect_timeout_s=2.0)
    link = CanLink(config=cfg, bus=can.Bus(interface="virtual", channel=channel, fd=True))
    try:
        with pytest.raises(LinkError, match="crane_key=" if signing else "signature frame.*signing_key="):
            link._await_controller()
        assert link.closed
    finally:
        link.close()
        ctl.close()
        tr.close()


# --- keys: each end refuses the wrong ones ----------------------------------------------------


def test_signing_key_files(tmp_path):
    sign, pub = generate_signing_key(tmp_path / "c.sign")
    assert (os.stat(sign).st_mode & 0o777) == 0o600 and pub.name == "c.sign.pub"
    assert "PRIVATE" not in pub.read_text()
    load_signing_key(sign), load_public_key(pub)
    with pytest.raises(KeyFileError, match="exists"):
        generate_signing_key(sign)
    with pytest.raises(KeyFileError, match="is a public key"):
        load_signing_key(pub)
    with pytest.raises(KeyFileError, match="PRIVATE signing key"):
        load_public_key(sign)
    os.chmod(sign, 0o640)
    with pytest.raises(KeyFileError, match="chmod 600"):
        load_signing_key(sign)
    bad = tmp_path / "bad.pub"
    bad.write_text("not a key\n")
    with pytest.raises(KeyFileError, match="not a PEM public key"):
        load_public_key(bad)
    with pytest.raises(KeyFileError, match="cannot be read"):
        load_public_key(tmp_path / "missing.pub")


@pytest.mark.safety_case(keys="the laptop needs the crane's public key, the crane its signing key", link="both",
                         reaction="a link or controller with a SecOC key but without them is refused unless "
                                  "insecure=1 / --insecure-link")
def test_signature_keys_are_needed_unless_the_operator_opts_out(keys):
    key, sign, pub = keys
    with pytest.raises(LinkError, match="no crane public key.*insecure=1"):
        open_link(f"can://virtual/sig-{uuid.uuid4().hex[:6]}?secoc_key={key}")
    with pytest.raises(ControllerError, match="needs its signing key"):
        CraneController(ControllerConfig(secoc_key_path=str(key), no_journal=True), FixedOutcomeExecutor())
    with pytest.raises(KeyFileError, match="is a public key"):
        CraneController(ControllerConfig(secoc_key_path=str(key), signing_key_path=str(pub), no_journal=True),
                        FixedOutcomeExecutor())
    with pytest.raises(KeyFileError, match="PRIVATE"):
        open_link(f"can://virtual/sig-{uuid.uuid4().hex[:6]}?secoc_key={key}&crane_key={sign}")
    with open_link(f"twin://?secoc_key={key}&crane_key={pub}&signing_key={sign}") as twin:
        assert twin.authenticated and twin.answers_signed
        assert twin.status().state is ControllerState.IDLE
