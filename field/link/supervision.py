"""Who is on the other end: heartbeat supervision and the commanding peer, crane side.

A heartbeat counts only when it is *fresh and in sequence*, the way CANopen / J1939 heartbeat
consumers judge a producer: its own 32-bit counter advanced by 1..``max_gap`` since the last one
of the same stream, and its E2E counter advanced by the same amount. A frozen sender (the same
frame again and again, or a fresh E2E counter around a stuck heartbeat counter) therefore never
keeps a laptop alive, and neither does the first frame of a new stream on its own.

A laptop starts its heartbeat counter at a random value, so two laptops on one CAN bus are two
streams far apart: :class:`HeartbeatStreams` follows each, and :class:`PeerTracker` knows which
peers are live, which one commands the running grasp, and says when a second one appears. On
Zenoh the peers are the laptops' liveliness tokens (present until their token goes).
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable

log = logging.getLogger(__name__)


@dataclass
class _Stream:
    heartbeat: int  # last heartbeat counter (uint32)
    e2e: int  # last E2E counter (uint8)
    sid: int  # stream id
    born_s: float  # monotonic time of its first frame [s]
    last_s: float | None = None  # monotonic time of the last in-sequence heartbeat; None = not yet [s]


class HeartbeatStreams:
    """Laptop heartbeat streams on a bus without source addresses (thread-safe)."""

    def __init__(self, timeout_s: float, max_gap: int = 8, clock: Callable[[], float] = time.monotonic):
        self.timeout_s = timeout_s
        self.max_gap = max_gap
        self._clock = clock
        self._streams: list[_Stream] = []
        self._ids = itertools.count(1)
        self._lock = threading.Lock()

    def feed(self, heartbeat: int, e2e: int) -> int | None:
        """One decoded heartbeat; returns the id of the stream it refreshed, or ``None`` when it
        refreshed nothing (frozen, repeated, or the first frame of a possible new stream)."""
        now = self._clock()
        with self._lock:
            self._prune(now)
            for s in self._streams:
                d = (heartbeat - s.heartbeat) & 0xFFFFFFFF
                if d == 0:
                    return None  # a frozen or repeated heartbeat: refreshes nothing
                if d <= self.max_gap and (e2e - s.e2e) & 0xFF == d & 0xFF:
                    s.heartbeat, s.e2e, s.last_s = heartbeat, e2e, now
                    return s.sid
            self._streams.append(_Stream(heartbeat, e2e, next(self._ids), now))
            return None

    def _prune(self, now: float) -> None:
        """Forget streams silent for a timeout (a candidate that never continued, too)."""
        self._streams = [s for s in self._streams if now - (s.born_s if s.last_s is None else s.last_s) <= self.timeout_s]


class PeerTracker:
    """Live laptops, the commanding one, and a clear word when a second one appears.

    Peers are strings: ``"can:<stream id>"`` (refreshed by in-sequence heartbeats, live for
    ``timeout_s``) or ``"zenoh:<zid>"`` (present until :meth:`gone`).
    """

    def __init__(self, timeout_s: float, clock: Callable[[], float] = time.monotonic):
        self.timeout_s = timeout_s
        self._clock = clock
        self._seen: dict[str, float | None] = {}  # peer -> last refresh (None = present until gone)
        self._order: list[str] = []  # first-established first
        self._warned: set[str] = set()
        self._lock = threading.Lock()

    def refresh(self, peer: str) -> bool:
        """An in-sequence heartbeat from ``peer``; True when it is a newly live peer."""
        return self._mark(peer, self._clock())

    def present(self, peer: str) -> bool:
        """A presence signal (Zenoh liveliness token) appeared; True when newly live."""
        return self._mark(peer, None)

    def gone(self, peer: str) -> None:
        with self._lock:
            self._seen.pop(peer, None)
            if peer in self._order:
                self._order.remove(peer)
            self._warned.discard(peer)

    def _mark(self, peer: str, t: float | None) -> bool:
        with self._lock:
            new = peer not in self._live_locked()
            self._seen[peer] = t
            if peer not in self._order:
                self._order.append(peer)
            if new:
                self._warn_if_second(peer)
            return new

    def _live_locked(self) -> list[str]:
        now = self._clock()
        live = [p for p in self._order if p in self._seen
                and (self._seen[p] is None or now - self._seen[p] <= self.timeout_s)]
        for p in [p for p in self._order if p not in live]:
            self._order.remove(p)
            self._seen.pop(p, None)
            self._warned.discard(p)
        return live

    def _warn_if_second(self, peer: str) -> None:
        others = [p for p in self._live_locked() if p != peer]
        if others and peer not in self._warned:
            self._warned.add(peer)
            log.warning("a second laptop (%s) appeared beside %s: only one laptop may command a crane; "
                        "its frames disturb the commanding laptop's counters - disconnect one", peer, others[0])

    def live(self) -> list[str]:
        """Live peers, first-established first."""
        with self._lock:
            return self._live_locked()

    def primary(self) -> str | None:
        """The first-established live peer (the one a command without a named sender came from)."""
        live = self.live()
        return live[0] if live else None

    def is_live(self, peer: str) -> bool:
        return peer in self.live()
