"""CAN backend of the crane link (python-can), laptop side and crane side.

The bus is opened the python-can way: ``can.Bus(interface=..., channel=..., fd=True, ...)`` with
everything not given resolved by python-can itself (``can.rc``, ``CAN_*`` environment variables,
``~/can.conf`` ...), so the same URL works on socketcan, PCAN, Kvaser or the virtual bus:

* ``can://virtual/ch0?bitrate=500000&data_bitrate=2000000`` -> interface ``virtual``, channel ``ch0``
* ``can://socketcan/can0``
* ``can://remote/127.0.0.1:54701/ch0`` -> python-can-remote client ``ws://127.0.0.1:54701/``; the
  server (``python -m can_remote -H 127.0.0.1 -p 54701 -i virtual -c ch0 --fd``) decides the
  channel it serves
* ``can://`` or ``can://?context=NAME`` -> no interface/channel given: python-can's config resolution

All frames are CAN FD (``fd=1`` is implied; ``fd=0`` is refused). Frames are built with
``check=True``. Heartbeats go out with ``bus.send_periodic(..., modifier_callback=...)`` which
advances the heartbeat counter, the E2E counter and the CRC each period. One ``can.Notifier``
per bus. With ``record_path`` (``.blf`` or ``.asc``, both hold CAN FD) every frame of the session,
both directions, is written with python-can's writers; :func:`read_recording` / :func:`replay`
read it back.
"""

from __future__ import annotations

import copy
import secrets
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import can

from field.errors import LinkError
from field.link.base import CraneLink, LinkConfig, LinkURL, track_resource, untrack_resource
from field.link.codec import (
    CRANE_TO_LAPTOP,
    LAPTOP_TO_CRANE,
    SIGNED_KIND,
    frame_id,
    kind_of_can_frame,
    kind_of_frame_id,
)

#: python-can config keys accepted as URL query parameters (passed to can.Bus as given)
_INT_KEYS = {"bitrate", "data_bitrate", "rx_queue_size"}
_BOOL_KEYS = {"receive_own_messages", "fd"}
_RECORD_SUFFIXES = (".blf", ".asc")


def bus_kwargs_from_url(url: LinkURL, query: dict[str, str] | None = None) -> dict[str, Any]:
    """python-can ``Bus`` keyword arguments for a ``can://`` URL (see the module docstring)."""
    if url.scheme != "can":
        raise ValueError(f"not a can:// URL: {url}")
    q = dict(url.query if query is None else query)
    kw: dict[str, Any] = {}
    if url.netloc:
        kw["interface"] = url.netloc
        if url.netloc == "remote":
            hostport, _, _channel = url.path.partition("/")
            if not hostport:
                raise ValueError("can://remote/ needs HOST:PORT, e.g. can://remote/127.0.0.1:54701/ch0")
            kw["channel"] = f"ws://{hostport}/"
        elif url.path:
            kw["channel"] = url.path
    elif url.path:
        kw["channel"] = url.path
    for key, value in q.items():
        if key in _INT_KEYS:
            try:
                kw[key] = int(value)
            except ValueError as exc:
                raise ValueError(f"can:// URL parameter {key} must be an integer, got {value!r}") from exc
        elif key in _BOOL_KEYS:
            kw[key] = value.lower() in ("1", "true", "yes", "on")
        else:
            kw[key] = value  # e.g. context=..., passed through to python-can
    if kw.get("fd") is False:
        raise ValueError("the crane link protocol needs CAN FD (64-byte grasp command); drop fd=0")
    kw["fd"] = True
    return kw


# --- bus wrappers ---------------------------------------------------------------------------


class ProxyBus(can.BusABC):
    """A bus that forwards to another bus (base for recording and fault injection).

    Periodic sending uses python-can's thread-based task on the proxy, so ``modifier_callback``
    works on every interface (python-can-remote's own periodic task ignores it).
    """

    def __init__(self, inner: can.BusABC, **kwargs: Any):
        self.inner = inner
        super().__init__(channel=getattr(inner, "channel_info", "proxy"), **kwargs)
        self.channel_info = f"{type(self).__name__}({getattr(inner, 'channel_info', inner)})"

    @property
    def protocol(self) -> can.CanProtocol:  # type: ignore[override]
        return self.inner.protocol

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.inner.recv(timeout), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self.inner.shutdown()


