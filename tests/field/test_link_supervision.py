"""No grasp runs unsupervised (issue 39): a command is accepted only from a live laptop (CAN: a
fresh, in-sequence heartbeat stream; Zenoh: a liveliness token), and a running grasp aborts within
the laptop timeout once its laptop is not live, whatever happened before.

Each path has its own test: CAN and Zenoh; a laptop that never sent a heartbeat, one frozen from
its first frame, one lost mid-grasp. The frozen-from-the-first-frame case ran to SUCCESS before
(``_peer_loss`` aborted only "late and ever_seen")."""

from __future__ import annotations

import time
import uuid

import can
import pytest

from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
from field.errors import LinkError
from field.link import ControllerState, LinkConfig, OutcomeClass, RejectReason
from field.link.can_backend import CanControllerTransport, CanLink, ProxyBus
from field.link.codec import Encoder, LaptopHeartbeat, decode, frame_id
from field.link.messages import Ack, Outcome
from tests.field.helpers import SupervisingLaptop, wait_until

TIMEOUT_S = 1.0  # the controller's laptop timeout in these tests [s]
GRASP_S = 3.0  # a grasp that outlasts the laptop timeout [s]


class Crane:
    """A controller driven frame by frame; its acks and published frames collected."""

    def __init__(self, grasp_s: float = GRASP_S):
        self.ex = FixedOutcomeExecutor(delay_s=grasp_s)
        self.ctl = CraneController(ControllerConfig(laptop_timeout_s=TIMEOUT_S, no_journal=True, insecure_link=True),
                                   self.ex)
        self.published: list = []
        self.ctl.attach(lambda k, d: self.published.append(decode(k, d).message))
        self.ctl.start()

    def command(self, data: tuple[str, bytes], peer: str | None = None) -> Ack:
        acks: list[Ack] = []
        self.ctl.on_frame(*data, lambda k, d: acks.append(decode(k, d).message), peer=peer)
        assert len(acks) == 1, acks
        return acks[0]

    def outcome(self, command_id: int) -> Outcome | None:
        return next((m for m in self.published if isinstance(m, Outcome) and m.command_id == command_id), None)

    def close(self) -> None:
        self.ctl.close()


@pytest.fixture
def crane():
    c = Crane()
    yield c
    c.close()


def _refused_unsupervised(crane: Crane, ack: Ack) -> None:
    assert not ack.accepted and ack.reason is RejectReason.UNSUPERVISED, ack
    time.sleep(0.2)
    assert crane.ex.executed == [] and crane.ctl.state is ControllerState.IDLE


# --- CAN: the laptop is its heartbeat stream ---------------------------------------------------


@pytest.mark.safety_case(error="loss", link="can", measure="supervision: a command only from a laptop with a fresh, "
                         "in-sequence heartbeat stream", reaction="refused UNSUPERVISED, never executed")
def test_can_a_command_from_a_laptop_that_never_sent_a_heartbeat_is_refused(crane, make_cmd):
    _refused_unsupervised(crane, crane.command(Encoder().encode(make_cmd(11))))


@pytest.mark.safety_case(error="loss", link="can", measure="supervision: a heartbeat frozen from its first frame "
                         "never makes a live laptop", reaction="refused UNSUPERVISED, never executed")
def test_can_a_command_from_a_laptop_frozen_from_its_first_frame_is_refused(crane, make_cmd):
    """The reproduction of issue 39: the same heartbeat frame again and again never makes a live
    laptop; its command ran to SUCCESS for the whole grasp before."""
    enc = Encoder()
    frozen = enc.encode(LaptopHeartbeat(5000))
    for _ in range(10):
        crane.ctl.on_frame(*frozen, lambda k, d: None)
        time.sleep(0.02)
    ack = crane.command(enc.encode(make_cmd(12)))
    if ack.accepted:  # the defect: show what it led to, then fail
        assert wait_until(lambda: crane.outcome(12) is not None, timeout_s=GRASP_S + 5)
        pytest.fail(f"an unsupervised command was accepted and ended {crane.outcome(12).outcome_class.name}")
    _refused_unsupervised(crane, ack)


@pytest.mark.safety_case(abort="no supervising laptop at any time during a grasp", link="can",
                         reaction="the grasp aborts within the laptop timeout (ABORTED)")
def test_can_a_grasp_aborts_within_the_laptop_timeout_when_its_laptop_goes_silent(crane, make_cmd):
    with SupervisingLaptop(crane.ctl) as laptop:
        assert crane.command(laptop.encode(make_cmd(13))).accepted
        t0 = time.monotonic()
        laptop.pause()  # the heartbeat stops mid-grasp
        assert wait_until(lambda: crane.outcome(13) is not None, timeout_s=GRASP_S + 5)
    assert crane.outcome(13).outcome_class is OutcomeClass.ABORTED
    assert time.monotonic() - t0 < GRASP_S - 0.5  # aborted after the 1 s timeout, not at the end


