"""The trial's Foxglove view (field/trial_view.py, field/trial_can.py): the recording read back
with the ``mcap`` package's reader, the live server on loopback with a WebSocket client, a port
in use, decoded CAN frames. A whole trial's recording: tests/field/test_field_trial.py and the
demo in tests/test_cli.py."""

from __future__ import annotations

import json
import socket

import pytest

from field.trial_view import MCAP_NAME, TrialView, ViewError, open_live_view, record_view
from tests.field.mcap_check import read_mcap


def test_log_times_never_go_back_within_a_topic_and_the_file_is_renamed(tmp_path):
    view = TrialView(tmp_path / ".part")
    view.line("first", t_s=10.0)
    view.line("earlier but logged later", t_s=5.0)  # e.g. a thread's line that lost the race
    view.state("SENDING", 7.0)
    assert view.close(tmp_path) == tmp_path / MCAP_NAME
    assert view.close(tmp_path) is None  # safe twice
    assert not (tmp_path / ".part").exists()
    m = read_mcap(tmp_path / MCAP_NAME)
    assert m.times_ns["/trial/log"] == [10_000_000_000, 10_000_000_000]
    assert m.times_ns["/trial/state"] == [7_000_000_000] and m.json["/trial/state"][0]["final_state"] == "SENDING"
    assert m.schemas["/trial/log"] == "foxglove.Log" and m.encodings["/trial/log"] == "protobuf"


def test_a_failure_to_log_never_reaches_the_trial(tmp_path):
    view = TrialView(tmp_path / ".part")
    view.planned(object(), object(), t_s=1.0)  # not a plan: recorded as an error, not raised
    view.line("still logging", t_s=2.0)
    assert view.errors and "plan" in view.errors[0]
    view.close(tmp_path)
    assert read_mcap(tmp_path / MCAP_NAME).times_ns["/trial/log"] == [2_000_000_000]


def test_a_record_that_is_gone_drops_its_recording(tmp_path):
    (tmp_path / "rec").mkdir()
    view = TrialView(tmp_path / "rec" / ".part")
    view.line("x", t_s=1.0)
    import shutil

    shutil.rmtree(tmp_path / "rec")  # a trial stopped before its record was published
    assert view.close(None) is None
    assert list(tmp_path.iterdir()) == []


def _busy_port() -> socket.socket:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    return s


def test_a_port_in_use_is_a_clear_error_and_leaves_nothing(tmp_path):
    with _busy_port() as s:
        port = s.getsockname()[1]
        with pytest.raises(ViewError, match=rf"127\.0\.0\.1:{port}.*--foxglove"):
            open_live_view(tmp_path / "rec", port)
    assert list(tmp_path.iterdir()) == []
    assert open_live_view(tmp_path / "rec", None) is None


def test_live_view_serves_the_trial_on_loopback(tmp_path):
    """A Foxglove WebSocket client on 127.0.0.1 sees the channels advertised and the messages."""
    ws_client = pytest.importorskip("websockets.sync.client")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    live = open_live_view(tmp_path / "rec", port)
    try:
        assert live.port == port
        (tmp_path / "stage").mkdir()
        view = record_view(tmp_path / "stage", live, print)
        assert view is live and live.part_path.parent == tmp_path / "stage"
        with ws_client.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                               open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=10))["op"] == "serverInfo"
            view.line("reconstructing the pile", t_s=100.0)
            adv = json.loads(ws.recv(timeout=10))
            assert adv["op"] == "advertise" and adv["channels"][0]["topic"] == "/trial/log"
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": adv["channels"][0]["id"]}]}))
            import time

            deadline = time.monotonic() + 10
            got = b""
            while b"planning" not in got and time.monotonic() < deadline:
                view.line("planning", t_s=101.0)  # until the subscription has reached the server
                try:
                    got = ws.recv(timeout=0.5)
                except TimeoutError:
                    continue
            assert got[0] == 1 and int.from_bytes(got[1:5], "little") == 7  # message data, our subscription
            assert int.from_bytes(got[5:13], "little") == 101_000_000_000  # its log time [ns]
    finally:
        live.close(tmp_path / "stage")
    assert read_mcap(tmp_path / "stage" / MCAP_NAME).times_ns["/trial/log"][0] == 100_000_000_000
    assert _refused_within(port, 5.0), "the live server still listens after the view closed"


def _refused_within(port: int, timeout_s: float) -> bool:
    """Whether connections to 127.0.0.1:``port`` are refused within ``timeout_s`` (the server's
    listener closes asynchronously)."""
    import time

    deadline = time.monotonic() + timeout_s
    while True:
        with socket.socket() as s:
            try:
                s.connect(("127.0.0.1", port))
            except ConnectionRefusedError:
                return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)


def test_can_frames_decode_with_their_signals_and_checks():
    from field.link.codec import encode, frame_id
    from field.link.messages import ControllerState
    from field.link.codec import CraneHeartbeat
    from field.trial_can import decode_frame

    kind, data = encode(CraneHeartbeat(heartbeat_counter=42, state=ControllerState.EXECUTING), 3)
    f = decode_frame(5.0, frame_id(kind), data, True)
    assert f["kind"] == "CraneHeartbeat" and f["check"] == "ok" and f["direction"] == "rx"
    assert f["signals"]["State"] == "EXECUTING" and f["signals"]["HeartbeatCounter"] == 42
    assert f["crane_state"] == {"t_utc_s": 5.0, "source": "CraneHeartbeat", "heartbeat_counter": 42,
                                "state": "EXECUTING"}
    bad = bytearray(data)
    bad[-1] ^= 0xFF
    g = decode_frame(5.0, frame_id(kind), bytes(bad), True)
    assert "CRC" in g["check"] or "reserved" in g["check"] or "decode" in g["check"]
    assert "crane_state" not in g
    assert decode_frame(1.0, 0x7FF, b"\x00", False)["check"] == "unknown frame id"


def test_authenticated_frames_decode_from_their_authentic_part():
    import secrets

    from field.link.codec import encode, frame_id
    from field.link.messages import GraspCommand
    from field.link.secoc import SecOC
    from field.trial_can import decode_frame

    cmd = GraspCommand(command_id=9, easting_mm=743497383, northing_mm=7117721873, height_mm=249944,
                       heading_cdeg=10565, opening_width_mm=868, target_log_count=4, plan_timestamp_ms=1795329353000)
    kind, plain = encode(cmd, 5)
    wire = SecOC(secrets.token_bytes(32)).secure(kind, plain)
    f = decode_frame(1.0, frame_id(kind), wire, False, secured=True)
    assert f["check"] == "ok" and f["secured"] and f["signals"]["EastingMm"] == 743497383
    assert decode_frame(1.0, frame_id(kind), wire, False)["check"] != "ok"  # read as a plain frame it is not one
