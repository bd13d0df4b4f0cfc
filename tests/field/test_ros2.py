"""ROS 2 over Zenoh (field/ros2.py): rmw_zenoh key expressions, REP 2011 type hashes, CDR that an
independent decoder (rosbags) reads, and the publications on a loopback Zenoh session
(tcp/127.0.0.1 only, multicast scouting off)."""

from __future__ import annotations

import json
import math
import struct
import threading

import numpy as np
import pytest

from field.ros2 import (MAP_FRAME, POSE_ARRAY, POSE_STAMPED, Pose, Ros2Publisher, attachment, command_pose,
                        grasp_pose_map, plan_poses, pose_array_cdr, pose_stamped_cdr, topic_key)

rosbags_typesys = pytest.importorskip("rosbags.typesys")
TYPESTORE = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)


def decode(payload: bytes, ros_type) -> object:
    """The independent decoder: rosbags' CDR deserializer (encapsulation header included)."""
    return TYPESTORE.deserialize_cdr(payload, ros_type.name)


def yaw_of(q) -> float:
    return 2 * math.atan2(q.z, q.w)


def test_type_hashes_are_rep2011_of_the_jazzy_definitions():
    for t in (POSE_STAMPED, POSE_ARRAY):
        assert t.rihs01 == TYPESTORE.hash_rihs01(t.name)


def test_key_expression_is_rmw_zenohs():
    key = topic_key(3, "/loggrasp/crane1/grasp", POSE_STAMPED)
    assert key == f"3/loggrasp/crane1/grasp/geometry_msgs::msg::dds_::PoseStamped_/{POSE_STAMPED.rihs01}"
    assert topic_key(0, "/plan/", POSE_ARRAY).split("/")[:3] == ["0", "plan", "geometry_msgs::msg::dds_::PoseArray_"]


@pytest.mark.parametrize("frame_id", ["map", "a", "pile_frame_xyz"])  # string lengths that need each padding
def test_pose_stamped_decodes_with_an_independent_cdr_reader(frame_id):
    pose = Pose((743497.125, 7117716.5, 249.75), (0.0, 0.0, math.sin(0.3), math.cos(0.3)))
    msg = decode(pose_stamped_cdr(1796533246.25, frame_id, pose), POSE_STAMPED)
    assert msg.header.frame_id == frame_id
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1796533246, 250_000_000)
    p, q = msg.pose.position, msg.pose.orientation
    assert (p.x, p.y, p.z) == pose.position
    assert (q.x, q.y, q.z, q.w) == pose.orientation


def test_pose_array_decodes_with_an_independent_cdr_reader():
    poses = [Pose((float(i), 2.0 * i, -1.5), (0.0, 0.0, 0.0, 1.0)) for i in range(3)]
    for frame_id in ("map", "ab"):
        msg = decode(pose_array_cdr(12.5, frame_id, poses), POSE_ARRAY)
        assert msg.header.frame_id == frame_id and msg.header.stamp.sec == 12
        assert [(p.position.x, p.position.y, p.position.z) for p in msg.poses] == [p.position for p in poses]
    assert len(decode(pose_array_cdr(0.0, "map", []), POSE_ARRAY).poses) == 0


def test_grasp_pose_x_axis_is_the_closing_axis_from_grid_heading():
    north = grasp_pose_map(1.0, 2.0, 3.0, 0.0)  # closing axis along grid north: +y of map, yaw 90 deg
    assert north.position == (1.0, 2.0, 3.0)
    x, y, z, w = north.orientation
    assert math.degrees(2 * math.atan2(z, w)) == pytest.approx(90.0)
    east = grasp_pose_map(0, 0, 0, 90.0)
    assert math.degrees(2 * math.atan2(east.orientation[2], east.orientation[3])) == pytest.approx(0.0, abs=1e-9)
    pose = command_pose({"easting_mm": 743497123, "northing_mm": 7117716456, "height_mm": 249800,
                         "heading_cdeg": 3000})
    assert pose.position == (743497.123, 7117716.456, 249.8)
    assert math.degrees(2 * math.atan2(pose.orientation[2], pose.orientation[3])) == pytest.approx(60.0)


def test_attachment_layout():
    gid = bytes(range(16))
    raw = attachment(7, 1_796_533_246_000_000_123, gid)
    assert struct.unpack("<qq", raw[:16]) == (7, 1_796_533_246_000_000_123) and raw[16:] == gid
    with pytest.raises(ValueError):
        attachment(1, 0, b"short")


