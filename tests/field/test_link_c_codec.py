"""The crane side's codec, proven: the C code ``cantools generate_c_source`` makes from the shipped
DBC compiles with ``gcc -Wall -Werror`` and agrees with :mod:`field.link.codec` bit for bit, in
both directions, for every message, every signal's edge values and the E2E header (CRC computed in
C, rolling counter, protocol version); and the DBC's signal ranges are the same line for cantools'
strict encoder, the generated ``*_is_in_range`` and our decoder. A DBC copy with one bit order,
scale or header field changed must make the comparison fail (the test can fail).

The harness: tests/field/c_codec.py (one C process answers a batch of stdin lines).
"""

from __future__ import annotations

import random
import subprocess
from pathlib import Path

import pytest
from cantools.database.errors import EncodeError
from e2e.p05 import e2e_p05_protect
from hypothesis import given, settings
from hypothesis import strategies as st

from field.errors import ProtocolError
from field.link import codec
from field.link.codec import CraneHeartbeat, EStopRequest, LaptopHeartbeat, StatusRequest
from field.link.messages import (
    Ack,
    ControllerState,
    ControllerStatus,
    GraspCommand,
    Outcome,
    OutcomeClass,
    RejectReason,
)
from tests.field import c_codec

DBC = Path(codec.__file__).with_name(codec.DBC_NAME)
DB = codec.load_database()


@pytest.fixture(scope="module")
def harness(tmp_path_factory) -> c_codec.CHarness:
    return c_codec.build(DBC, DB, tmp_path_factory.mktemp("c-codec"))


# -- what is compared ------------------------------------------------------------------------------


def raw_width(sig) -> tuple[int, int]:
    """The raw values a signal's bits can hold."""
    return (-(2 ** (sig.length - 1)), 2 ** (sig.length - 1) - 1) if sig.is_signed else (0, 2**sig.length - 1)


def edge_values(sig) -> list[int]:
    """A signal's raw ends, zero and one, and its DBC range's ends and the values just outside."""
    low, high = raw_width(sig)
    picks = {low, low + 1, -1, 0, 1, high - 1, high}
    if sig.minimum is not None:
        picks |= {int(sig.minimum) - 1, int(sig.minimum), int(sig.maximum), int(sig.maximum) + 1}
    return sorted(v for v in picks if low <= v <= high)


def raw_cases(seed: int = 38, randoms_per_message: int = 40) -> list[tuple[str, list[int]]]:
    """Every edge value of every signal (the other signals random), plus random frames."""
    rng = random.Random(seed)
    cases = []
    for message in DB.messages:
        def rand() -> list[int]:
            return [rng.randint(*raw_width(s)) for s in message.signals]

        for i, sig in enumerate(message.signals):
            for v in edge_values(sig):
                values = rand()
                values[i] = v
                cases.append((message.name, values))
        cases += [(message.name, rand()) for _ in range(randoms_per_message)]
    return cases


def raw_mismatches(harness: c_codec.CHarness, cases: list[tuple[str, list[int]]]) -> list[str]:
    """Raw layer: the C ``*_pack`` against cantools' encoder (no scaling, no range check) and the C
    ``*_unpack`` of cantools' frame against the values; one line per disagreement."""
    frames, requests = [], []
    for kind, values in cases:
        message = DB.get_message_by_name(kind)
        frame = message.encode(dict(zip([s.name for s in message.signals], values)), scaling=False, strict=False,
                               padding=False)
        frames.append(frame)
        requests += [f"pack {kind} {' '.join(map(str, values))}", f"unpack {kind} {frame.hex()}"]
    answers = harness.ask(requests)
    out = []
    for (kind, values), frame, packed, unpacked in zip(cases, frames, answers[::2], answers[1::2]):
        if packed != frame.hex():
            out.append(f"{kind} {values}: C packs {packed}, cantools {frame.hex()}")
        if unpacked.split() != ["raw", *map(str, values)]:
            out.append(f"{kind} {frame.hex()}: C unpacks {unpacked}, cantools packed {values}")
    return out


