"""The field chain end to end: bundled scan -> reconstruction -> plan -> SWEREF 99 TM command ->
crane controller twin (pybullet) over simulated CAN and over Zenoh loopback -> record -> replay.
And the safety gates: nothing is sent on stale data, float fixes, out-of-reach plans or a 'no'."""

from __future__ import annotations

import json
import time
import uuid

import pytest

from field.controller import controller_in_thread
from field.demo import DEMO_DATA, crane_config, default_crane_base
from field.executor import PybulletTrialExecutor
from field.trial import TrialAborted, TrialOptions, execute_trial, prepare_trial
from field.trial_record import replay_record, run_trial_record
from synth.scene.pile import read_pile

pytestmark = pytest.mark.slow
TRUTH = read_pile(DEMO_DATA / "truth" / "pile.json")
BASE = default_crane_base(TRUTH)
AGE = 10 * 365 * 86400.0  # the bundled scan is old: judge it against its own age limit here


class Crane:
    """The controller twin on a thread, serving ``url`` with the pybullet executor on the true pile."""

    def __init__(self, url: str) -> None:
        self.executor = PybulletTrialExecutor(TRUTH)
        self.calls = 0
        inner = self.executor

        def counted(cmd):
            self.calls += 1
            return inner(cmd)

        self._served = controller_in_thread(url, counted, crane_config(BASE, 10.0, AGE), start_timeout_s=20.0)

    def __enter__(self) -> "Crane":
        self._served.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._served.__exit__(*exc)


def options(**kw) -> TrialOptions:
    base = dict(objective="f3", max_pile_age_s=AGE, crane_base_tm=BASE, max_reach_m=10.0)
    base.update(kw)
    return TrialOptions(**base)


@pytest.fixture(scope="module")
def can_record(tmp_path_factory):
    url = f"can://virtual/trial-{uuid.uuid4().hex[:8]}?insecure=1"
    rec = tmp_path_factory.mktemp("rec") / "t1"
    with Crane(url) as crane:
        record = run_trial_record(DEMO_DATA / "scan", DEMO_DATA / "gnss.csv", url, rec, options())
    return rec, record, crane.calls


def test_full_trial_over_simulated_can(can_record):
    rec, record, calls = can_record
    assert calls == 1  # executed exactly once
    assert record["accepted"] and record["outcome"] is not None
    assert record["final_state"] == record["outcome"]["class"]
    kinds = [m["kind"] for m in record["messages"]]
    assert kinds == ["command", "ack", "outcome"]
    assert all(m["t_utc_s"] > 0 for m in record["messages"])
    on_disk = json.loads((rec / "record.json").read_text())
    assert on_disk["format"] == "loggrasp.trial-record" and on_disk["command"] == record["command"]
    for f in ("reconstruction/pile.json", "plan/plan.png", "plan/pile.geojson", "plan/grasp_map.png",
              "link/traffic.blf", "inputs/gnss.csv"):
        assert (rec / f).exists(), f
    assert (rec / "link" / "traffic.blf").stat().st_size > 0


def test_trial_mcap_reads_back_with_an_independent_reader(can_record):
    """trial.mcap: every stage's topic, counts that match record.json and traffic.blf, times in order."""
    from tests.field.mcap_check import check_trial_mcap

    rec, record, _ = can_record
    on_disk = json.loads((rec / "record.json").read_text())
    m = check_trial_mcap(rec, on_disk)
    assert on_disk["view"]["path"] == "trial.mcap" and "view_errors" not in on_disk
    assert on_disk["view"]["messages"] == {t: len(v) for t, v in m.times_ns.items()}


def test_replay_is_bit_identical(can_record, tmp_path):
    """... in the number format the trial's network ran in, which the record names ("auto" as this
    machine resolved it: int8 on a CPU with int8 dot products)."""
    from planner.checkpoint import DEFAULT_MODEL
    from planner.inference import checkpoint_precision

    rec, record, _ = can_record
    assert record["model"]["precision"] == checkpoint_precision(DEFAULT_MODEL, "cpu") and \
        record["options"]["precision"] == "auto"
    result = replay_record(rec, tmp_path / "replay")
    assert result["identical"], result["differences"]


