"""Shared fixtures of the field tests: leak check, free ports, controller processes, rigs."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from field.link.base import close_leaked_resources, open_resources
from field.link.latency import stop_process as terminate
from field.link.messages import GraspCommand

PY = sys.executable
REPO = Path(__file__).resolve().parents[2]

# default reach envelope base of field.controller.ReachEnvelope
BASE_E, BASE_N, BASE_H = 744_000.0, 7_112_000.0, 50.0


@pytest.fixture(autouse=True)
def no_leaked_links() -> Iterator[None]:
    """Fail a test that leaves a CAN bus or a Zenoh session (opened by field.link) open."""
    before = set(open_resources())
    yield
    leaked = [d for d in open_resources() if d not in before]
    if leaked:
        close_leaked_resources()
        pytest.fail(f"test leaked link resources: {leaked}")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def make_cmd() -> Callable[..., GraspCommand]:
    """``make_cmd(command_id, de=, dn=, dz=, heading_deg=, width_m=, logs=, age_s=)``."""
    return _make_cmd


def _make_cmd(command_id: int, *, de: float = 5.0, dn: float = 0.0, dz: float = 0.0, heading_deg: float = 30.0,
             width_m: float = 0.9, logs: int = 2, age_s: float = 0.0) -> GraspCommand:
    """A command that the default controller accepts (offsets from the crane base)."""
    return GraspCommand.from_metres(command_id, BASE_E + de, BASE_N + dn, BASE_H + dz, heading_deg, width_m, logs, time.time() - age_s)


_CONTROLLER_MAIN = """
import json, signal, sys, threading
from field.controller import FixedOutcomeExecutor, controller_config_from_dict, run_controller
a = json.loads(sys.argv[1])
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
ready = threading.Event()
def announce():
    ready.wait()
    print("READY", flush=True)
threading.Thread(target=announce, daemon=True).start()
run_controller(a["url"], FixedOutcomeExecutor(**a["executor"]), stop, controller_config_from_dict(a["config"]), ready_event=ready)
"""


class ControllerProcess:
    """A crane controller twin in its own process (``run_controller``)."""

    def __init__(self, url: str, config: dict[str, Any], executor: dict[str, Any]):
        self.url, self.config, self.executor = url, config, executor
        self.proc: subprocess.Popen | None = None

    def start(self, timeout_s: float = 20.0) -> "ControllerProcess":
        args = json.dumps({"url": self.url, "config": self.config, "executor": self.executor})
        import tempfile

        self._stderr = tempfile.TemporaryFile(mode="w+")  # a file, not a pipe: never blocks the child
        self.proc = subprocess.Popen([PY, "-c", _CONTROLLER_MAIN, args], stdout=subprocess.PIPE, stderr=self._stderr,
                                     text=True, cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        line = _readline_with_timeout(self.proc, timeout_s)
        if line.strip() != "READY":
            self.kill()
            self._stderr.seek(0)
            err = self._stderr.read()[-4000:]
            raise RuntimeError(f"controller process did not start: {line!r} {err}")
        return self

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None:
            terminate(self.proc)
        if self.proc is not None and self.proc.stdout:
            self.proc.stdout.close()
        if getattr(self, "_stderr", None) is not None:
            self._stderr.close()
            self._stderr = None


def _readline_with_timeout(proc: subprocess.Popen, timeout_s: float) -> str:
    out: list[str] = []
    t = threading.Thread(target=lambda: out.append(proc.stdout.readline()), daemon=True)
    t.start()
    t.join(timeout_s)
    return out[0] if out else ""


class RemoteCanServer:
    """``python -m can_remote`` bound to 127.0.0.1, serving a virtual CAN FD channel."""

    def __init__(self) -> None:
        self.port = free_port()
        self.channel = f"lg-{uuid.uuid4().hex[:8]}"
        self.proc = subprocess.Popen(
            [PY, "-m", "can_remote", "-H", "127.0.0.1", "-p", str(self.port), "-i", "virtual", "-c", self.channel, "--fd"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                    return
            except OSError:
                if self.proc.poll() is not None:
                    raise RuntimeError("can_remote server exited") from None
                time.sleep(0.05)
        self.close()
        raise RuntimeError("can_remote server did not start")

    @property
    def url(self) -> str:
        return f"can://remote/127.0.0.1:{self.port}/{self.channel}"

    def close(self) -> None:
        terminate(self.proc)


@dataclass
class Rig:
    """A laptop URL with a controller behind it, whatever the backend."""

    name: str
    url: str
    log_path: Path
    start_controller: Callable[[], None]
    stop_controller: Callable[[], None]
    kill_controller: Callable[[], None]
    cleanup: list[Callable[[], None]] = field(default_factory=list)

    def executed(self) -> list[int]:
        from field.controller import read_execution_log

        return read_execution_log(self.log_path) if self.log_path.exists() else []


BACKENDS = ["can-virtual", "can-remote", "zenoh"]

#: controller config used by rigs (short timeouts: fast tests)
#: (a rig without secoc_key= in its URL opts out of authentication explicitly; with a key, frames are
#: authenticated whatever insecure_link says)
RIG_CONFIG = {"max_pile_age_s": 5.0, "laptop_timeout_s": 1.0, "heartbeat_period_s": 0.05, "insecure_link": True}
#: executor used by rigs: 50 ms per grasp, 1.5 s for 9-log grasps (a slow command), 7 logs -> COLLISION
RIG_EXECUTOR = {"delay_s": 0.05, "delay_by_target_logs": {"9": 1.5}}


@pytest.fixture(scope="session")
def link_key(tmp_path_factory) -> Path:
    """A generated SecOC key (mode 0600) and beside it the crane's signing key pair
    (:func:`signing_key_of`): the rigs run authenticated, as a field link should."""
    from field.link.secoc import generate_key_file
    from field.link.signing import generate_signing_key

    key = generate_key_file(tmp_path_factory.mktemp("secoc") / "link.key")
    generate_signing_key(signing_key_of(key))
    return key


def signing_key_of(key: str | Path) -> Path:
    """Where a test keeps the crane's signing key that goes with SecOC key ``key`` (its public key: + .pub)."""
    key = Path(key)
    return key.with_name(key.name + ".sign")


