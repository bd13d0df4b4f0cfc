"""Soak: thousands of authenticated commands under every transmission error class of IEC
61784-3, over the virtual CAN bus and over Zenoh on loopback, with supervision outages and
e-stops at random moments.

Faults injected (each lane: a laptop and a controller, one key file per lane = per crane):

- channel faults in both directions (:class:`field.link.faults.ChaosChannel`): loss (drop),
  unintended repetition (duplicate), corruption (one bit flipped), incorrect sequence (reorder),
  unacceptable delay (delay) - on commands, status queries, e-stops and every answer;
- insertion, masquerade and addressing (:mod:`tests.field.soak_intruder`): frames without the
  key, MACed with a foreign key or the wrong direction's key, another crane's genuine frames, and
  genuine frames under another kind's identifier / key expression, toward both sides;
- supervision outages on half the lanes: the laptop's heartbeat frames dropped or frozen (CAN),
  its liveliness token withdrawn (Zenoh), for longer than the controller's laptop timeout, now
  and then and as one of the lane's few long (3 s) grasps starts;
- e-stops at random moments during commands on a quarter of the lanes (confirmed by the laptop,
  then reset locally on the crane).

Invariants: every command's final state for the operator (:meth:`CraneLink.execute`) equals the
controller's (executed exactly once iff the operator is told it ran, same outcome; never run
when rejected); nothing runs that nobody sent; 0 commands executed unsupervised (none started
while its laptop was silenced beyond the laptop timeout, none started while the controller
counted no live laptop unless the controller aborted it, and every grasp running when its
laptop fell silent ended ABORTED within the timeout and a grace); 0 e-stops lost (the controller
saw every e-stop the laptop confirmed and was still stopped when the laptop returned, or the
laptop reported the failure); every class above injected at least once.

Counts: ``LOGGRASP_SOAK_CAN_N`` (default 4000), ``LOGGRASP_SOAK_ZENOH_N`` (default 2000) and
``LOGGRASP_SOAK_LANES`` (default 16 lanes per link, the waits on lost frames overlap);
``make safety-case`` runs 8,000 and 2,000, ``make soak`` 100,000 and 20,000 (docs/link-safety.md,
"Soak"). Loopback only.
"""

from __future__ import annotations

import collections
import os
import random
import threading
import time
import uuid
from dataclasses import dataclass, field

import can
import pytest

from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor
from field.errors import ControllerError, LinkError
from field.link.base import CommandFate, CraneLink, LinkConfig
from field.link.can_backend import CanControllerTransport, CanLink, make_frame
from field.link.faults import CHAOS_ACTIONS, ChaosChannel, FaultPlan, FaultyBus
from field.link.messages import ControllerState, GraspCommand, OutcomeClass, RejectReason
from field.link.secoc import generate_key_file
from field.link.signing import carriage_frames, generate_signing_key
from tests.field.conftest import signing_key_of
from tests.field.soak_intruder import Forger, Intruder, Outages

CAN_N = int(os.environ.get("LOGGRASP_SOAK_CAN_N", "4000"))
ZENOH_N = int(os.environ.get("LOGGRASP_SOAK_ZENOH_N", "2000"))
LANES = int(os.environ.get("LOGGRASP_SOAK_LANES", "16"))
P_FAULT = {"drop": 0.006, "duplicate": 0.006, "corrupt": 0.006, "delay": 0.006, "reorder": 0.006}
TO_CRANE = ("GraspCommand", "StatusRequest", "EStop")
TO_LAPTOP = ("Ack", "Outcome", "Status")
LAPTOP_TIMEOUT_S = 0.5  # the controller's laptop timeout [s]
ACK_TIMEOUT_S = 0.5
FORGE_PERIOD_S = 0.4  # mean time between forged frames per lane [s]
OUTAGE_EVERY_S = 6.0  # mean time between supervision outages on an outage lane [s]
OUTAGE_S = (2.0, 3.0)  # outage length range [s]
# silence after which nothing may start [s]: the timeout, plus frames (or a token) still on their way on a
# loaded machine
SUPERVISION_GRACE_S = {"can": LAPTOP_TIMEOUT_S + 1.0, "zenoh": 1.0}
P_ESTOP = 0.004  # per command, on an e-stop lane
ABORT_WAIT_S = 2.0  # a grasp started with no live laptop lasts this long unless aborted [s]
ESTOP_TIMEOUT_S = 2.0  # link.abort()'s deadline [s]
ESTOP_HANG_S = 10.0  # abort() not back by then: hung (it returns at its deadline + one send and status query) [s]
# the crane's states that only a local reset clears: a confirmed e-stop must find the crane in one
STOPPED = (ControllerState.ESTOP, ControllerState.FAULT)
# on outage lanes, 1 % of grasps (5 target logs) last 3 s, and an outage starts as one starts
SLOW_LOGS, SLOW_S, P_SLOW = 5, 3.0, 0.01
ABORT_LATE_S = 1.0  # a running grasp is aborted by the laptop timeout + grace + this [s]
MATRIX = {"corruption": "corrupt", "unintended repetition": "duplicate", "incorrect sequence": "reorder",
          "loss": "drop", "unacceptable delay": "delay", "insertion": "insertion", "masquerade": "masquerade",
          "addressing": "addressing"}