# -- on a loopback Zenoh session ----------------------------------------------------------------
def _conf(mode: str, port: int):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    key = "listen/endpoints" if mode == "peer" else "connect/endpoints"
    conf.insert_json5(key, json.dumps([f"tcp/127.0.0.1:{port}"]))
    if mode == "peer":
        conf.insert_json5("connect/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    return conf


@pytest.fixture
def zenoh_pair(port):
    """(the crane side's listening peer, a ROS 2 subscriber's client session), both closed after."""
    import zenoh

    hub = zenoh.open(_conf("peer", port))
    sub = zenoh.open(_conf("client", port))
    yield hub, sub
    sub.close()
    hub.close()


def _demo_plan():
    from field.demo import DEMO_DATA
    from planner.inference import Plan, PlannedGrasp
    from synth.geometry.grasp import Grasp
    from synth.scene.pile import read_pile

    pile = read_pile(DEMO_DATA / "truth" / "pile.json")
    grasps = [PlannedGrasp(Grasp(x, y, phi, 0.9), 0.5, 0.6, 1.0, (0,), (0, 0))
              for x, y, phi in ((0.1, 0.2, 0.3), (-0.5, 0.4, 1.2))]
    return Plan(grasps=grasps, subsets_evaluated=2, elapsed_s=0.0), pile


def test_plan_and_grasp_reach_a_loopback_subscriber(zenoh_pair, port):
    import zenoh

    from field.geo import grasp_to_gnss

    hub, sub = zenoh_pair
    got: dict[str, list] = {}
    done = threading.Event()

    def on_sample(s) -> None:
        att = s.attachment.to_bytes() if s.attachment is not None else b""
        got.setdefault(str(s.key_expr), []).append((s.payload.to_bytes(), att))
        if len(got) == 2:
            done.set()

    subscriber = sub.declare_subscriber("0/loggrasp/crane9/**", on_sample)
    laptop = zenoh.open(_conf("client", port))
    try:
        ros = Ros2Publisher(laptop, "loggrasp/crane9")
        plan, pile = _demo_plan()
        import time

        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and not done.is_set():  # the subscription may take a moment to route
            ros.publish_plan(100.5, plan_poses(plan, pile), 1)
            ros.publish_grasp(100.5, grasp_pose_map(743497.0, 7117716.0, 249.8, 30.0), 2)
            done.wait(0.2)
        tokens: list[str] = []
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and len(tokens) < 3:  # the graph tokens may take a moment too (under load)
            tokens = [str(r.ok.key_expr) for r in sub.liveliness().get("@ros2_lv/0/**", timeout=2.0) if r.ok]
            time.sleep(0.05 if len(tokens) >= 3 else 0.2)
        ros.close()
        ros.close()  # safe twice
    finally:
        subscriber.undeclare()
        laptop.close()
    assert done.is_set(), f"received only {sorted(got)}"
    keys = ros.keys()
    assert keys == {"plan": topic_key(0, "/loggrasp/crane9/plan", POSE_ARRAY),
                    "grasp": topic_key(0, "/loggrasp/crane9/grasp", POSE_STAMPED)}
    payload, att = got[keys["grasp"]][0]
    msg = decode(payload, POSE_STAMPED)
    assert msg.header.frame_id == MAP_FRAME and msg.header.stamp.sec == 100
    assert (msg.pose.position.x, msg.pose.position.y, msg.pose.position.z) == (743497.0, 7117716.0, 249.8)
    assert math.degrees(yaw_of(msg.pose.orientation)) == pytest.approx(60.0)
    seq, ts = struct.unpack("<qq", att[:16])
    assert seq >= 1 and ts == 2 and len(att) == 32
    arr = decode(got[keys["plan"]][0][0], POSE_ARRAY)
    assert arr.header.frame_id == MAP_FRAME and len(arr.poses) == 2
    for planned, pose in zip(plan.grasps, arr.poses):
        g = planned.grasp
        geo = grasp_to_gnss(g, pile.georef, float(pile.terrain.height_at(g.x_m, g.y_m)))
        np.testing.assert_allclose((pose.position.x, pose.position.y, pose.position.z),
                                   (geo.easting_m, geo.northing_m, geo.h_ell_m), atol=1e-6)
        assert math.degrees(yaw_of(pose.orientation)) % 180 == pytest.approx((90 - geo.heading_grid_deg) % 180)
    # the graph sees a node and two publishers (rmw_zenoh's liveliness keys)
    assert any(t.endswith("/NN/%/%/loggrasp_laptop") for t in tokens), tokens
    pubs = [t for t in tokens if "/MP/" in t]
    assert len(pubs) == 2 and any("/%loggrasp%crane9%grasp/geometry_msgs::msg::dds_::PoseStamped_/" in t for t in pubs)
