"""The link seam: URL forms, lazy backends, python-can config resolution, twin, latency."""

from __future__ import annotations

import subprocess
import sys
import threading
import uuid

import pytest

from field.errors import LinkError
from field.link import open_link
from field.link.base import BACKENDS, CONTROLLER_TRANSPORTS, LinkConfig, LinkURL


def test_import_loads_no_backend_library():
    code = (
        "import sys, field.link, field.controller, field.errors\n"
        "bad = [m for m in ('can', 'zenoh', 'cantools', 'e2e', 'torch', 'pybullet') if m in sys.modules]\n"
        "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "[]", out.stderr


def test_registries_name_importable_classes():
    import importlib

    for registry in (BACKENDS, CONTROLLER_TRANSPORTS):
        for name, entry in registry.items():
            module, _, attr = entry.partition(":")
            assert hasattr(importlib.import_module(module), attr), (name, entry)


@pytest.mark.parametrize(
    "url, expected",
    [
        ("can://virtual/ch0?bitrate=500000&data_bitrate=2000000", {"interface": "virtual", "channel": "ch0", "bitrate": 500000, "data_bitrate": 2000000, "fd": True}),
        ("can://socketcan/can0", {"interface": "socketcan", "channel": "can0", "fd": True}),
        ("can://pcan/PCAN_USBBUS1?fd=1", {"interface": "pcan", "channel": "PCAN_USBBUS1", "fd": True}),
        ("can://remote/127.0.0.1:54701/ch0", {"interface": "remote", "channel": "ws://127.0.0.1:54701/", "fd": True}),
        ("can://", {"fd": True}),
        ("can://?context=bench", {"context": "bench", "fd": True}),
    ],
)
def test_can_url_to_python_can_kwargs(url, expected):
    from field.link.can_backend import bus_kwargs_from_url

    u = LinkURL.parse(url)
    _, q = u.pop_link_config()
    assert bus_kwargs_from_url(u, q) == expected


def test_bad_urls_and_options():
    from field.link.can_backend import bus_kwargs_from_url
    from field.link.zenoh_backend import ZenohTarget

    with pytest.raises(ValueError):
        LinkURL.parse("virtual/ch0")
    with pytest.raises(LinkError, match="unknown link backend"):
        open_link("serial://ttyUSB0")
    with pytest.raises(ValueError, match="CAN FD"):
        bus_kwargs_from_url(LinkURL.parse("can://virtual/x?fd=0"))
    with pytest.raises(ValueError):
        LinkConfig(heartbeat_period_s=0.5, heartbeat_timeout_s=0.2)
    cfg, rest = LinkURL.parse("can://virtual/x?heartbeat_ms=20&max_pile_age_s=10&record=a.blf").pop_link_config()
    assert (cfg.heartbeat_period_s, cfg.safety.max_pile_age_s, cfg.record_path, rest) == (0.02, 10.0, "a.blf", {})
    t = ZenohTarget.from_url(LinkURL.parse("zenoh://127.0.0.1:7447/crane1?lease_ms=800"), {"lease_ms": "800"})
    assert (t.endpoint, t.crane, t.prefix, t.lease_ms) == ("tcp/127.0.0.1:7447", "crane1", "loggrasp/crane1", 800)
    t = ZenohTarget.from_url(LinkURL.parse("zenoh://crane2?config=z.json5"), {"config": "z.json5", "prefix": "site/a"})
    assert (t.endpoint, t.config_path, t.prefix) == (None, "z.json5", "site/a")
    with pytest.raises(ValueError):
        ZenohTarget.from_url(LinkURL.parse("zenoh://crane3"), {})


def test_can_url_without_interface_uses_python_can_config(monkeypatch, make_cmd):
    """``can://`` hands resolution to python-can: here the CAN_* environment variables."""
    from field.controller import run_controller

    channel = f"env-{uuid.uuid4().hex[:8]}"
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", channel)
    stop, ready = threading.Event(), threading.Event()
    th = threading.Thread(target=run_controller, args=(f"can://virtual/{channel}?insecure=1", "fixed", stop), kwargs={"ready_event": ready})
    th.start()
    try:
        assert ready.wait(5)
        with open_link("can://?insecure=1") as link:
            assert link._bus.inner.channel_info.endswith(channel) or channel in str(link._bus.inner.channel_info)
            cmd = make_cmd(link.new_command_id())
            assert link.send_grasp(cmd).accepted
    finally:
        stop.set()
        th.join(5)


def test_twin_backend(make_cmd):
    with open_link("twin://?delay_ms=10&outcome=fewer") as link:
        cmd = make_cmd(link.new_command_id(), logs=3)
        link.send_grasp(cmd)
        out = link.wait_outcome(cmd.command_id, 2.0)
        assert out.outcome_class.name == "FEWER"
        assert link.controller.executor.executed == [cmd.command_id]
    with pytest.raises(ValueError, match="unknown twin"):
        open_link("twin://?bogus=1")


def test_latency_function():
    from field.link.latency import local_controller, measure_latency

    with local_controller("can-virtual") as url:
        s = measure_latency(url, n=20, warmup=2)
    assert s.n == 20 and 0 < s.p50_ms <= s.p99_ms <= s.max_ms < 1000
    s = measure_latency("twin://", n=10, mode="accept", warmup=1)
    assert s.mode == "accept" and s.p50_ms > 0


def test_leak_tracking_sees_an_unclosed_link():
    """What the autouse ``no_leaked_links`` fixture relies on."""
    from field.link.base import open_resources

    before = len(open_resources())
    link = open_link("twin://")
    try:
        assert len(open_resources()) == before + 2  # the laptop bus and the twin's bus
    finally:
        link.close()
    assert len(open_resources()) == before


def test_open_link_from_a_config_mapping(make_cmd):
    with open_link({"url": "twin://", "status_timeout_s": 0.5, "safety": {"max_pile_age_s": 5.0}}) as link:
        assert link.config.status_timeout_s == 0.5 and link.config.safety.max_pile_age_s == 5.0
        from field.errors import CommandRejected

        with pytest.raises(CommandRejected, match="rescan"):
            link.send_grasp(make_cmd(link.new_command_id(), age_s=6.0))
    with pytest.raises(ValueError, match="url"):
        open_link({"status_timeout_s": 0.5})
    with pytest.raises(ValueError, match="unknown"):
        open_link({"url": "twin://", "bogus": 1})
