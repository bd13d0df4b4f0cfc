"""A fault-injecting python-can bus wrapper, for tests and field drills.

Wrap any bus and arm faults; each armed fault applies to the next ``count`` matching frames::

    bus = FaultyBus(can.Bus(interface="virtual", channel="ch0", fd=True))
    bus.arm("drop", kind="GraspCommand")            # the next command frame vanishes
    bus.arm("corrupt", kind="Ack", direction="rx")  # the next received ack has a flipped bit
    bus.arm("drop", kind="CraneHeartbeat", direction="rx", count=None)  # all of them, until disarm()

Actions: ``drop``, ``duplicate`` (sent / delivered twice), ``corrupt`` (one bit flipped at
``byte``), ``hold`` (kept back until :meth:`release`; frames behind it overtake it = reordering),
``error`` (the operation raises ``can.CanOperationError`` = a bus error), ``freeze`` (sent frames
only: the first matching frame is sent again in place of each later one = a stuck sender).

For soak tests, :class:`FaultPlan` draws a random fault (drop, duplicate, corrupt, delay,
reorder) per frame from a seed, and :class:`ChaosChannel` applies it to any ``send(kind,
bytes)`` — a CAN bus (``FaultyBus(bus, plan=...)``) or a Zenoh link's transmit / deliver hooks.
"""

from __future__ import annotations

import collections
import heapq
import itertools
import random
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import can

from field.link.can_backend import ProxyBus
from field.link.codec import kind_of_frame_id

ACTIONS = ("drop", "duplicate", "corrupt", "hold", "error", "freeze")


@dataclass
class _Fault:
    action: str
    kind: str | None
    direction: str
    count: int | None  # None = until disarmed
    byte: int
    bit: int
    frozen: bytes | None = None  # freeze: the data every matching frame is sent with


CHAOS_ACTIONS = ("drop", "duplicate", "corrupt", "delay", "reorder")


@dataclass
class FaultPlan:
    """Random faults, reproducible from ``seed``: each frame of ``kinds`` (all if None) gets at
    most one action, drawn with the probabilities in ``p`` (action -> probability)."""

    seed: int = 0
    p: dict[str, float] = field(default_factory=lambda: {a: 0.01 for a in CHAOS_ACTIONS})
    kinds: tuple[str, ...] | None = None
    max_delay_s: float = 0.02  # a delayed frame arrives up to this much later [s]

    def __post_init__(self) -> None:
        bad = set(self.p) - set(CHAOS_ACTIONS)
        if bad or sum(self.p.values()) > 1 or min(self.p.values(), default=0) < 0:
            raise ValueError(f"FaultPlan.p: actions from {CHAOS_ACTIONS} with probabilities summing to <= 1, "
                             f"got {self.p}")
        self._rng = random.Random(self.seed)
        self._lock = threading.Lock()

    def choose(self, kind: str | None) -> str | None:
        """The fault for one frame of ``kind``, or None."""
        if self.kinds is not None and kind not in self.kinds:
            return None
        with self._lock:
            x = self._rng.random()
        for action, prob in self.p.items():
            if x < prob:
                return action
            x -= prob
        return None

    def delay_s(self) -> float:
        with self._lock:
            return self._rng.uniform(0.0, self.max_delay_s)


class ChaosChannel:
    """Applies a :class:`FaultPlan` to the frames pushed through ``send(kind, data)``.

    ``reorder`` holds a frame until the next frame of the same kind has gone (which overtakes it);
    ``delay`` sends it from a timer thread. :meth:`close` stops the timer (held or pending frames
    are then lost, like frames on a bus that is switched off).
    """

    def __init__(self, plan: FaultPlan, send: Callable[[str, bytes], None]):
        self.plan, self._send = plan, send
        self.injected: collections.Counter = collections.Counter()  # (action, kind) -> count
        self._held: dict[str, list[bytes]] = {}
        self._due: list[tuple[float, int, str, bytes]] = []
        self._seq = itertools.count()
        self._cond = threading.Condition()
        self._closed = False
        self._timer = threading.Thread(target=self._run_timer, name="chaos-delay", daemon=True)
        self._timer.start()

    def push(self, kind: str, data: bytes) -> None:
        action = self.plan.choose(kind)
        if action is not None:
            self.injected[(action, kind)] += 1
        if action == "drop":
            return
        if action == "delay":
            with self._cond:
                heapq.heappush(self._due, (time.monotonic() + self.plan.delay_s(), next(self._seq), kind, data))
                self._cond.notify()
            return
        if action == "reorder":
            with self._cond:
                self._held.setdefault(kind, []).append(data)
            return
        self._send(kind, _flip(data) if action == "corrupt" else data)
        if action == "duplicate":
            self._send(kind, data)
        with self._cond:
            overtaken = self._held.pop(kind, [])
        for old in overtaken:
            self._send(kind, old)

    def _run_timer(self) -> None:
        while True:
            with self._cond:
                while not self._closed and (not self._due or self._due[0][0] > time.monotonic()):
                    self._cond.wait(None if not self._due else max(0.0, self._due[0][0] - time.monotonic()))
                if self._closed:
                    return
                _, _, kind, data = heapq.heappop(self._due)
            try:
                self._send(kind, data)
            except Exception:  # the bus / session closed under a late frame
                pass

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._timer.join(2.0)


def _flip(data: bytes) -> bytes:
    b = bytearray(data)
    if b:
        b[len(b) // 2] ^= 0x08
    return bytes(b)


class FaultyBus(ProxyBus):
    """A bus with armed faults (:meth:`arm`) and, with ``plan``, random ones on every sent frame."""

    def __init__(self, inner: can.BusABC, plan: FaultPlan | None = None):
        super().__init__(inner)
        self._chaos = ChaosChannel(plan, self._send_kind) if plan is not None else None
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
        if action in ("hold", "freeze") and direction != "tx":
            raise ValueError(f"{action!r} applies to sent frames only (direction='tx')")
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

    @property
    def chaos_injected(self) -> collections.Counter:
        """(action, kind) -> how many random faults the plan injected."""
        return collections.Counter() if self._chaos is None else self._chaos.injected

    def _send_kind(self, kind: str, data: bytes) -> None:
        from field.link.can_backend import make_frame

        self.inner.send(make_frame(kind, data))

    def shutdown(self) -> None:
        if self._chaos is not None:
            self._chaos.close()
        super().shutdown()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        f = self._match(msg, "tx")
        if f is None:
            kind = kind_of_frame_id(msg.arbitration_id)
            if self._chaos is not None and kind is not None:
                self._chaos.push(kind, bytes(msg.data))
            else:
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
        if f.action == "freeze":
            with self._lock:
                if f.frozen is None:
                    f.frozen = bytes(msg.data)
                data = f.frozen
            self.inner.send(can.Message(arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                                        is_fd=msg.is_fd, bitrate_switch=msg.bitrate_switch, data=data), timeout)
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