def _link_config(key: str) -> LinkConfig:
    # the laptop's authentication-failure threshold, like the controller's, sits above what a lane's forged and
    # corrupted frames reach in its window (it is tested on its own in test_link_signing)
    return LinkConfig(secoc_key_path=key, crane_key_path=f"{signing_key_of(key)}.pub", heartbeat_timeout_s=1.0,
                      status_timeout_s=0.5, connect_timeout_s=20.0, max_auth_failures=200)


class TimedExecutor(FixedOutcomeExecutor):
    """Instant outcomes; keeps when each command started and how many live laptops the
    controller counted then. A command that starts when the controller counts none (its laptop's
    liveness ran out between the acceptance and the start) lasts until the controller aborts it,
    or ``ABORT_WAIT_S``: the supervision must abort it."""

    def __init__(self) -> None:
        super().__init__(delay_s=0.0, delay_by_target_logs={SLOW_LOGS: SLOW_S})
        self.controller: CraneController | None = None
        self.started: dict[int, tuple[float, int]] = {}
        self.ended: dict[int, float] = {}  # command id -> time.monotonic() at the executor's return [s]
        self.due: dict[int, float] = {}  # command id -> when it would end unaborted (time.monotonic()) [s]
        self.on_slow_start = lambda: None  # called as a long grasp starts

    def execute(self, cmd, should_abort):
        live = self.controller.status(0).laptops
        self.started[cmd.command_id] = (time.monotonic(), live)
        self.due[cmd.command_id] = time.monotonic() + self.delay_by_target_logs.get(cmd.target_log_count, self.delay_s)
        if cmd.target_log_count == SLOW_LOGS:
            self.on_slow_start()
        end = time.monotonic() + ABORT_WAIT_S
        while not live and not should_abort() and time.monotonic() < end:
            time.sleep(0.005)
        try:
            return super().execute(cmd, should_abort)
        finally:
            self.ended[cmd.command_id] = time.monotonic()


class CountingController(CraneController):
    """The real controller, counting the e-stops it acted on.

    Counted as :meth:`CraneController.estop` starts, before it latches ESTOP under the controller's
    lock: a status answer that shows the latch is built under that lock, so the count is in before
    the laptop can confirm. ``estop()`` returns only after publishing a status frame, and the Zenoh
    transport answers status queries on another callback thread meanwhile; a count taken after it
    returned can trail the confirmation (``test_estop_counted_before_its_confirmation``)."""

    estops = 0

    def estop(self, why: str = "e-stop") -> None:
        self.estops += 1
        super().estop(why)