class LockedWriter(can.Listener):
    """A python-can writer made safe for the notifier thread and senders at the same time."""

    def __init__(self, path: str | Path):
        path = Path(path)
        if path.suffix.lower() not in _RECORD_SUFFIXES:
            raise ValueError(f"record_path must end in .blf or .asc (CAN FD capable), got {path.name!r}")
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._writer = can.Logger(str(path))
        self._lock = threading.Lock()
        self._closed = False

    def on_message_received(self, msg: can.Message) -> None:
        ch = msg.channel
        if not (isinstance(ch, int) and 0 <= ch <= 0xFFFF):
            # BLF stores a 16-bit channel number and python-can derives it from the digits of a
            # channel *name* ("trial-88983136" -> 88983136, which does not fit): record such
            # frames on the writer's default channel instead of failing the link.
            msg = copy.copy(msg)
            msg.channel = None
        with self._lock:
            if not self._closed:
                self._writer.on_message_received(msg)

    def stop(self) -> None:
        with self._lock:
            if not self._closed:
                self._closed = True
                self._writer.stop()


class TapBus(ProxyBus):
    """Records every frame sent through it (received frames are recorded by the notifier)."""

    def __init__(self, inner: can.BusABC, recorder: LockedWriter | None):
        super().__init__(inner)
        self.recorder = recorder

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)
        if self.recorder is not None:
            rec = can.Message(
                timestamp=time.time(),
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_fd=msg.is_fd,
                bitrate_switch=msg.bitrate_switch,
                data=bytes(msg.data),
                is_rx=False,
                channel=msg.channel,
            )
            self.recorder.on_message_received(rec)


def open_bus(kwargs: dict[str, Any]) -> can.BusABC:
    """``can.Bus(**kwargs)`` with a clear :class:`LinkError` on failure."""
    try:
        return can.Bus(**kwargs)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
        raise LinkError(
            f"cannot open CAN bus {kwargs}: {exc}. Check the interface name, channel and driver "
            f"(python-can config: can.rc / CAN_* environment / ~/can.conf)"
        ) from exc


def make_frame(kind: str, data: bytes, bitrate_switch: bool = True) -> can.Message:
    return can.Message(
        arbitration_id=frame_id(kind),
        is_extended_id=False,
        is_fd=True,
        bitrate_switch=bitrate_switch,
        data=data,
        check=True,
    )


class _CanEndpoint:
    """Shared plumbing: bus (+tap), notifier, heartbeat task, tracking, close."""

    def _setup_bus(self, bus: can.BusABC, record_path: str | None, on_message: Callable[[can.Message], None], description: str) -> None:
        self._recorder = LockedWriter(record_path) if record_path else None
        self._bus = TapBus(bus, self._recorder)
        track_resource(self._bus, description, self._bus.shutdown)
        listeners: list[Any] = [_Dispatch(on_message, self._on_bus_error)]
        if self._recorder is not None:
            listeners.append(self._recorder)
        self._notifier = can.Notifier(self._bus, listeners, timeout=0.05)
        self._hb_task: Any = None

    def _start_heartbeat(self, kind: str, period_s: float, first: bytes, modify: Callable[[can.Message], None]) -> None:
        msg = make_frame(kind, first)
        self._hb_task = self._bus.send_periodic(msg, period_s, modifier_callback=modify)

    def _on_bus_error(self, exc: Exception) -> None:  # overridden
        pass

    def _shutdown_bus(self) -> None:
        try:
            if self._hb_task is not None:
                self._hb_task.stop()
        finally:
            try:
                self._notifier.stop(timeout=1.0)
            finally:
                try:
                    self._bus.shutdown()
                finally:
                    untrack_resource(self._bus)
                    if self._recorder is not None:
                        self._recorder.stop()


class _Dispatch(can.Listener):
    def __init__(self, on_message: Callable[[can.Message], None], on_error: Callable[[Exception], None]):
        self._on_message = on_message
        self._on_error = on_error

    def on_message_received(self, msg: can.Message) -> None:
        self._on_message(msg)

    def on_error(self, exc: Exception) -> None:
        self._on_error(exc)


