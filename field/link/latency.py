"""Command -> acknowledgement round-trip latency of a crane link, and local rigs to measure it.

``measure_latency(url, n)`` sends ``n`` grasp commands and times each ``send_grasp`` call (the
ack round trip, including encode/E2E/decode on both sides). ``mode="reject"`` (the default)
sends commands far outside the reach envelope, so every one is answered with an OUT_OF_REACH
rejection and nothing moves — safe against a real crane. ``mode="accept"`` sends executable
commands (waiting, untimed, for each outcome before the next): use it against a twin only.

``local_controller(backend)`` starts a controller twin for a backend on this machine and yields
the laptop URL: ``"can-virtual"`` (in-process), ``"can-remote"`` (``python -m can_remote`` bound
to 127.0.0.1 + a controller process), ``"zenoh"`` (a controller process listening on
``tcp/127.0.0.1``), ``"twin"`` (``twin://``). With ``secoc_key`` both ends use authenticated
frames (:mod:`field.link.secoc`), so the cost of the MACs can be measured.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, replace
from typing import Iterator

from field.errors import CommandRejected, LinkError
from field.link.messages import GraspCommand, RejectReason


@dataclass(frozen=True)
class LatencyStats:
    url: str
    mode: str
    n: int
    p50_ms: float
    p99_ms: float
    mean_ms: float
    max_ms: float
    label: str = ""  # e.g. the backend name, "+secoc" when authenticated

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _percentile(sorted_ms: list[float], q: float) -> float:
    if not sorted_ms:
        return float("nan")
    k = min(len(sorted_ms) - 1, max(0, int(round(q * (len(sorted_ms) - 1)))))
    return sorted_ms[k]


def measure_latency(url: str, n: int = 200, *, mode: str = "reject", warmup: int = 5, timeout_s: float = 1.0,
                    base_en_h_m: tuple[float, float, float] | None = None) -> LatencyStats:
    """p50/p99 of the command -> ack round trip over ``n`` commands on the link at ``url``.

    ``base_en_h_m`` is the crane base (SWEREF 99 TM easting, northing, height [m]); default: the
    controller twin's default :class:`field.controller.ReachEnvelope`.
    """
    from field.link.base import open_link

    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if mode not in ("reject", "accept"):
        raise ValueError(f"mode must be 'reject' or 'accept', got {mode!r}")
    if base_en_h_m is None:
        from field.controller import ReachEnvelope

        r = ReachEnvelope()
        base_en_h_m = (r.base_easting_m, r.base_northing_m, r.base_height_m)
    e0, n0, h0 = base_en_h_m
    offset = 5.0 if mode == "accept" else 5_000.0  # 5 km away = certainly out of reach
    times: list[float] = []
    with open_link(url) as link:
        for i in range(warmup + n):
            cmd = GraspCommand.from_metres(link.new_command_id(), e0 + offset, n0, h0, 30.0, 0.9, 2, time.time())
            t0 = time.perf_counter()
            try:
                link.send_grasp(cmd, timeout_s=timeout_s)
                dt = time.perf_counter() - t0
                link.wait_outcome(cmd.command_id, timeout_s=30.0)
            except CommandRejected as exc:
                dt = time.perf_counter() - t0
                if mode == "accept" or exc.reason is not RejectReason.OUT_OF_REACH:
                    raise LinkError(f"latency run: unexpected rejection {exc.reason.name}: {exc}") from exc
            if i >= warmup:
                times.append(dt * 1000.0)
    times.sort()
    return LatencyStats(url, mode, len(times), _percentile(times, 0.50), _percentile(times, 0.99),
                        sum(times) / len(times), times[-1])


_CONTROLLER_MAIN = """
import json, signal, sys, threading
from field.controller import FixedOutcomeExecutor, run_controller
a = json.loads(sys.argv[1])
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
ready = threading.Event()
threading.Thread(target=lambda: (ready.wait(), print("READY", flush=True)), daemon=True).start()
run_controller(a["url"], FixedOutcomeExecutor(delay_s=a["delay_s"]), stop, ready_event=ready)
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_process(proc: subprocess.Popen) -> None:
    """Stop a server process: SIGTERM, then SIGKILL if it has not gone within 10 s."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


@contextlib.contextmanager
def _controller_process(url: str, delay_s: float) -> Iterator[None]:
    proc = subprocess.Popen([sys.executable, "-c", _CONTROLLER_MAIN, json.dumps({"url": url, "delay_s": delay_s})],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        line: list[str] = []
        t = threading.Thread(target=lambda: line.append(proc.stdout.readline()), daemon=True)
        t.start()
        t.join(30)
        if not line or line[0].strip() != "READY":
            raise LinkError(f"controller process for {url} did not start")
        yield
    finally:
        stop_process(proc)
        if proc.stdout:
            proc.stdout.close()


def _keyed(url: str, secoc_key: str | None) -> str:
    """``url`` with the rig's keys: ``secoc_key`` and, when one lies beside it (``KEY.sign``, made by
    ``loggrasp link-key --crane-signing KEY.sign``), the crane's signing key: signed answers."""
    from field.link.link_config import keyed_url

    sign = None if secoc_key is None else f"{secoc_key}.sign"
    return keyed_url(url, secoc_key, sign if sign is not None and os.path.exists(sign) else None)