def codec_mismatches(harness: c_codec.CHarness, messages: list[tuple[object, int]]) -> list[str]:
    """Codec layer, both ways: our codec's frame passes the C E2E check and unpacks to the same
    physical values; the C side's own frame from those values (CRC computed in C, CRC value given
    as 0) is byte for byte our frame, and our decoder reads the same message and counter back."""
    frames, requests = [], []
    for msg, counter in messages:
        kind, frame = codec.encode(msg, counter)
        message = DB.get_message_by_name(kind)
        values = message.decode(frame, decode_choices=False, scaling=True)
        phys = [0 if s.name == "CRC" else values[s.name] for s in message.signals]
        frames.append((kind, frame, [values[s.name] for s in message.signals]))
        requests += [f"decode {kind} {frame.hex()}", f"encode {kind} {' '.join(map(str, phys))}"]
    answers = harness.ask(requests)
    out = []
    for (msg, counter), (kind, frame, values), decoded, encoded in zip(messages, frames, answers[::2], answers[1::2]):
        status, *c_values = decoded.split()
        if status != "ok" or [float(v) for v in c_values] != values:
            out.append(f"{kind} {frame.hex()}: C decodes {decoded}, Python {values}")
        if encoded != frame.hex():
            out.append(f"{msg!r} counter {counter}: C encodes {encoded}, Python {frame.hex()}")
            continue
        back = codec.decode(kind, bytes.fromhex(encoded))
        if back.message != msg or back.counter != counter:
            out.append(f"{kind} {encoded}: Python decodes the C frame as {back}, sent {msg!r} counter {counter}")
    return out


# -- messages within the DBC's ranges ------------------------------------------------------------------


def in_range(kind: str, signal: str) -> st.SearchStrategy[int]:
    sig = DB.get_message_by_name(kind).get_signal_by_name(signal)
    return st.integers(int(sig.minimum), int(sig.maximum))


U32 = st.integers(0, 2**32 - 1)
U8 = st.integers(0, 255)
outcomes = st.builds(Outcome, in_range("Outcome", "CommandId"), st.sampled_from(OutcomeClass), U8,
                     in_range("Outcome", "BalanceCosMilli"))
messages = st.one_of(
    st.builds(GraspCommand, *(in_range("GraspCommand", s) for s in (
        "CommandId", "EastingMm", "NorthingMm", "HeightMm", "HeadingCdeg", "OpeningWidthMm", "TargetLogCount",
        "PlanTimestampMs"))),
    st.builds(Ack, U32, st.just(True)),
    st.builds(Ack, U32, st.just(False), st.sampled_from([r for r in RejectReason if r is not RejectReason.NONE])),
    outcomes,
    st.builds(ControllerStatus, st.sampled_from(ControllerState), U32, U32,
              st.one_of(st.none(), outcomes), U32, U8),
    st.builds(StatusRequest, U32),
    st.builds(LaptopHeartbeat, U32),
    st.builds(CraneHeartbeat, U32, st.sampled_from(ControllerState)),
    st.builds(EStopRequest, U8),
)


def extreme_commands() -> list[GraspCommand]:
    """The grasp command at the low and the high end of every signal's DBC range."""
    m = DB.get_message_by_name("GraspCommand")
    names = ["CommandId", "EastingMm", "NorthingMm", "HeightMm", "HeadingCdeg", "OpeningWidthMm", "TargetLogCount",
             "PlanTimestampMs"]
    return [GraspCommand(*(int(getattr(m.get_signal_by_name(n), end)) for n in names)) for end in ("minimum", "maximum")]


FIXED = [(cmd, counter) for cmd in extreme_commands() for counter in (0, 255)] + [
    (Ack(2**32 - 1, False, RejectReason.FAULT), 1),
    (Outcome(1, OutcomeClass.ABORTED, 255, -1000), 2),
    (ControllerStatus(ControllerState.ESTOP, 2**32 - 1, 0, Outcome(0, OutcomeClass.DROPPED, 0, 1000), 7, 255), 3),
    (EStopRequest(2), 128),
]


#: one valid message of every kind (the base the range test changes one signal of)
ONE_PER_KIND = [extreme_commands()[0], *(m for m, _ in FIXED[4:]), StatusRequest(1), LaptopHeartbeat(1),
                CraneHeartbeat(1, ControllerState.IDLE)]


# -- the tests -------------------------------------------------------------------------------------------