def test_the_trial_plans_with_the_shipped_ranker_and_records_it(can_record):
    """By default the network's best grasps are re-scored by planner/weights/ranker.safetensors; the
    record names that file and its hash, and its plan says which grasps were re-scored."""
    from planner.checkpoint import DEFAULT_RANKER
    from synth.common.files import sha256_file as sha256_of

    rec, record, _ = can_record
    on_disk = json.loads((rec / "record.json").read_text())
    assert on_disk["options"]["rerank"] is True
    assert on_disk["ranker"] == {"path": str(DEFAULT_RANKER), "sha256": sha256_of(DEFAULT_RANKER)}
    info = on_disk["plan"]["info"]
    assert info["reranked"] >= 1 and set(info["p_ranker"]) == set(info["u_network"])


@pytest.mark.parametrize("what", ["model", "ranker"])
def test_replay_refuses_a_checkpoint_that_is_not_the_recorded_one(can_record, tmp_path, what):
    import shutil

    from field.trial_record import RecordError

    rec, _, _ = can_record
    copy = tmp_path / "rec"
    shutil.copytree(rec, copy)
    doc = json.loads((copy / "record.json").read_text())
    doc[what]["sha256"] = "0" * 64
    (copy / "record.json").write_text(json.dumps(doc))
    with pytest.raises(RecordError, match=f"the {what} .* differs from the one the trial used \\(sha256 000000000000"):
        replay_record(copy, tmp_path / "replay")


def test_trial_over_zenoh_loopback(can_record, tmp_path):
    """The same command over Zenoh (controller listening on 127.0.0.1 only, no scouting); a ROS 2
    subscriber on the same loopback Zenoh network gets the sent grasp as geometry_msgs/PoseStamped
    on rmw_zenoh's key, decoded by an independent CDR reader (rosbags)."""
    import math
    import socket
    import threading

    import zenoh
    from rosbags.typesys import Stores, get_typestore

    from field.ros2 import POSE_STAMPED, topic_key
    from field.trial import PreparedTrial

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    _, record, _ = can_record
    prepared = PreparedTrial(pile=None, plan=None, geo=None, command_fields=record["command"],
                             captured_utc_s=0.0, work_dir=tmp_path)
    crane_name = f"crane-{uuid.uuid4().hex[:6]}"
    url = f"zenoh://127.0.0.1:{port}/{crane_name}?insecure=1"
    got, heard = [], threading.Event()
    conf = zenoh.Config()
    for k, v in (("mode", '"client"'), ("connect/endpoints", f'["tcp/127.0.0.1:{port}"]'),
                 ("scouting/multicast/enabled", "false"), ("scouting/gossip/enabled", "false")):
        conf.insert_json5(k, v)
    with Crane(url) as crane:
        ros_sub = zenoh.open(conf)
        try:
            key = topic_key(0, f"/loggrasp/{crane_name}/grasp", POSE_STAMPED)
            sub = ros_sub.declare_subscriber(key, lambda s: (got.append(s.payload.to_bytes()), heard.set()))
            time.sleep(0.5)  # the subscription's declaration reaches the crane's peer
            out = execute_trial(prepared, url, options())
            heard.wait(5.0)
            sub.undeclare()
        finally:
            ros_sub.close()
    assert crane.calls == 1 and out.accepted
    assert out.final_state == record["final_state"]  # same pile, same grasp, same outcome
    assert len(got) == 1, "the sent grasp was not published as ROS 2 (or more than once)"
    msg = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(got[0], POSE_STAMPED.name)
    c = record["command"]
    assert msg.header.frame_id == "map"
    assert (msg.pose.position.x, msg.pose.position.y, msg.pose.position.z) == (
        c["easting_mm"] / 1000, c["northing_mm"] / 1000, c["height_mm"] / 1000)
    yaw_deg = math.degrees(2 * math.atan2(msg.pose.orientation.z, msg.pose.orientation.w))
    assert yaw_deg == pytest.approx(90.0 - c["heading_cdeg"] / 100.0)