# --- laptop side ----------------------------------------------------------------------------


class CanLink(_CanEndpoint, CraneLink):
    """Laptop side over CAN FD. ``bus`` may be an already open python-can bus (owned: closed
    with the link), e.g. a fault-injecting wrapper in tests."""

    backend_name = "can"

    def __init__(self, bus_kwargs: dict[str, Any] | None = None, config: LinkConfig | None = None, *, bus: can.BusABC | None = None):
        CraneLink.__init__(self, config)
        from field.link.codec import LaptopHeartbeat

        self.bus_kwargs = dict(bus_kwargs or {})
        raw = bus if bus is not None else open_bus(self.bus_kwargs)
        # a random start: two laptops on one bus are two heartbeat streams far apart
        self._hb_counter = secrets.randbits(31)
        try:
            self._setup_bus(raw, self.config.record_path, self._on_message, f"CanLink bus {raw.channel_info}")
            _, first = self._wire(LaptopHeartbeat(self._hb_counter))
            self._start_heartbeat("LaptopHeartbeat", self.config.heartbeat_period_s, first, self._next_heartbeat)
        except BaseException:
            raw.shutdown()
            untrack_resource(getattr(self, "_bus", None))
            raise

    @classmethod
    def from_url(cls, url: LinkURL, config: LinkConfig | None = None, *, bus: can.BusABC | None = None) -> "CanLink":
        cfg, q = url.pop_link_config(config)
        link = cls(bus_kwargs_from_url(url, q) if bus is None else None, cfg, bus=bus)
        link._await_controller()
        return link

    def _next_heartbeat(self, msg: can.Message) -> None:
        from field.link.codec import LaptopHeartbeat

        self._hb_counter = (self._hb_counter + 1) & 0xFFFFFFFF
        msg.data = bytearray(self._wire(LaptopHeartbeat(self._hb_counter))[1])

    def _on_message(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.stats.bus_errors += 1
            return
        kind = kind_of_can_frame(msg.arbitration_id, msg.is_extended_id, msg.is_fd)
        if msg.is_remote_frame:
            return
        if kind in CRANE_TO_LAPTOP:
            self._deliver(kind, bytes(msg.data))
        elif kind in SIGNED_KIND:
            self._deliver_signature(SIGNED_KIND[kind], bytes(msg.data))

    def _on_bus_error(self, exc: Exception) -> None:
        self._fail(exc)

    def _transmit(self, kind: str, data: bytes) -> None:
        self._bus.send(make_frame(kind, data), timeout=0.2)

    def _close_transport(self) -> None:
        self._shutdown_bus()


# --- crane side -----------------------------------------------------------------------------


class _Periodic:
    """Calls ``send()`` every ``period_s`` on a thread of its own (the crane's heartbeat: a signed
    heartbeat is two frames, which python-can's periodic task cannot send); ``stop()`` joins it."""

    def __init__(self, period_s: float, send: Callable[[], None], on_error: Callable[[Exception], None]):
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period_s, send, on_error), daemon=True,
                                        name="crane-heartbeat")
        self._thread.start()

    def _run(self, period_s: float, send: Callable[[], None], on_error: Callable[[Exception], None]) -> None:
        next_s = time.monotonic()
        while not self._stop.wait(max(0.0, next_s - time.monotonic())):
            next_s += period_s
            try:
                send()
            except Exception as exc:  # a bus error: counted; the laptop's staleness check covers a silent crane
                on_error(exc)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(1.0)