@contextlib.contextmanager
def local_controller(backend: str, *, delay_s: float = 0.0, secoc_key: str | None = None) -> Iterator[str]:
    """Start a controller twin for ``backend`` on this machine; yields the laptop URL (with
    ``secoc_key``: both ends authenticated)."""
    with _local_controller(backend, delay_s, secoc_key) as url:
        yield url


@contextlib.contextmanager
def _local_controller(backend: str, delay_s: float, secoc_key: str | None) -> Iterator[str]:
    if backend == "twin":
        yield _keyed(f"twin://?delay_ms={delay_s * 1000:g}", secoc_key)
        return
    if backend == "can-virtual":
        from field.controller import FixedOutcomeExecutor, controller_in_thread

        url = _keyed(f"can://virtual/lat-{uuid.uuid4().hex[:8]}", secoc_key)
        with controller_in_thread(url, FixedOutcomeExecutor(delay_s=delay_s), start_timeout_s=10.0):
            yield url
        return
    if backend == "can-remote":
        port, channel = _free_port(), f"lat-{uuid.uuid4().hex[:8]}"
        server = subprocess.Popen([sys.executable, "-m", "can_remote", "-H", "127.0.0.1", "-p", str(port), "-i",
                                   "virtual", "-c", channel, "--fd"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 20
            while True:
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                    break
                except OSError:
                    if time.monotonic() > deadline or server.poll() is not None:
                        raise LinkError("can_remote server did not start") from None
                    time.sleep(0.05)
            url = _keyed(f"can://remote/127.0.0.1:{port}/{channel}", secoc_key)
            with _controller_process(url, delay_s):
                yield url
        finally:
            stop_process(server)
        return
    if backend == "zenoh":
        url = _keyed(f"zenoh://127.0.0.1:{_free_port()}/lat-{uuid.uuid4().hex[:6]}", secoc_key)
        with _controller_process(url, delay_s):
            yield url
        return
    raise ValueError(f"unknown backend {backend!r}; choose twin, can-virtual, can-remote or zenoh")


def measure_backends(n: int = 200, mode: str = "reject", backends: tuple[str, ...] = ("can-virtual", "can-remote", "zenoh"),
                     secoc_key: str | None = None) -> list[LatencyStats]:
    """Latency of every local backend rig (what the benchmark reports); ``secoc_key``:
    authenticated frames on both ends."""
    out = []
    for b in backends:
        with local_controller(b, secoc_key=secoc_key) as url:
            s = measure_latency(url, n, mode=mode)
            out.append(replace(s, label=b + (" +SecOC" if secoc_key else "")))
    return out