@dataclass
class Lane:
    """One laptop and one controller with faults injected on both sides."""

    backend: str
    link: CraneLink
    controller: CountingController
    executor: TimedExecutor
    closers: list = field(default_factory=list)
    fates: list[CommandFate] = field(default_factory=list)
    commands: list[GraspCommand] = field(default_factory=list)
    injected: list = field(default_factory=list)  # Counters of (chaos action, kind) -> count
    intruder: Intruder | None = None
    outages: Outages | None = None
    p_estop: float = 0.0
    p_slow: float = 0.0
    estops: collections.Counter = field(default_factory=collections.Counter)
    resets: collections.Counter = field(default_factory=collections.Counter)

    def last_id(self) -> int:
        return self.commands[-1].command_id if self.commands else 0

    def run(self, n: int, rng: random.Random, make_cmd) -> None:
        for _ in range(n):
            cmd = make_cmd(self.link.new_command_id(), **_variant(rng, self.p_slow))
            self.commands.append(cmd)
            stop = self._estop_soon(rng.uniform(0.0, 0.004)) if rng.random() < self.p_estop else None
            self.fates.append(self.link.execute(cmd, ack_timeout_s=ACK_TIMEOUT_S, outcome_timeout_s=10.0))
            if stop is not None:
                self._settle_estop(*stop)
            if self.controller.status(0).state is ControllerState.FAULT:  # MAC-failure safe state tripped
                self.resets["fault"] += 1
                self._reset()

    def _estop_soon(self, delay_s: float) -> tuple[threading.Thread, int, list]:
        """An e-stop from another thread ``delay_s`` from now, while the next command runs."""
        before, result = self.controller.estops, []

        def fire() -> None:
            time.sleep(delay_s)
            try:
                self.link.abort(timeout_s=ESTOP_TIMEOUT_S)
                result.append("confirmed")
            except LinkError as exc:
                result.append(f"reported: {exc}")

        t = threading.Thread(target=fire, name="soak-estop", daemon=True)
        t.start()
        return t, before, result

    def _settle_estop(self, t: threading.Thread, before: int, result: list) -> None:
        """Classify the e-stop: what the operator was told, and whether the crane acted on it and,
        before its local reset, is still stopped."""
        t.join(ESTOP_HANG_S)
        seen = self.controller.estops > before
        stopped = self.controller.state in STOPPED
        outcome = result[0] if result else "hung"
        key = "confirmed" if outcome == "confirmed" else "hung" if outcome == "hung" else "reported"
        crane = "not seen" if not seen else "seen by the crane" if stopped else "seen, crane not stopped"
        self.estops[(key, crane)] += 1
        self._reset()

    def _reset(self) -> None:
        """The crane's local reset (a grasp still winding down: retry)."""
        for _ in range(200):
            try:
                self.controller.reset_estop()
                return
            except ControllerError:
                time.sleep(0.01)

    def close(self) -> None:
        for c in reversed(self.closers):
            c()


def _variant(rng: random.Random, p_slow: float) -> dict:
    """Mostly executable commands; some the controller must refuse."""
    x = rng.random()
    if x < 0.08:
        return {"de": 50.0}  # out of reach
    if x < 0.12:
        return {"width_m": 2.0}  # wider than the grapple
    if x < 0.15:
        return {"age_s": 10.0}  # stale for the controller (5 s), fine for the laptop (30 s)
    if x < 0.15 + p_slow:
        return {"logs": SLOW_LOGS}  # a long grasp
    return {"logs": rng.randint(1, 4)}


def _controller(key: str) -> tuple[CountingController, TimedExecutor]:
    ex = TimedExecutor()
    # the MAC-failure safe state is tested on its own (test_link_safety); here its threshold sits
    # above the forged + corrupted frames a lane sees in its window, and a trip is reset and counted
    cfg = ControllerConfig(max_pile_age_s=5.0, laptop_timeout_s=LAPTOP_TIMEOUT_S, no_journal=True, secoc_key_path=key,
                           signing_key_path=str(signing_key_of(key)), max_mac_failures=200)
    ctl = CountingController(cfg, ex)
    ex.controller = ctl
    return ctl, ex


def _attach(lane: Lane, i: int, keys: list[str], make_cmd, to_crane, to_laptop, to_crane_kinds, silence, restore,
            modes: tuple[str, ...]) -> None:
    """The lane's intruder, and on some lanes supervision outages and e-stops."""
    forger = Forger(keys[i], keys[(i + 1) % len(keys)], make_cmd, seed=7 * i + 1, to_crane_kinds=to_crane_kinds)
    lane.intruder = Intruder(forger, to_crane, to_laptop, lane.last_id, FORGE_PERIOD_S, seed=7 * i + 2)
    lane.closers.append(lane.intruder.close)
    if i % 2 == 0:
        lane.outages = Outages(silence, restore, modes, OUTAGE_EVERY_S, OUTAGE_S, seed=7 * i + 3)
        lane.closers.append(lane.outages.close)
        lane.p_slow, lane.executor.on_slow_start = P_SLOW, lane.outages.kick
    if i % 4 in (1, 2):
        lane.p_estop = P_ESTOP