class CanControllerTransport(_CanEndpoint):
    """Crane side over CAN FD: feeds frames to a :class:`field.controller.CraneController`. A
    signed crane frame goes out as two frames, the data frame and then its signature frame
    (:func:`field.link.signing.carriage_frames`), never interleaved with another pair."""

    def __init__(self, bus_kwargs: dict[str, Any] | None = None, *, bus: can.BusABC | None = None, heartbeat_period_s: float = 0.05, record_path: str | None = None):
        self.bus_kwargs = dict(bus_kwargs or {})
        self._raw = bus if bus is not None else open_bus(self.bus_kwargs)
        self.heartbeat_period_s = heartbeat_period_s
        self.record_path = record_path
        self.controller: Any = None
        self._closed = False
        self.bus_errors = 0
        self._send_lock = threading.Lock()

    @classmethod
    def from_url(cls, url: LinkURL, *, bus: can.BusABC | None = None, heartbeat_period_s: float = 0.05) -> "CanControllerTransport":
        cfg, q = url.pop_link_config()
        return cls(bus_kwargs_from_url(url, q) if bus is None else None, bus=bus, heartbeat_period_s=heartbeat_period_s, record_path=cfg.record_path)

    def start(self, controller: Any) -> None:
        self.controller = controller
        controller.attach(self.send)
        try:
            self._setup_bus(self._raw, self.record_path, self._on_message, f"CanControllerTransport bus {self._raw.channel_info}")
            self._hb_task = _Periodic(self.heartbeat_period_s, self._send_heartbeat, self._on_bus_error)
        except BaseException:
            self._raw.shutdown()
            raise

    def _send_heartbeat(self) -> None:
        self.send("CraneHeartbeat", self.controller.heartbeat_frame())

    def _on_message(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame:
            return
        kind = kind_of_can_frame(msg.arbitration_id, msg.is_extended_id, msg.is_fd)
        if kind in LAPTOP_TO_CRANE:
            self.controller.on_frame(kind, bytes(msg.data), self.send)

    def _on_bus_error(self, exc: Exception) -> None:
        self.bus_errors += 1

    def send(self, kind: str, data: bytes) -> None:
        from field.link.signing import carriage_frames

        if self._closed:
            return
        with self._send_lock:
            for k, frame in carriage_frames(kind, data):
                self._bus.send(make_frame(k, frame), timeout=0.2)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if hasattr(self, "_bus"):
            self._shutdown_bus()
        else:
            self._raw.shutdown()


# --- recordings -----------------------------------------------------------------------------


def read_recording(path: str | Path) -> list[can.Message]:
    """All frames of a session recording (.blf / .asc), in file order."""
    path = Path(path)
    if not path.exists():
        raise LinkError(f"recording {path} does not exist")
    with can.LogReader(str(path)) as reader:
        return list(reader)


def decode_recording(path: str | Path, secoc_key: str | Path | None = None) -> list[tuple[float, str, Any]]:
    """``(timestamp, kind, message or ProtocolError)`` for every link frame of a recording.

    ``secoc_key``: the key file of an authenticated session (MACs are checked, freshness is not:
    a recording is old by nature)."""
    from field.errors import ProtocolError
    from field.link.codec import decode

    secoc = None
    if secoc_key is not None:
        from field.link.secoc import SecOC

        secoc = SecOC.from_key_file(secoc_key)
    out: list[tuple[float, str, Any]] = []
    for msg in read_recording(path):
        kind = kind_of_frame_id(msg.arbitration_id)
        if kind is None or kind in SIGNED_KIND:
            continue  # not a link frame, or a signature frame (what it signs is decoded)
        try:
            data = bytes(msg.data) if secoc is None else secoc.verify(kind, bytes(msg.data), check_freshness=False)
            out.append((msg.timestamp, kind, decode(kind, data).message))
        except ProtocolError as exc:
            out.append((msg.timestamp, kind, exc))
    return out


def replay(path: str | Path, bus: can.BusABC | None = None, *, realtime: bool = False, only: tuple[str, ...] | None = None) -> Iterator[can.Message]:
    """Yield the frames of a recording (optionally sending them on ``bus``).

    ``realtime=True`` keeps the original timing (python-can's ``MessageSync``); ``only``
    restricts to message kinds (e.g. ``LAPTOP_TO_CRANE`` to replay the laptop's side).
    """
    path = Path(path)
    if not path.exists():
        raise LinkError(f"recording {path} does not exist")
    with can.LogReader(str(path)) as reader:
        source: Any = can.MessageSync(reader, timestamps=True) if realtime else reader
        for msg in source:
            if only is not None and kind_of_frame_id(msg.arbitration_id) not in only:
                continue
            if bus is not None:
                bus.send(
                    can.Message(
                        arbitration_id=msg.arbitration_id,
                        is_extended_id=msg.is_extended_id,
                        is_fd=msg.is_fd,
                        bitrate_switch=msg.bitrate_switch,
                        data=bytes(msg.data),
                        check=True,
                    )
                )
            yield msg