def keyed(url: str, key: Path | None) -> str:
    """``url`` with its SecOC key and the crane's keys (public for the laptop, signing for the crane:
    one URL serves both ends of a rig), or without one the explicit opt-out ``insecure=1``."""
    if key is None:
        return f"{url}{'&' if '?' in url else '?'}insecure=1"
    sign = signing_key_of(key)
    return f"{url}{'&' if '?' in url else '?'}secoc_key={key}&crane_key={sign}.pub&signing_key={sign}"


def build_rig(name: str, tmp_path: Path, *, config: dict | None = None, executor: dict | None = None,
              key: Path | None = None) -> Rig:
    """A rig for backend ``name``; with ``key`` both ends use authenticated frames."""
    config = {**RIG_CONFIG, **(config or {})}
    log_path = tmp_path / f"executed-{uuid.uuid4().hex[:6]}.jsonl"
    executor = {**RIG_EXECUTOR, **(executor or {}), "log_path": str(log_path)}
    if name == "can-virtual":
        from field.controller import FixedOutcomeExecutor, controller_config_from_dict, run_controller

        url = keyed(f"can://virtual/lg-{uuid.uuid4().hex[:8]}", key)
        state: dict[str, Any] = {}

        def start() -> None:
            stop, ready = threading.Event(), threading.Event()
            th = threading.Thread(target=run_controller, args=(url, FixedOutcomeExecutor(**executor), stop,
                                                                controller_config_from_dict(config)),
                                  kwargs={"ready_event": ready}, daemon=True)
            th.start()
            assert ready.wait(10)
            state.update(stop=stop, thread=th)

        def stop_() -> None:
            if "stop" in state:
                state.pop("stop").set()
                state.pop("thread").join(10)

        rig = Rig(name, url, log_path, start, stop_, stop_)
        rig.cleanup.append(stop_)
        return rig
    if name == "can-remote":
        server = RemoteCanServer()
        url = keyed(server.url, key)
    elif name == "zenoh":
        server = None
        url = keyed(f"zenoh://127.0.0.1:{free_port()}/crane-{uuid.uuid4().hex[:6]}", key)
    else:
        raise ValueError(name)
    holder: dict[str, ControllerProcess] = {}

    def start_p() -> None:
        holder["p"] = ControllerProcess(url, config, executor).start()

    def stop_p() -> None:
        if "p" in holder:
            holder.pop("p").stop()

    def kill_p() -> None:
        if "p" in holder:
            p = holder.pop("p")
            p.kill()
            p.stop()

    rig = Rig(name, url, log_path, start_p, stop_p, kill_p)
    rig.cleanup.append(stop_p)
    if server is not None:
        rig.cleanup.append(server.close)
    return rig


@pytest.fixture
def rig_factory(tmp_path: Path, link_key: Path) -> Iterator[Callable[..., Rig]]:
    """``rig_factory(name, config=..., executor=...)`` -> a started, authenticated :class:`Rig`
    (cleaned up); ``secoc=False`` for plain frames."""
    made: list[Rig] = []

    def make(name: str, *, config: dict | None = None, executor: dict | None = None, start: bool = True,
             secoc: bool = True) -> Rig:
        r = build_rig(name, tmp_path, config=config, executor=executor, key=link_key if secoc else None)
        made.append(r)
        if start:
            r.start_controller()
        return r

    yield make
    for r in made:
        for c in r.cleanup:
            c()


@pytest.fixture(params=BACKENDS)
def rig(request: pytest.FixtureRequest, tmp_path: Path, link_key: Path) -> Iterator[Rig]:
    """Every backend, authenticated (the contract suite runs with a generated SecOC key)."""
    r = build_rig(request.param, tmp_path, key=link_key)
    try:
        r.start_controller()
        yield r
    finally:
        for c in r.cleanup:
            c()


@pytest.fixture
def port() -> int:
    """A free TCP port on 127.0.0.1."""
    return free_port()


@pytest.fixture
def controller_process(tmp_path: Path) -> Iterator[Callable[..., ControllerProcess]]:
    """``controller_process(url, config={...}, executor={...})`` -> a started controller process
    (rig defaults; ``executor["log_path"]`` defaults to ``tmp_path/executed.jsonl``); stopped
    at teardown."""
    made: list[ControllerProcess] = []

    def start(url: str, *, config: dict | None = None, executor: dict | None = None) -> ControllerProcess:
        ex = {**RIG_EXECUTOR, "log_path": str(tmp_path / "executed.jsonl"), **(executor or {})}
        p = ControllerProcess(url, {**RIG_CONFIG, **(config or {})}, ex).start()
        made.append(p)
        return p

    yield start
    for p in made:
        p.kill()
        p.stop()
