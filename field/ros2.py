"""The plan and the sent grasp as ROS 2 messages on a Zenoh session, laid out as rmw_zenoh lays them.

A ROS 2 crane stack running ``rmw_zenoh_cpp`` subscribes to these topics without a bridge: the
data travel on the key expressions rmw_zenoh derives from a topic (its ``TopicInfo``)::

    <domain_id>/<topic without leading '/'>/<DDS type name>/<type hash>
    e.g. 0/loggrasp/crane1/grasp/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3786d...

with the payload CDR-serialised (XCDR1 little-endian, the 4-byte encapsulation header
``00 01 00 00`` first) and an attachment of (sequence number int64, source timestamp int64 [ns],
source GID 16 bytes), each little-endian as zenoh's ext serializer writes them. Graph presence
(``ros2 topic list``, ``ros2 node list``) uses rmw_zenoh's liveliness tokens under ``@ros2_lv``
(a node token and one publisher token per topic, default QoS). The type hashes are REP 2011's
RIHS01 of the Jazzy message definitions (constants below; the tests recompute them with an
independent implementation). The GID is the first 16 bytes of the SHA-256 of the publisher's
liveliness key (rmw_zenoh hashes it with XXH3-128; a subscriber only compares GIDs).

Topics (``<ns>`` = ``loggrasp/<crane>``)::

    /<ns>/plan    geometry_msgs/msg/PoseArray    every planned grasp, best first, frame ``map``
    /<ns>/grasp   geometry_msgs/msg/PoseStamped  the grasp sent to the crane, frame ``map``

Frames (REP 103 axes, REP 105 names; docs/robotics-interfaces.md draws the tree): ``map`` is
SWEREF 99 TM (EPSG:3006) itself, x = easting, y = northing [m], z = ellipsoidal height (GRS80) [m]
-- a world-fixed ENU frame aligned with grid north. A grasp pose's position is the grasp point;
its x axis is the grapple's closing axis (pi-periodic: x and -x are the same grasp), z up, so its
yaw is ``90 deg - heading_grid_deg``. The header stamp is the capture time of the pile data the
plan used (the staleness clock the crane checks), in UTC.
"""

from __future__ import annotations

import hashlib
import math
import os
import struct
import threading
from dataclasses import dataclass
from typing import Any

DEFAULT_DOMAIN_ID = 0  # ROS_DOMAIN_ID when the environment does not set one [-]
MAP_FRAME = "map"  # SWEREF 99 TM, ENU axes (x east, y north, z up), ellipsoidal height
NODE_NAME = "loggrasp_laptop"
GID_BYTES = 16  # RMW_GID_STORAGE_SIZE of Jazzy and later


@dataclass(frozen=True)
class RosType:
    """A ROS 2 message type: its name (``pkg/msg/Name``) and REP 2011 type hash."""

    name: str
    rihs01: str

    @property
    def dds_name(self) -> str:
        """The name rmw_zenoh puts in key expressions: ``pkg::msg::dds_::Name_``."""
        pkg, kind, leaf = self.name.split("/")
        return f"{pkg}::{kind}::dds_::{leaf}_"


POSE_STAMPED = RosType("geometry_msgs/msg/PoseStamped",
                       "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8")
POSE_ARRAY = RosType("geometry_msgs/msg/PoseArray",
                     "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0")


def topic_key(domain_id: int, topic: str, ros_type: RosType) -> str:
    """rmw_zenoh's data key expression of ``topic`` (``/a/b``) carrying ``ros_type``."""
    return f"{domain_id}/{topic.strip('/')}/{ros_type.dds_name}/{ros_type.rihs01}"


