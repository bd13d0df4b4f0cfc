"""One codec for the crane link: messages <-> protected frame bytes.

The wire format is the DBC file shipped next to this module (``loggrasp.dbc``), loaded with
cantools. Every frame is a CAN FD frame: the grasp command needs a SWEREF 99 TM position at
millimetre resolution (two int64) plus height, heading, width, log count and a uint64 plan
timestamp — about 36 bytes — so it travels as ONE 64-byte CAN FD frame instead of a multiplexed
sequence of classic 8-byte frames (atomic on the bus, one CRC, no reassembly state). The small
frames are FD too (one bus mode, one frame format).

End-to-end protection: AUTOSAR E2E Profile 5 (PyPI ``autosar-e2e``, import ``e2e``): bytes 0-1
hold the CRC-16 over the frame and a per-message data ID (the DBC attribute ``E2EDataID``),
byte 2 an 8-bit rolling counter, byte 3 the protocol version. The counter is managed here (one
transmit counter per message per sender) and checked by :class:`CounterMonitor`, AUTOSAR style:
a repeated counter is a duplicated frame (dropped), a jump larger than ``max_delta`` or backwards
is a wrong sequence (lost / reordered / replayed frames).

Signal ranges are the DBC's ``[minimum|maximum]`` (SWEREF 99 TM over Sweden, heights, the plan
time up to 2100): the strict encoder refuses a value outside them, and so does :func:`decode`
(MALFORMED), the same line as the C ``*_is_in_range`` that ``cantools generate_c_source`` makes
for the crane side (tests/field/test_link_c_codec.py).

The Zenoh backend sends exactly these bytes as its payloads: one codec, one protection.
"""

from __future__ import annotations

import enum
import functools
import threading
from dataclasses import dataclass
from importlib import resources
from typing import Any, Union

from field.errors import ProtocolError
from field.link.messages import (
    NO_OUTCOME,
    Ack,
    ControllerState,
    ControllerStatus,
    GraspCommand,
    Outcome,
    OutcomeClass,
    RejectReason,
)

#: Major version of the link protocol carried in every frame (byte 3). A frame of another
#: version is refused (MALFORMED).
PROTOCOL_VERSION = 1
DBC_NAME = "loggrasp.dbc"


@dataclass(frozen=True)
class StatusRequest:
    """Status query, laptop -> crane; the reply echoes ``request_id``."""

    request_id: int  # uint32


@dataclass(frozen=True)
class LaptopHeartbeat:
    heartbeat_counter: int  # uint32, wraps


@dataclass(frozen=True)
class CraneHeartbeat:
    heartbeat_counter: int  # uint32, wraps
    state: ControllerState


@dataclass(frozen=True)
class EStopRequest:
    source: int = 1  # 1 = operator, 2 = link supervision


Message = Union[GraspCommand, Ack, Outcome, ControllerStatus, StatusRequest, LaptopHeartbeat, CraneHeartbeat, EStopRequest]

#: message type -> DBC message name
KIND_OF: dict[type, str] = {
    GraspCommand: "GraspCommand",
    Ack: "Ack",
    Outcome: "Outcome",
    ControllerStatus: "Status",
    StatusRequest: "StatusRequest",
    LaptopHeartbeat: "LaptopHeartbeat",
    CraneHeartbeat: "CraneHeartbeat",
    EStopRequest: "EStop",
}
#: frames the laptop sends / the crane sends
LAPTOP_TO_CRANE = ("GraspCommand", "StatusRequest", "LaptopHeartbeat", "EStop")
CRANE_TO_LAPTOP = ("Ack", "Outcome", "Status", "CraneHeartbeat")
#: CAN FD: the signature frame that follows each crane -> laptop frame (field/link/signing.py),
#: and the reverse map; signature frames carry 64 signature bytes, no E2E header
SIGNATURE_KIND = {kind: f"{kind}Signature" for kind in CRANE_TO_LAPTOP}
SIGNED_KIND = {sig: kind for kind, sig in SIGNATURE_KIND.items()}


@functools.lru_cache(maxsize=1)
def load_database() -> Any:
    """The link's cantools database (parsed once, strict)."""
    import cantools

    text = resources.files("field.link").joinpath(DBC_NAME).read_text()
    return cantools.database.load_string(text, database_format="dbc", strict=True)


@functools.lru_cache(maxsize=None)
def _message(kind: str) -> Any:
    return load_database().get_message_by_name(kind)


