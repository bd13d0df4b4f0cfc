"""A fault-injecting python-can bus wrapper, for tests and field drills.

Wrap any bus and arm faults; each armed fault applies to the next ``count`` matching frames::

    bus = FaultyBus(can.Bus(interface="virtual", channel="ch0", fd=True))
    bus.arm("drop", kind="GraspCommand")            # the next command frame vanishes
    bus.arm("corrupt", kind="Ack", direction="rx")  # the next received ack has a flipped bit
    bus.arm("drop", kind="CraneHeartbeat", direction="rx", count=None)  # all of them, until disarm()

Actions: ``drop``, ``duplicate`` (sent / delivered twice), ``corrupt`` (one bit flipped at
``byte``), ``hold`` (kept back until :meth:`release`; frames behind it overtake it = reordering),
``error`` (the operation raises ``can.CanOperationError`` = a bus error).
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass
import can

from field.link.can_backend import ProxyBus
from field.link.codec import kind_of_frame_id

ACTIONS = ("drop", "duplicate", "corrupt", "hold", "error")


@dataclass
class _Fault:
    action: str
    kind: str | None
    direction: str
    count: int | None  # None = until disarmed
    byte: int
    bit: int


class FaultyBus(ProxyBus):
    def __init__(self, inner: can.BusABC):
        super().__init__(inner)
        self._faults: list[_Fault] = []
        self._lock = threading.Lock()
        self._held: list[can.Message] = []
        self._rx_pending: collections.deque[can.Message] = collections.deque()
        self.injected: list[tuple[str, str | None, str]] = []  # (action, kind, direction)

    def arm(self, action: str, kind: str | None = None, *, direction: str = "tx", count: int | None = 1, byte: int = 20, bit: int = 3) -> None:
        """Arm a fault for the next ``count`` frames of ``kind`` (any kind if None)."""
        if action not in ACTIONS:
            raise ValueError(f"unknown fault {action!r}; choose one of {ACTIONS}")
        if direction not in ("tx", "rx"):
            raise ValueError(f"direction must be 'tx' or 'rx', got {direction!r}")
        if action == "hold" and direction != "tx":
            raise ValueError("'hold' (reordering) applies to sent frames only (direction='tx')")
        if count is not None and count < 1:
            raise ValueError(f"count must be >= 1 or None, got {count}")
        with self._lock:
            self._faults.append(_Fault(action, kind, direction, count, byte, bit))

    def disarm(self) -> None:
        with self._lock:
            self._faults.clear()

    def release(self) -> int:
        """Send the held frames now (after the frames that overtook them); returns how many."""
        with self._lock:
            held, self._held = self._held, []
        for msg in held:
            self.inner.send(msg)
        return len(held)

    def _match(self, msg: can.Message, direction: str) -> _Fault | None:
        kind = kind_of_frame_id(msg.arbitration_id)
        with self._lock:
            for f in self._faults:
                if f.direction == direction and (f.kind is None or f.kind == kind):
                    if f.count is not None:
                        f.count -= 1
                        if f.count == 0:
                            self._faults.remove(f)
                    self.injected.append((f.action, kind, direction))
                    return f
        return None

    @staticmethod
    def _corrupt(msg: can.Message, f: _Fault) -> can.Message:
        data = bytearray(msg.data)
        if data:
            data[f.byte % len(data)] ^= 1 << (f.bit % 8)
        return can.Message(
            timestamp=msg.timestamp,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_fd=msg.is_fd,
            bitrate_switch=msg.bitrate_switch,
            data=data,
            channel=msg.channel,
        )

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        f = self._match(msg, "tx")
        if f is None:
            self.inner.send(msg, timeout)
            return
        if f.action == "drop":
            return
        if f.action == "error":
            raise can.CanOperationError("injected bus error on send")
        if f.action == "hold":
            with self._lock:
                self._held.append(can.Message(
                    arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id, is_fd=msg.is_fd,
                    bitrate_switch=msg.bitrate_switch, data=bytes(msg.data)))
            return
        if f.action == "corrupt":
            self.inner.send(self._corrupt(msg, f), timeout)
            return
        if f.action == "duplicate":
            self.inner.send(msg, timeout)
            self.inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._rx_pending:
            return self._rx_pending.popleft(), False
        msg = self.inner.recv(timeout)
        if msg is None:
            return None, False
        f = self._match(msg, "rx")
        if f is None:
            return msg, False
        if f.action == "drop":
            return None, False
        if f.action == "error":
            raise can.CanOperationError("injected bus error on receive")
        if f.action == "corrupt":
            return self._corrupt(msg, f), False
        if f.action == "duplicate":
            self._rx_pending.append(msg)
            return msg, False
        return msg, False

    def __repr__(self) -> str:  # pragma: no cover - diagnostics
        return f"<FaultyBus {self.channel_info} faults={self._faults!r}>"