def domain_id_from_env() -> int:
    """``ROS_DOMAIN_ID`` as ROS 2 reads it, else :data:`DEFAULT_DOMAIN_ID`."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return DEFAULT_DOMAIN_ID
    if not text.isdigit() or not 0 <= int(text) <= 232:
        raise ValueError(f"ROS_DOMAIN_ID must be a whole number 0-232, got {text!r}")
    return int(text)


# -- CDR (XCDR1, little-endian) -------------------------------------------------------------------
class CdrWriter:
    """Plain CDR as ROS 2 serialises a message: primitives aligned to their size, counted from
    the end of the encapsulation header; strings as uint32 length (NUL included) + bytes + NUL."""

    HEADER = b"\x00\x01\x00\x00"  # CDR_LE, options 0

    def __init__(self) -> None:
        self.body = bytearray()

    def _align(self, n: int) -> None:
        self.body += b"\x00" * (-len(self.body) % n)

    def int32(self, v: int) -> None:
        self._align(4)
        self.body += struct.pack("<i", v)

    def uint32(self, v: int) -> None:
        self._align(4)
        self.body += struct.pack("<I", v)

    def float64(self, *vs: float) -> None:
        for v in vs:
            self._align(8)
            self.body += struct.pack("<d", v)

    def string(self, s: str) -> None:
        raw = s.encode("utf-8") + b"\x00"
        self.uint32(len(raw))
        self.body += raw

    def bytes(self) -> bytes:
        return self.HEADER + bytes(self.body)


@dataclass(frozen=True)
class Pose:
    """A pose in a frame: position [m] and orientation quaternion (x, y, z, w)."""

    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]


def grasp_pose_map(easting_m: float, northing_m: float, h_ell_m: float, heading_grid_deg: float) -> Pose:
    """A grasp in the ``map`` frame: x axis along the closing axis (``heading_grid_deg`` clockwise
    from grid north, so yaw = 90 deg - heading counter-clockwise from east), z up."""
    yaw = math.radians(90.0 - heading_grid_deg)
    return Pose((easting_m, northing_m, h_ell_m), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))


def _header(w: CdrWriter, stamp_s: float, frame_id: str) -> None:
    sec = math.floor(stamp_s)
    w.int32(sec)
    w.uint32(min(999_999_999, round((stamp_s - sec) * 1e9)))
    w.string(frame_id)


def _pose(w: CdrWriter, pose: Pose) -> None:
    w.float64(*pose.position)
    w.float64(*pose.orientation)


def pose_stamped_cdr(stamp_s: float, frame_id: str, pose: Pose) -> bytes:
    """geometry_msgs/msg/PoseStamped, CDR with its encapsulation header."""
    w = CdrWriter()
    _header(w, stamp_s, frame_id)
    _pose(w, pose)
    return w.bytes()


def pose_array_cdr(stamp_s: float, frame_id: str, poses: list[Pose]) -> bytes:
    """geometry_msgs/msg/PoseArray, CDR with its encapsulation header."""
    w = CdrWriter()
    _header(w, stamp_s, frame_id)
    w.uint32(len(poses))
    for p in poses:
        _pose(w, p)
    return w.bytes()


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's sample attachment: int64 sequence number, int64 source timestamp [ns], the
    16-byte GID (zenoh ext serializer: little-endian, the fixed-size array without a length)."""
    if len(gid) != GID_BYTES:
        raise ValueError(f"a GID has {GID_BYTES} bytes, got {len(gid)}")
    return struct.pack("<qq", sequence_number, source_timestamp_ns) + gid


# -- the publisher on a Zenoh session ---------------------------------------------------------
_DEFAULT_QOS = "::,:,:,:,,"  # rmw_zenoh's QoS key part when every policy is the default


def _mangle(name: str) -> str:
    return name.replace("/", "%")