def test_generated_code_compiles_with_gcc_wall_werror(harness, tmp_path):
    source, _ = c_codec.generate_c(DBC, tmp_path)
    done = subprocess.run(["gcc", "-Wall", "-Werror", "-c", str(source), "-o", str(tmp_path / "codec.o")],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert sorted(harness.messages) == sorted(m.name for m in DB.messages)  # every message has its C struct


def test_every_signal_packs_and_unpacks_like_cantools(harness):
    cases = raw_cases()
    assert len({kind for kind, _ in cases}) == len(DB.messages)
    assert raw_mismatches(harness, cases) == []


def test_fixed_extremes_agree_with_our_codec_both_ways(harness):
    assert codec_mismatches(harness, FIXED) == []


@settings(max_examples=25, deadline=None)
@given(batch=st.lists(st.tuples(messages, U8), min_size=1, max_size=40))
def test_random_messages_agree_with_our_codec_both_ways(harness, batch):
    assert codec_mismatches(harness, batch) == []


def test_c_rejects_a_corrupted_frame_of_ours(harness):
    kind, frame = codec.encode(extreme_commands()[1], 9)
    bad = bytearray(frame)
    bad[20] ^= 0x04
    good, corrupted = harness.ask([f"decode {kind} {frame.hex()}", f"decode {kind} {bytes(bad).hex()}"])
    assert good.startswith("ok ") and corrupted.startswith("crc ")


def test_dbc_ranges_are_one_line_for_cantools_c_and_our_decoder(harness):
    """Per signal, at its range's ends and just outside: the generated ``*_is_in_range``, cantools'
    strict encoder (what our codec sends) and our decoder (MALFORMED, 'outside its range') agree."""
    base = {}
    for msg in ONE_PER_KIND:
        kind, frame = codec.encode(msg, 0)
        base[kind] = DB.get_message_by_name(kind).decode(frame, decode_choices=False)
    # every message with signals to range-check (a signature frame's 64 bytes take every value)
    assert sorted(base) == sorted(m.name for m in DB.messages if m.name not in codec.SIGNED_KIND)
    checks, requests = [], []
    for kind, values in base.items():
        message = DB.get_message_by_name(kind)
        for i, sig in enumerate(message.signals):
            for v in edge_values(sig):
                trial = [v if s is sig else values[s.name] for s in message.signals]
                checks.append((kind, sig, v, i))
                requests.append(f"range {kind} {' '.join(map(str, trial))}")
    answers = harness.ask(requests)
    disagree = []
    for (kind, sig, v, i), ranged in zip(checks, answers):
        c_ok = ranged.split()[1 + i] == "1"
        message = DB.get_message_by_name(kind)
        try:
            message.encode({**base[kind], sig.name: v}, strict=True)
            sender_ok = True
        except EncodeError:  # the sender refuses the value
            sender_ok = False
        frame = bytearray(message.encode({**base[kind], sig.name: v}, strict=False, padding=False))
        e2e_p05_protect(frame, codec.data_id(kind), increment_counter=False)
        try:
            codec.decode(kind, bytes(frame))
            receiver_ok = True
        except ProtocolError as exc:
            receiver_ok = "outside its range" not in str(exc)
        if not c_ok == sender_ok == receiver_ok:
            disagree.append(f"{kind}.{sig.name} = {v}: C {c_ok}, cantools {sender_ok}, our decoder {receiver_ok}")
    assert disagree == []
    crossed = {(kind, sig.name) for (kind, sig, _, i), r in zip(checks, answers) if r.split()[1 + i] == "0"}
    assert {("GraspCommand", s) for s in ("EastingMm", "NorthingMm", "HeightMm", "PlanTimestampMs")} <= crossed


MUTATIONS = {  # a DBC copy the C side might have been built from: one line changed
    "EastingMm big-endian": (" SG_ EastingMm : 64|64@1-", " SG_ EastingMm : 71|64@0-"),
    "HeightMm scale 2": (" SG_ HeightMm : 192|32@1- (1,0)", " SG_ HeightMm : 192|32@1- (2,0)"),
    "E2E CRC big-endian": (" SG_ CRC : 0|16@1+", " SG_ CRC : 7|16@0+"),
}


@pytest.mark.parametrize("name", sorted(MUTATIONS))
def test_a_c_side_built_from_a_changed_dbc_is_caught(name, tmp_path):
    old, new = MUTATIONS[name]
    text = DBC.read_text()
    assert old in text
    changed = tmp_path / "loggrasp.dbc"
    changed.write_text(text.replace(old, new))
    import cantools

    other = c_codec.build(changed, cantools.database.load_file(changed, strict=True), tmp_path / "c")
    found = raw_mismatches(other, raw_cases(randoms_per_message=5)) + codec_mismatches(other, FIXED)
    assert found, f"{name}: the comparison saw no difference"