def test_stale_pile_data_is_never_sent(tmp_path):
    url = f"can://virtual/stale-{uuid.uuid4().hex[:8]}?insecure=1"
    with Crane(url) as crane:
        with pytest.raises(TrialAborted, match="old"):
            run_trial_record(DEMO_DATA / "scan", DEMO_DATA / "gnss.csv", url, tmp_path / "r", options(max_pile_age_s=1.0))
    assert crane.calls == 0
    rec = json.loads((tmp_path / "r" / "record.json").read_text())
    assert rec["final_state"] == "NOT SENT" and "old" in rec["reason"]


def test_float_fix_is_refused_unless_allowed(tmp_path):
    rows = (DEMO_DATA / "gnss.csv").read_text().splitlines()
    i = next(k for k, r in enumerate(rows) if r.startswith("log0,"))
    assert "rtk_fixed" in rows[i]
    rows[i] = rows[i].replace("rtk_fixed", "rtk_float")
    (tmp_path / "gnss.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(TrialAborted, match="float"):
        prepare_trial(DEMO_DATA / "scan", tmp_path / "gnss.csv", tmp_path / "w", options())
    # the operator's explicit choice lets it through (one grasp verified in the twin, not eight: what is
    # checked here is the gate before the reconstruction)
    prepared = prepare_trial(DEMO_DATA / "scan", tmp_path / "gnss.csv", tmp_path / "w2",
                             options(allow_float=True, verify_k=1))
    assert prepared.command_fields["target_log_count"] >= 1


def test_out_of_reach_and_declined_are_not_sent(tmp_path):
    url = f"can://virtual/reach-{uuid.uuid4().hex[:8]}?insecure=1"
    far = (BASE[0] + 500.0, BASE[1], BASE[2])
    with Crane(url) as crane:
        with pytest.raises(TrialAborted, match="reach|constraints"):
            run_trial_record(DEMO_DATA / "scan", DEMO_DATA / "gnss.csv", url, tmp_path / "far",
                             options(crane_base_tm=far))
        with pytest.raises(TrialAborted, match="declined"):  # one verified grasp is enough to be asked
            run_trial_record(DEMO_DATA / "scan", DEMO_DATA / "gnss.csv", url, tmp_path / "no", options(verify_k=1),
                             confirm=lambda prepared: False)
    assert crane.calls == 0
    assert json.loads((tmp_path / "no" / "record.json").read_text())["final_state"] == "NOT SENT"


def test_summary_warns_about_targets_the_scan_hardly_showed(tmp_path):
    """The operator's confirmation names target logs that were placed from the survey (seen only
    in part, or hidden under others), and says nothing for fitted ones."""
    from types import SimpleNamespace

    from field.trial import PreparedTrial

    best = SimpleNamespace(targets=(0, 2), quality=0.9, graspability=0.95, balance=0.9)
    geo = SimpleNamespace(easting_m=1.0, northing_m=2.0, h_ell_m=3.0, heading_grid_deg=10.0, heading_true_deg=9.0,
                          width_m=1.2)

    def prepared(fits):
        return PreparedTrial(pile=SimpleNamespace(n_logs=3), plan=SimpleNamespace(best=best), geo=geo,
                             command_fields={}, captured_utc_s=0.0, work_dir=tmp_path, report={"log_fits": fits})

    lines = prepared(["scan", "hidden", "hidden"]).summary_lines()
    warn = [s for s in lines if s.startswith("WARNING")]
    assert len(warn) == 1 and "target log 2" in warn[0] and "hidden under other logs" in warn[0]
    assert prepared(["partial", "scan", "scan"]).doubtful_targets()[0][0] == 0
    assert not any(s.startswith("WARNING") for s in prepared(["scan"] * 3).summary_lines())