class Ros2Publisher:
    """ROS 2 publications on an open Zenoh session (the crane link's): the graph's liveliness
    tokens are declared here and undeclared by :meth:`close` (safe twice); the session stays the
    caller's. ``namespace`` is the topics' prefix (``/loggrasp/<crane>``)."""

    def __init__(self, session: Any, namespace: str, domain_id: int = DEFAULT_DOMAIN_ID) -> None:
        self.session, self.domain_id = session, domain_id
        self.namespace = "/" + namespace.strip("/")
        self._lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._tokens: list[Any] = []
        zid = str(session.zid())
        self._node_key = f"@ros2_lv/{domain_id}/{zid}/0/0/NN/%/%/{NODE_NAME}"
        self._tokens.append(session.liveliness().declare_token(self._node_key))
        self._pubs: dict[str, tuple[str, bytes]] = {}
        for i, (leaf, rtype) in enumerate((("plan", POSE_ARRAY), ("grasp", POSE_STAMPED)), start=1):
            topic = f"{self.namespace}/{leaf}"
            token = (f"@ros2_lv/{domain_id}/{zid}/0/{i}/MP/%/%/{NODE_NAME}/{_mangle(topic)}/{rtype.dds_name}/"
                     f"{rtype.rihs01}/{_DEFAULT_QOS}")
            self._tokens.append(session.liveliness().declare_token(token))
            self._pubs[leaf] = (topic_key(domain_id, topic, rtype), hashlib.sha256(token.encode()).digest()[:GID_BYTES])

    def keys(self) -> dict[str, str]:
        """Topic leaf (``plan``, ``grasp``) -> its data key expression."""
        return {leaf: key for leaf, (key, _) in self._pubs.items()}

    def _put(self, leaf: str, payload: bytes, now_ns: int) -> None:
        key, gid = self._pubs[leaf]
        with self._lock:
            seq = self._seq.get(leaf, 0) + 1
            self._seq[leaf] = seq
        self.session.put(key, payload, attachment=attachment(seq, now_ns, gid))

    def publish_plan(self, stamp_s: float, poses: list[Pose], now_ns: int) -> None:
        """The plan's grasps, best first, in ``map``."""
        self._put("plan", pose_array_cdr(stamp_s, MAP_FRAME, poses), now_ns)

    def publish_grasp(self, stamp_s: float, pose: Pose, now_ns: int) -> None:
        """The grasp sent to the crane, in ``map``."""
        self._put("grasp", pose_stamped_cdr(stamp_s, MAP_FRAME, pose), now_ns)

    def close(self) -> None:
        tokens, self._tokens = self._tokens, []
        for t in tokens:
            try:
                t.undeclare()
            except Exception:  # the session closed first: its tokens are gone with it
                pass


def plan_poses(the_plan: Any, pile: Any) -> list[Pose]:
    """Every grasp of a plan (best first) as a pose in ``map``."""
    from field.geo import grasp_to_gnss

    out = []
    for pg in the_plan.grasps:
        g = pg.grasp
        geo = grasp_to_gnss(g, pile.georef, float(pile.terrain.height_at(g.x_m, g.y_m)))
        out.append(grasp_pose_map(geo.easting_m, geo.northing_m, geo.h_ell_m, geo.heading_grid_deg))
    return out


def command_pose(fields: dict) -> Pose:
    """The grasp a :class:`field.link.messages.GraspCommand`'s fields carry (wire units), in ``map``."""
    return grasp_pose_map(fields["easting_mm"] / 1000.0, fields["northing_mm"] / 1000.0, fields["height_mm"] / 1000.0,
                          fields["heading_cdeg"] / 100.0)


def publish_trial(publisher: Ros2Publisher, prepared: Any, say=None) -> None:
    """A prepared trial's plan and the grasp its command carries, stamped with the pile data's
    capture time; called as the command is sent. A prepared trial without a plan (a recorded
    command sent again by ``replay --link``) publishes the grasp only."""
    import time

    now_ns = time.time_ns()
    if prepared.plan is not None and prepared.pile is not None:  # a re-sent recorded command has no plan here
        publisher.publish_plan(prepared.captured_utc_s, plan_poses(prepared.plan, prepared.pile), now_ns)
    publisher.publish_grasp(prepared.captured_utc_s, command_pose(prepared.command_fields), now_ns)
    if say is not None:
        keys = publisher.keys()
        say(f"ROS 2: plan on {publisher.namespace}/plan, grasp on {publisher.namespace}/grasp "
            f"(rmw_zenoh key {keys['grasp']})")
