"""A trial's CAN recording (``link/traffic.blf``) as decoded frames, for the trial's MCAP view.

Each frame becomes a JSON-able dict: its recorded time, id, direction, bytes, the DBC signals
(``field/link/loggrasp.dbc``, value tables by name) and whether it passed the codec's checks
(E2E CRC, length, reserved bits, protocol version: :func:`field.link.codec.decode`). On a link
with authenticated (SecOC-style) frames each frame is decoded from its authentic part; its MAC
is not checked here (the key stays with the link), and a crane answer's signature frame shows its
64 bytes (checked by the laptop when it arrived). Status and crane heartbeat frames also give the crane's
state at that time (``crane_state``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

STATE_KINDS = ("Status", "CraneHeartbeat")  # frames that carry the controller's state


def _plain(v: Any) -> Any:
    """A cantools signal value as JSON: named values by name, numbers as numbers."""
    if isinstance(v, (int, float, bool)) or v is None:
        return v
    return str(v)


def decode_frame(t_s: float, arbitration_id: int, data: bytes, is_rx: bool, secured: bool = False) -> dict:
    """One recorded frame as a dict (see the module docstring); ``secured``: the link carried
    authenticated frames (:mod:`field.link.secoc`)."""
    from field.errors import ProtocolError
    from field.link.codec import SIGNED_KIND, authentic_length, decode, kind_of_frame_id, load_database

    out: dict[str, Any] = {"t_utc_s": t_s, "id": f"0x{arbitration_id:03X}", "direction": "rx" if is_rx else "tx",
                           "length": len(data), "data_hex": data.hex(), "kind": None, "signals": {}, "check": None}
    kind = kind_of_frame_id(arbitration_id)
    if kind is None:
        out["check"] = "unknown frame id"
        return out
    out["kind"] = kind
    message = load_database().get_message_by_frame_id(arbitration_id)
    pdu = bytes(data)
    out["secured"] = secured
    if kind in SIGNED_KIND:  # the crane's signature of the frame before it: 64 bytes, no E2E header
        ok = len(pdu) == message.length
        out["check"] = "ok" if ok else f"{kind}: {len(pdu)} bytes, expected {message.length}"
        out["signals"] = {k: _plain(v) for k, v in message.decode(pdu).items()} if ok else {}
        return out
    if secured:  # the authentic PDU, then freshness and MAC where the plain frame's reserved tail is
        a = authentic_length(kind)
        pdu = pdu[:a] + bytes(message.length - a)
    try:
        decoded = decode(kind, pdu)
        out["check"] = "ok"
    except ProtocolError as exc:
        decoded = None
        out["check"] = str(exc)
    try:
        out["signals"] = {k: _plain(v) for k, v in message.decode(pdu, decode_choices=True).items()}
    except Exception as exc:  # cantools' DecodeError: the check above says why
        out["signals"] = {}
        out["check"] = out["check"] if out["check"] != "ok" else f"cannot decode: {exc}"
    if kind in STATE_KINDS and decoded is not None:
        out["crane_state"] = _crane_state(kind, decoded.message, t_s)
    return out


def _crane_state(kind: str, msg: Any, t_s: float) -> dict:
    from dataclasses import asdict
    import enum

    fields = {k: (v.name if isinstance(v, enum.Enum) else v) for k, v in asdict(msg).items()
              if not isinstance(v, dict)}
    return {"t_utc_s": t_s, "source": kind, **fields}


def decode_recording(blf_path: str | Path, secured: bool = False) -> list[dict]:
    """Every frame of a BLF recording, decoded, in time order (``secured``: see :func:`decode_frame`)."""
    import can

    frames = []
    with can.BLFReader(str(blf_path)) as reader:
        for msg in reader:
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            frames.append(decode_frame(float(msg.timestamp), int(msg.arbitration_id), bytes(msg.data),
                                       bool(msg.is_rx), secured))
    frames.sort(key=lambda f: f["t_utc_s"])
    return frames