def can_lane(i: int, keys: list[str], make_cmd) -> Lane:
    seed = 1000 + 10 * i
    channel = f"soak-{uuid.uuid4().hex[:8]}"
    ctl, ex = _controller(keys[i])
    cbus = FaultyBus(can.Bus(interface="virtual", channel=channel, fd=True), FaultPlan(seed, P_FAULT, TO_LAPTOP))
    tr = CanControllerTransport(bus=cbus)
    tr.start(ctl)
    ctl.start()
    lbus = FaultyBus(can.Bus(interface="virtual", channel=channel, fd=True), FaultPlan(seed + 1, P_FAULT, TO_CRANE))
    link = CanLink(config=_link_config(keys[i]), bus=lbus)
    lane = Lane("can", link, ctl, ex, [ctl.close, tr.close, link.close], injected=[cbus.chaos_injected, lbus.chaos_injected])
    link._await_controller()
    # an intruder node: what the laptop's bus node sends reaches the crane and vice versa (a virtual
    # bus does not echo a node's own frames)
    _attach(lane, i, keys, make_cmd,
            to_crane=lambda k, d: lbus.inner.send(make_frame(k, d)),
            to_laptop=lambda k, d: [cbus.inner.send(make_frame(*f)) for f in carriage_frames(k, d)],
            to_crane_kinds=("GraspCommand", "StatusRequest", "LaptopHeartbeat"),
            silence=lambda mode: lbus.arm(mode, "LaptopHeartbeat", count=None), restore=lbus.disarm,
            modes=("drop", "freeze"))
    return lane


def zenoh_lane(i: int, keys: list[str], make_cmd, port: int) -> Lane:
    from field.link.base import LinkURL
    from field.link.zenoh_backend import ZenohControllerTransport, ZenohLink, ZenohTarget

    seed = 2000 + 10 * i

    class ChaosZenohLink(ZenohLink):
        """Faults on the laptop's sends (commands, status queries, e-stops) and on what it receives."""

        def __init__(self, target, config):
            self.tx = ChaosChannel(FaultPlan(seed + 1, P_FAULT, TO_CRANE), lambda k, d: ZenohLink._transmit(self, k, d))
            self.rx = ChaosChannel(FaultPlan(seed, P_FAULT, TO_LAPTOP), lambda k, d: ZenohLink._deliver(self, k, d))
            super().__init__(target, config)

        def _transmit(self, kind, data):
            self.tx.push(kind, data)

        def _deliver(self, kind, data):
            self.rx.push(kind, data)

        def _close_transport(self):
            self.tx.close()
            self.rx.close()
            super()._close_transport()

        def withdraw_token(self, _mode: str) -> None:
            self._token.undeclare()

        def restore_token(self) -> None:
            self._token = self._session.liveliness().declare_token(f"{self.keys.alive_laptop}/{self._session.zid()}")

    url = LinkURL.parse(f"zenoh://127.0.0.1:{port}/soak-{seed}")
    target = ZenohTarget.from_url(url, url.pop_link_config()[1])
    ctl, ex = _controller(keys[i])
    tr = ZenohControllerTransport(target)
    tr.start(ctl)
    ctl.start()
    link = ChaosZenohLink(target, _link_config(keys[i]))
    lane = Lane("zenoh", link, ctl, ex, [ctl.close, tr.close, link.close], injected=[link.tx.injected, link.rx.injected])
    link._await_controller()
    # the intruder's frames enter where the network's do: the laptop's session (toward the crane)
    # and the laptop's receive path (toward the laptop)
    _attach(lane, i, keys, make_cmd,
            to_crane=lambda k, d: ZenohLink._transmit(link, k, d), to_laptop=lambda k, d: ZenohLink._deliver(link, k, d),
            to_crane_kinds=("GraspCommand", "StatusRequest"),
            silence=link.withdraw_token, restore=link.restore_token, modes=("token withdrawn",))
    return lane


def soak(lanes: list[Lane], n: int, make_cmd) -> dict:
    per = [n // len(lanes) + (1 if i < n % len(lanes) else 0) for i in range(len(lanes))]
    errors: list[BaseException] = []

    def run(lane: Lane, k: int, seed: int) -> None:
        try:
            lane.run(k, random.Random(seed), make_cmd)
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(lane, k, i)) for i, (lane, k) in enumerate(zip(lanes, per))]
    t0 = time.monotonic()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    elapsed = time.monotonic() - t0
    print(f"\nsoak: {n} commands on {len(lanes)} lanes in {elapsed:.1f} s ({n / elapsed:.0f} commands/s)")
    for lane in lanes:  # no new faults; open outages end (their windows kept)
        for part in (lane.intruder, lane.outages):
            if part is not None:
                part.close()
    time.sleep(0.5)  # late frames (delays, reorders) land before the final check
    return check(lanes, elapsed)