def test_can_a_supervised_grasp_runs_to_its_end(crane, make_cmd):
    with SupervisingLaptop(crane.ctl) as laptop:
        assert crane.command(laptop.encode(make_cmd(14))).accepted
        assert wait_until(lambda: crane.outcome(14) is not None, timeout_s=GRASP_S + 5)
    assert crane.outcome(14).outcome_class is OutcomeClass.SUCCESS


# --- Zenoh: the laptop is its liveliness token -------------------------------------------------


@pytest.mark.safety_case(error="loss", link="zenoh", measure="supervision: a command only from a laptop whose "
                         "liveliness token is live", reaction="refused UNSUPERVISED, never executed")
def test_zenoh_a_command_from_a_laptop_without_a_token_is_refused(crane, make_cmd):
    _refused_unsupervised(crane, crane.command(Encoder().encode(make_cmd(21)), peer="zenoh:ab12"))


@pytest.mark.safety_case(error="masquerade", link="zenoh", measure="supervision: the sender a command names must "
                         "hold a live liveliness token", reaction="refused UNSUPERVISED, never executed")
def test_zenoh_a_command_naming_another_laptop_than_the_live_one_is_refused(crane, make_cmd):
    """A frame whose attachment names a laptop with no token is unsupervised even while another
    laptop's token is live (that laptop did not send it)."""
    crane.ctl.peer_present("zenoh:cafe")
    _refused_unsupervised(crane, crane.command(Encoder().encode(make_cmd(22)), peer="zenoh:ab12"))


@pytest.mark.safety_case(abort="no supervising laptop at any time during a grasp", link="zenoh",
                         reaction="the grasp aborts at once (ABORTED)")
def test_zenoh_a_grasp_aborts_when_its_laptops_token_goes(crane, make_cmd):
    crane.ctl.peer_present("zenoh:ab12")
    assert crane.command(Encoder().encode(make_cmd(23)), peer="zenoh:ab12").accepted
    t0 = time.monotonic()
    crane.ctl.peer_gone("zenoh:ab12")
    assert wait_until(lambda: crane.outcome(23) is not None, timeout_s=GRASP_S + 5)
    assert crane.outcome(23).outcome_class is OutcomeClass.ABORTED
    assert time.monotonic() - t0 < GRASP_S - 0.5


def test_zenoh_a_grasp_with_a_live_token_runs_to_its_end(crane, make_cmd):
    crane.ctl.peer_present("zenoh:ab12")
    assert crane.command(Encoder().encode(make_cmd(24)), peer="zenoh:ab12").accepted
    assert wait_until(lambda: crane.outcome(24) is not None, timeout_s=GRASP_S + 5)
    assert crane.outcome(24).outcome_class is OutcomeClass.SUCCESS


# --- the laptop: it opens a link only once the controller hears it ------------------------------


class FrozenHeartbeat(ProxyBus):
    """A laptop bus whose heartbeat is stuck at its first frame (a frozen sender)."""

    first: bytes | None = None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == frame_id("LaptopHeartbeat"):
            self.first = self.first or bytes(msg.data)
            msg = can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, is_fd=True, data=self.first)
        self.inner.send(msg, timeout)


def test_can_a_laptop_with_a_frozen_heartbeat_cannot_open_the_link(make_cmd):
    """End to end on can://virtual: the controller answers, but hears no live laptop, so the
    link is refused at open with that reason (before, a command from it ran to SUCCESS)."""
    channel = f"frozen-{uuid.uuid4().hex[:8]}"
    ctl = CraneController(ControllerConfig(laptop_timeout_s=TIMEOUT_S, no_journal=True, insecure_link=True), FixedOutcomeExecutor(delay_s=GRASP_S))
    transport = CanControllerTransport(bus=can.Bus(interface="virtual", channel=channel, fd=True))
    transport.start(ctl)
    ctl.start()
    try:
        cfg = LinkConfig(insecure=True, heartbeat_timeout_s=1.0, connect_timeout_s=2.0)
        link = CanLink(config=cfg, bus=FrozenHeartbeat(can.Bus(interface="virtual", channel=channel, fd=True)))
        with pytest.raises(LinkError, match="hears no live laptop"):
            link._await_controller()
        assert link.closed and ctl.status().laptops == 0
    finally:
        ctl.close()
        transport.close()