def frame_id(kind: str) -> int:
    """CAN arbitration id of a message kind (``"GraspCommand"``...)."""
    return _message(kind).frame_id


def data_id(kind: str) -> int:
    """AUTOSAR E2E data ID of a message kind (DBC attribute ``E2EDataID``)."""
    return int(_message(kind).dbc.attributes["E2EDataID"].value)


@functools.lru_cache(maxsize=None)
def kind_of_frame_id(arbitration_id: int) -> str | None:
    try:
        return load_database().get_message_by_frame_id(arbitration_id).name
    except KeyError:
        return None


def kind_of_can_frame(arbitration_id: int, is_extended_id: bool, is_fd: bool) -> str | None:
    """The message kind of a received CAN frame, or ``None`` when it is not a link frame.

    The DBC's ``VFrameFormat`` decides: every link frame is a CAN FD frame with an 11-bit
    identifier, so an extended (29-bit) frame whose id happens to equal a link id, or a classic
    frame, is a foreign frame and is ignored.
    """
    kind = kind_of_frame_id(arbitration_id)
    if kind is None:
        return None
    message = _message(kind)
    if bool(is_extended_id) != bool(message.is_extended_frame) or bool(is_fd) != bool(message.is_fd):
        return None
    return kind


@functools.lru_cache(maxsize=None)
def used_bits_mask(kind: str) -> bytes:
    """One byte per frame byte, a bit set where a DBC signal lives (little-endian signals)."""
    message = _message(kind)
    mask = bytearray(message.length)
    for sig in message.signals:
        for bit in range(sig.start, sig.start + sig.length):
            mask[bit // 8] |= 1 << (bit % 8)
    return bytes(mask)


@functools.lru_cache(maxsize=None)
def authentic_length(kind: str) -> int:
    """Bytes from the start of the frame up to the last byte a signal uses (the part an
    authenticated frame carries; the rest is reserved and zero)."""
    mask = used_bits_mask(kind)
    return max(i for i, m in enumerate(mask) if m) + 1


def _check_reserved_zero(kind: str, data: bytearray) -> None:
    mask = used_bits_mask(kind)
    bad = [i for i, (b, m) in enumerate(zip(data, mask)) if b & ~m & 0xFF]
    if bad:
        raise ProtocolError(
            f"{kind}: reserved bits set in byte(s) {bad}; loggrasp.dbc says unused bytes are zero. "
            f"The sender speaks another protocol variant: run the same loggrasp on both sides",
            reason=RejectReason.MALFORMED,
            integrity_ok=True,
        )


def _check_ranges(kind: str, values: dict[str, Any]) -> None:
    """Refuse a received signal outside its DBC range ``[minimum, maximum]`` (MALFORMED): the
    receiver refuses exactly what the sender's strict cantools encoder and the generated C code's
    ``*_is_in_range`` refuse (tests/field/test_link_c_codec.py holds the three to the same line)."""
    for sig in _message(kind).signals:
        v = values[sig.name]
        low, high = sig.minimum, sig.maximum
        if (low is not None and v < low) or (high is not None and v > high):
            raise ProtocolError(
                f"{kind}: {sig.name} = {v} is outside its range [{low}, {high}] in loggrasp.dbc; "
                f"the sender does not speak this protocol: run the same loggrasp on both sides",
                reason=RejectReason.MALFORMED,
                integrity_ok=True,
            )


def _signals(msg: Message) -> dict[str, int]:
    if isinstance(msg, GraspCommand):
        return {
            "CommandId": msg.command_id,
            "EastingMm": msg.easting_mm,
            "NorthingMm": msg.northing_mm,
            "HeightMm": msg.height_mm,
            "HeadingCdeg": msg.heading_cdeg,
            "OpeningWidthMm": msg.opening_width_mm,
            "TargetLogCount": msg.target_log_count,
            "PlanTimestampMs": msg.plan_timestamp_ms,
        }
    if isinstance(msg, Ack):
        return {"CommandId": msg.command_id, "Accepted": int(msg.accepted), "RejectReason": int(msg.reason)}
    if isinstance(msg, Outcome):
        return {
            "CommandId": msg.command_id,
            "OutcomeClass": int(msg.outcome_class),
            "LogsGrasped": msg.logs_grasped,
            "BalanceCosMilli": msg.balance_cos_milli,
        }
    if isinstance(msg, ControllerStatus):
        last = msg.last_outcome
        return {
            "State": int(msg.state),
            "RequestId": msg.request_id,
            "HeartbeatCounter": msg.heartbeat_counter,
            "CurrentCommandId": msg.current_command_id,
            "LastCommandId": last.command_id if last else 0,
            "LastOutcomeClass": int(last.outcome_class) if last else NO_OUTCOME,
            "LastLogsGrasped": last.logs_grasped if last else 0,
            "LastBalanceCosMilli": last.balance_cos_milli if last else 0,
            "LaptopPeers": msg.laptops,
        }
    if isinstance(msg, StatusRequest):
        return {"RequestId": msg.request_id}
    if isinstance(msg, LaptopHeartbeat):
        return {"HeartbeatCounter": msg.heartbeat_counter}
    if isinstance(msg, CraneHeartbeat):
        return {"HeartbeatCounter": msg.heartbeat_counter, "State": int(msg.state)}
    if isinstance(msg, EStopRequest):
        return {"EStopSource": msg.source}
    raise TypeError(f"not a crane-link message: {msg!r}")


def encode(msg: Message, counter: int) -> tuple[str, bytes]:
    """Encode ``msg`` with rolling ``counter`` (0..255) and E2E-protect it.

    Returns ``(kind, frame bytes)``. Raises :class:`ProtocolError` when a value does not fit
    its signal (cantools ``EncodeError`` / overflow), naming the signal and its range.
    """
    from cantools.database.errors import EncodeError
    from e2e.p05 import e2e_p05_protect

    kind = KIND_OF.get(type(msg))
    if kind is None:
        raise TypeError(f"not a crane-link message: {msg!r}")
    message = _message(kind)
    values = {"CRC": 0, "Counter": counter & 0xFF, "ProtocolVersion": PROTOCOL_VERSION, **_signals(msg)}
    try:
        data = bytearray(message.encode(values, scaling=True, padding=False, strict=True))
    except (EncodeError, OverflowError, ValueError) as exc:
        raise ProtocolError(
            f"cannot encode {kind}: a value does not fit its wire signal ({exc}). Bring it into "
            f"the range loggrasp.dbc allows; nothing was sent",
            reason=RejectReason.MALFORMED,
        ) from exc
    e2e_p05_protect(data, data_id(kind), increment_counter=False)
    return kind, bytes(data)


@dataclass(frozen=True)
class Decoded:
    kind: str
    counter: int
    message: Message


def _enum(kind: str, enum_type: type[enum.IntEnum], value: int) -> Any:
    try:
        return enum_type(value)
    except ValueError as exc:
        raise ProtocolError(
            f"{kind}: {value} is not a valid {enum_type.__name__}", reason=RejectReason.MALFORMED
        ) from exc


def decode(kind_or_id: str | int, data: bytes | bytearray) -> Decoded:
    """Check and decode one frame. Raises :class:`ProtocolError` with ``reason`` CRC (failed
    E2E check) or MALFORMED (unknown id, wrong length, reserved bits set, wrong version, invalid
    field); ``integrity_ok`` on the error says whether the frame passed its E2E check first
    (only then may a reply name the command id in it)."""
    from e2e.p05 import e2e_p05_check

    kind = kind_of_frame_id(kind_or_id) if isinstance(kind_or_id, int) else kind_or_id
    if kind is None or kind not in KIND_OF.values():
        raise ProtocolError(f"unknown frame {kind_or_id!r}", reason=RejectReason.MALFORMED)
    message = _message(kind)
    data = bytearray(data)
    if len(data) != message.length:
        raise ProtocolError(
            f"{kind}: {len(data)} bytes, expected {message.length}", reason=RejectReason.MALFORMED
        )
    if not e2e_p05_check(data, data_id(kind)):
        raise ProtocolError(f"{kind}: end-to-end CRC check failed (corrupted frame)", reason=RejectReason.CRC)
    _check_reserved_zero(kind, data)
    try:
        v = message.decode(bytes(data), decode_choices=False, scaling=True)
    except Exception as exc:  # cantools DecodeError and friends: a malformed frame
        raise ProtocolError(f"{kind}: cannot decode ({exc})", reason=RejectReason.MALFORMED,
                            integrity_ok=True) from exc
    if v["ProtocolVersion"] != PROTOCOL_VERSION:
        raise ProtocolError(
            f"{kind}: protocol version {v['ProtocolVersion']}, this code speaks {PROTOCOL_VERSION}; "
            f"run the same loggrasp version on the laptop and the crane",
            reason=RejectReason.MALFORMED,
            integrity_ok=True,
        )
    _check_ranges(kind, v)
    counter = int(v["Counter"])
    try:
        msg = _build(kind, v)
    except (ValueError, ProtocolError) as exc:
        raise ProtocolError(f"{kind}: invalid content ({exc})", reason=RejectReason.MALFORMED,
                            integrity_ok=True) from exc
    return Decoded(kind, counter, msg)


def _build(kind: str, v: dict[str, Any]) -> Message:
    i = {k: int(x) for k, x in v.items()}
    if kind == "GraspCommand":
        return GraspCommand(
            command_id=i["CommandId"],
            easting_mm=i["EastingMm"],
            northing_mm=i["NorthingMm"],
            height_mm=i["HeightMm"],
            heading_cdeg=i["HeadingCdeg"],
            opening_width_mm=i["OpeningWidthMm"],
            target_log_count=i["TargetLogCount"],
            plan_timestamp_ms=i["PlanTimestampMs"],
        )
    if kind == "Ack":
        return Ack(i["CommandId"], bool(i["Accepted"]), _enum(kind, RejectReason, i["RejectReason"]))
    if kind == "Outcome":
        return Outcome(
            i["CommandId"], _enum(kind, OutcomeClass, i["OutcomeClass"]), i["LogsGrasped"], i["BalanceCosMilli"]
        )
    if kind == "Status":
        last = None
        if i["LastOutcomeClass"] != NO_OUTCOME:
            last = Outcome(
                i["LastCommandId"],
                _enum(kind, OutcomeClass, i["LastOutcomeClass"]),
                i["LastLogsGrasped"],
                i["LastBalanceCosMilli"],
            )
        return ControllerStatus(
            state=_enum(kind, ControllerState, i["State"]),
            current_command_id=i["CurrentCommandId"],
            heartbeat_counter=i["HeartbeatCounter"],
            last_outcome=last,
            request_id=i["RequestId"],
            laptops=i["LaptopPeers"],
        )
    if kind == "StatusRequest":
        return StatusRequest(i["RequestId"])
    if kind == "LaptopHeartbeat":
        return LaptopHeartbeat(i["HeartbeatCounter"])
    if kind == "CraneHeartbeat":
        return CraneHeartbeat(i["HeartbeatCounter"], _enum(kind, ControllerState, i["State"]))
    if kind == "EStop":
        return EStopRequest(i["EStopSource"])
    raise ProtocolError(f"unknown frame kind {kind!r}", reason=RejectReason.MALFORMED)


class Encoder:
    """A sender's encoder: one rolling transmit counter per message kind (thread-safe)."""

    def __init__(self, first_counter: int = 0) -> None:
        self._counters: dict[str, int] = {}
        self._first = first_counter & 0xFF
        self._lock = threading.Lock()

    def next_counter(self, kind: str) -> int:
        with self._lock:
            c = (self._counters.get(kind, self._first - 1) + 1) & 0xFF
            self._counters[kind] = c
            return c

    def encode(self, msg: Message) -> tuple[str, bytes]:
        kind = KIND_OF.get(type(msg))
        if kind is None:
            raise TypeError(f"not a crane-link message: {msg!r}")
        return encode(msg, self.next_counter(kind))


class CounterCheck(enum.Enum):
    INITIAL = "initial"  # first frame seen: counter adopted
    OK = "ok"  # 1 <= delta <= max_delta
    REPEATED = "repeated"  # delta == 0: a duplicated frame
    WRONG_SEQUENCE = "wrong_sequence"  # backwards or too far ahead: lost / reordered / replayed


class CounterMonitor:
    """Receiver side of the rolling counter, one per message kind (AUTOSAR E2E state machine,
    simplified): the counter is adopted on the first frame and after :meth:`reset`; a repeated
    counter leaves the state unchanged, anything else re-synchronises on the received value."""

    def __init__(self, max_delta: int = 2) -> None:
        if not 1 <= max_delta <= 127:
            raise ValueError(f"max_delta must be in [1, 127], got {max_delta}")
        self.max_delta = max_delta
        self._last: dict[str, int] = {}
        self._lock = threading.Lock()

    def check(self, kind: str, counter: int) -> CounterCheck:
        with self._lock:
            last = self._last.get(kind)
            if last is None:
                self._last[kind] = counter
                return CounterCheck.INITIAL
            delta = (counter - last) & 0xFF
            if delta == 0:
                return CounterCheck.REPEATED
            self._last[kind] = counter
            return CounterCheck.OK if delta <= self.max_delta else CounterCheck.WRONG_SEQUENCE

    def reset(self) -> None:
        with self._lock:
            self._last.clear()