def check_final_states(lane: Lane, tally: collections.Counter) -> None:
    """Every command's final state for the operator equals the controller's; exactly once."""
    executed = lane.executor.executed
    assert len(executed) == len(set(executed)), "a command ran twice"
    assert set(executed) <= {c.command_id for c in lane.commands}, "a command nobody sent ran"
    for cmd, fate in zip(lane.commands, lane.fates):
        final = fate
        if fate.executed is None or (fate.executed and fate.outcome is None):
            final = lane.link.fate(cmd.command_id)  # settled after the fact (late answers, a status)
            tally["settled afterwards"] += 1
        ran = cmd.command_id in executed
        assert final.executed is not None, f"final state UNKNOWN: {final}"
        assert final.executed == ran, f"operator told {final.final_state}, the crane {'ran' if ran else 'did not run'} it: {final}"
        if ran:
            assert final.outcome == lane.controller.outcome_of(cmd.command_id), final
        if fate.reason is not None:  # rejected: never run
            assert not ran, final
        tally[final.final_state] += 1
        tally["with notes"] += bool(final.notes)


def check_supervised(lane: Lane, tally: collections.Counter) -> None:
    """Nothing started while its laptop was silenced past the laptop timeout, nor while the
    controller itself counted no live laptop."""
    grace = SUPERVISION_GRACE_S[lane.backend]
    windows = [] if lane.outages is None else lane.outages.windows
    for cid, (t, live) in lane.executor.started.items():
        _check_aborted_when_silenced(lane, cid, t, windows, grace, tally)
        if not live:  # the laptop ran out between the acceptance and the start: aborted, not run
            outcome = lane.controller.outcome_of(cid)
            assert outcome is not None and outcome.outcome_class is OutcomeClass.ABORTED, (
                f"command {cid} started while the controller counted no live laptop and was not aborted: {outcome}")
            tally["started as supervision ran out, aborted"] += 1
        for mode, t_off, t_on in windows:
            assert not t_off + grace < t <= t_on, (
                f"command {cid} started {t - t_off:.2f} s into a supervision outage ({mode}, "
                f"{t_on - t_off:.2f} s long): executed unsupervised")
    tally["outages"] += len(windows)
    tally["outage s"] += sum(t_on - t_off for _, t_off, t_on in windows)
    tally["refused UNSUPERVISED"] += sum(r is RejectReason.UNSUPERVISED for _, r in lane.controller.rejections)


def _check_aborted_when_silenced(lane: Lane, cid: int, t_start: float, windows: list, grace: float,
                                 tally: collections.Counter) -> None:
    """A grasp running when its laptop fell silent, that would run on past ``grace`` into the outage,
    must end ABORTED by ``ABORT_LATE_S`` after that."""
    t_end = lane.executor.ended.get(cid, float("inf"))
    for mode, t_off, t_on in windows:
        due = t_off + grace
        if t_start <= t_off < t_end and lane.executor.due[cid] > due and due <= t_on:
            outcome = lane.controller.outcome_of(cid)
            assert outcome is not None and outcome.outcome_class is OutcomeClass.ABORTED, (
                f"command {cid} was still running {grace:.1f} s into a supervision outage ({mode}) and not "
                f"aborted: {outcome}")
            assert t_end <= due + ABORT_LATE_S, f"command {cid} aborted only {t_end - t_off:.2f} s into an outage"
            tally["running when silenced, aborted"] += 1


def check(lanes: list[Lane], elapsed_s: float) -> dict:
    tally: collections.Counter = collections.Counter()
    faults: collections.Counter = collections.Counter()
    estops: collections.Counter = collections.Counter()
    auth: collections.Counter = collections.Counter()
    for lane in lanes:
        check_final_states(lane, tally)
        check_supervised(lane, tally)
        lost = sum(k for (told, crane), k in lane.estops.items()
                   if told == "hung" or (told == "confirmed" and crane != "seen by the crane"))
        assert lost == 0, (f"e-stops lost (confirmed to the operator but not seen by the crane or the crane not "
                           f"stopped, or never answered): {lane.estops}")
        estops.update({f"{k[0]}, {k[1]}": v for k, v in lane.estops.items()})
        for counter in lane.injected:
            for (action, _), k in counter.items():
                faults[action] += k
        for (cls, _), k in lane.intruder.injected.items():
            faults[cls] += k
        auth["controller"] += lane.controller.auth_failures
        auth["laptops"] += lane.link.stats.auth_failures
        auth["MAC-failure FAULT resets"] += lane.resets["fault"]
    missing = [c for c, a in MATRIX.items() if faults[a] == 0]
    assert not missing, f"fault classes never injected: {missing} ({faults})"
    assert sum(estops.values()) > 0 and tally["outages"] > 0 and tally["running when silenced, aborted"] > 0, (estops, tally)
    tally["outage s"] = round(tally["outage s"], 1)
    return {"commands": sum(len(lane.commands) for lane in lanes), "elapsed_s": round(elapsed_s, 1),
            "states": dict(tally), "faults": {c: faults[a] for c, a in MATRIX.items()}, "e-stops": dict(estops),
            "dropped by authentication": dict(auth)}


