"""Session recording with python-can writers (BLF and ASC, both hold CAN FD) and replay."""

from __future__ import annotations

import time

import can
import pytest

from field.link import ControllerState, OutcomeClass, open_link
from field.link.can_backend import decode_recording, read_recording, replay
from field.link.codec import kind_of_frame_id
from field.link.messages import Ack, Outcome


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_session_recorded_both_directions_and_replayed(tmp_path, suffix, make_cmd):
    path = tmp_path / f"session{suffix}"
    with open_link(f"twin://?delay_ms=30&record={path}") as link:
        cmd = make_cmd(link.new_command_id(), logs=2)
        link.send_grasp(cmd)
        assert link.wait_outcome(cmd.command_id, 2.0).outcome_class is OutcomeClass.SUCCESS
        time.sleep(0.12)  # a few heartbeats
        controller = link.controller
    frames = read_recording(path)
    kinds = [kind_of_frame_id(m.arbitration_id) for m in frames]
    for k in ("GraspCommand", "Ack", "Outcome", "StatusRequest", "Status", "LaptopHeartbeat", "CraneHeartbeat"):
        assert k in kinds, k
    assert all(m.is_fd for m in frames)
    sent = [m for m in frames if kind_of_frame_id(m.arbitration_id) == "GraspCommand"]
    assert len(sent) == 1 and len(sent[0].data) == 64 and not sent[0].is_rx
    decoded = decode_recording(path)
    msgs = [m for _, _, m in decoded]
    assert cmd in msgs and Ack(cmd.command_id, True) in msgs
    assert any(isinstance(m, Outcome) and m.command_id == cmd.command_id for m in msgs)
    hb = [m.heartbeat_counter for _, k, m in decoded if k == "LaptopHeartbeat"]
    assert hb == sorted(hb) and len(set(hb)) == len(hb) > 1  # modifier_callback advanced them

    # replay with the original timing keeps the spacing of the frames
    span = frames[-1].timestamp - frames[0].timestamp
    t0 = time.perf_counter()
    replayed = list(replay(path, realtime=True))
    assert len(replayed) == len(frames)
    assert time.perf_counter() - t0 >= 0.8 * span

    # replaying the laptop's side at a controller is refused: the id was executed already
    bus = can.Bus(interface="virtual", channel=f"replay-{suffix[1:]}", fd=True)
    try:
        from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
        from field.link.can_backend import CanControllerTransport

        ex = FixedOutcomeExecutor(delay_s=0.0)
        twin = CraneController(ControllerConfig(no_journal=True, insecure_link=True), ex)
        twin._decisions = dict(controller._decisions)  # the same crane, which remembers executed ids
        tr = CanControllerTransport(bus=can.Bus(interface="virtual", channel=f"replay-{suffix[1:]}", fd=True))
        tr.start(twin)
        try:
            list(replay(path, bus, only=("GraspCommand",)))
            time.sleep(0.2)
        finally:
            tr.close()
            twin.close()
        assert ex.executed == []  # the identical frame gets its original answer, not a second run
        assert twin.status().current_command_id == 0 and twin.state is ControllerState.IDLE
    finally:
        bus.shutdown()


def test_bad_record_path(tmp_path):
    from field.link.can_backend import LockedWriter

    with pytest.raises(ValueError, match="blf"):
        LockedWriter(tmp_path / "x.trc")  # TRC drops CAN FD frames


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_recording_survives_channel_names_with_large_numbers(tmp_path, suffix):
    """python-can turns the digits of a channel name into the BLF channel number; a virtual
    bus named "trial-88983136" once failed the link with a 16-bit overflow."""
    from field.link.can_backend import LockedWriter

    path = tmp_path / f"rec{suffix}"
    writer = LockedWriter(path)
    for ch in ("trial-88983136", 3, None, "vcan0"):
        writer.on_message_received(can.Message(arbitration_id=0x101, data=bytes(64), is_fd=True, channel=ch,
                                               timestamp=time.time()))
    writer.stop()
    frames = read_recording(path)
    assert len(frames) == 4 and all(len(m.data) == 64 for m in frames)