@pytest.fixture
def lanes():
    made: list[Lane] = []
    yield made
    for lane in made:
        lane.close()


def _keys(tmp_path, n: int = LANES) -> list[str]:
    """One SecOC key per lane (= per crane), each with its crane's signing key pair beside it."""
    keys = [generate_key_file(tmp_path / f"crane{i}.key") for i in range(n)]
    for key in keys:
        generate_signing_key(signing_key_of(key))
    return [str(k) for k in keys]


def soak_cells(link: str):
    """The soak as evidence for every transmission error on ``link``: it injects each class (and asserts it
    did) among the others, with authentication, signed answers and supervision on, and checks the invariants."""
    def mark(test):
        for error, action in MATRIX.items():
            test = pytest.mark.safety_case(
                error=error, link=link,
                measure=f"every measure at once: soak with random faults of every class ({action} among them)",
                reaction="invariants hold for every command: the operator's final state equals the controller's, "
                         "nothing runs that was not sent, 0 executed unsupervised, 0 e-stops lost")(test)
        return test
    return mark


@soak_cells("can")
@pytest.mark.timeout(3600)
def test_soak_can_virtual(lanes, make_cmd, record_property, tmp_path):
    keys = _keys(tmp_path)
    lanes.extend(can_lane(i, keys, make_cmd) for i in range(LANES))
    report = soak(lanes, CAN_N, make_cmd)
    record_property("soak_can", report)
    print("soak can-virtual:", report)
    assert report["commands"] == CAN_N


@soak_cells("zenoh")
@pytest.mark.timeout(3600)
def test_soak_zenoh(lanes, make_cmd, record_property, tmp_path):
    from tests.field.conftest import free_port

    keys = _keys(tmp_path)
    lanes.extend(zenoh_lane(i, keys, make_cmd, free_port()) for i in range(LANES))
    report = soak(lanes, ZENOH_N, make_cmd)
    record_property("soak_zenoh", report)
    print("soak zenoh:", report)
    assert report["commands"] == ZENOH_N


class SlowPublishController(CountingController):
    """Publishes its status frames late, as on a starved machine: ``estop()`` is still publishing when
    the status query that the laptop's ``abort()`` makes is answered on another Zenoh callback thread."""

    publish_delay_s = 0.3  # [s], far above the status query's round trip on loopback

    def _publish_status(self) -> None:
        time.sleep(self.publish_delay_s)
        super()._publish_status()


def test_estop_counted_before_its_confirmation(lanes, tmp_path):
    """An e-stop the crane latched before the laptop confirmed it is classified as seen by the crane,
    however late the crane's ``estop()`` returns (docs/link-safety.md, "Soak")."""
    from tests.field.conftest import free_port
    from field.link.base import LinkURL
    from field.link.zenoh_backend import ZenohControllerTransport, ZenohLink, ZenohTarget

    key = _keys(tmp_path, 1)[0]
    url = LinkURL.parse(f"zenoh://127.0.0.1:{free_port()}/soak-estop-count")
    target = ZenohTarget.from_url(url, url.pop_link_config()[1])
    ex = TimedExecutor()
    ctl = SlowPublishController(ControllerConfig(laptop_timeout_s=LAPTOP_TIMEOUT_S, no_journal=True, secoc_key_path=key,
                                                 signing_key_path=str(signing_key_of(key))), ex)
    ex.controller = ctl
    tr = ZenohControllerTransport(target)
    tr.start(ctl)
    ctl.start()
    link = ZenohLink(target, _link_config(key))
    lanes.append(Lane("zenoh", link, ctl, ex, [ctl.close, tr.close, link.close]))
    link._await_controller()
    lanes[0]._settle_estop(*lanes[0]._estop_soon(0.0))
    assert lanes[0].estops == {("confirmed", "seen by the crane"): 1}
