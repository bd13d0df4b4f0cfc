"""Reading a trial's ``trial.mcap`` back with an independent reader (the ``mcap`` package's, not
the Foxglove SDK that wrote it), for the trial and CLI tests."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

#: topic -> schema name every trial over CAN with verification logs (JSON channels: their topic)
TRIAL_TOPICS = {
    "/scan/pair_000/left": "foxglove.CompressedImage", "/scan/pair_000/right": "foxglove.CompressedImage",
    "/scan/points": "foxglove.PointCloud", "/tf": "foxglove.FrameTransforms", "/pile/logs": "foxglove.SceneUpdate",
    "/plan": "/plan", "/plan/grasps": "foxglove.SceneUpdate", "/verification/candidates": "/verification/candidates",
    "/verification/grasps": "foxglove.SceneUpdate", "/command": "/command", "/trial/events": "/trial/events",
    "/trial/state": "/trial/state", "/trial/log": "foxglove.Log", "/can/frames": "/can/frames",
    "/crane/state": "/crane/state",
}


@dataclass
class McapContent:
    schemas: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    encodings: dict[str, str] = field(default_factory=dict)  # topic -> message encoding
    times_ns: dict[str, list[int]] = field(default_factory=dict)  # topic -> log times in file order
    json: dict[str, list[dict]] = field(default_factory=dict)  # JSON topics' messages
    raw: dict[str, list[bytes]] = field(default_factory=dict)
    summary_counts: dict[str, int] = field(default_factory=dict)  # the file's own statistics


def read_mcap(path: Path) -> McapContent:
    from mcap.reader import make_reader

    out = McapContent()
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            t = channel.topic
            out.schemas[t] = schema.name if schema is not None else ""
            out.encodings[t] = channel.message_encoding
            out.times_ns.setdefault(t, []).append(message.log_time)
            out.raw.setdefault(t, []).append(message.data)
            if channel.message_encoding == "json":
                out.json.setdefault(t, []).append(json.loads(message.data))
        summary = reader.get_summary()
        for cid, n in summary.statistics.channel_message_counts.items():
            out.summary_counts[summary.channels[cid].topic] = n
    return out


def check_trial_mcap(record_dir: Path, rec: dict) -> McapContent:
    """The checks every successful trial's recording passes: the topics and their schemas, counts
    that match the record, and log times that never go back within a topic and lie in the trial."""
    import can

    m = read_mcap(record_dir / "trial.mcap")
    for topic, schema in TRIAL_TOPICS.items():
        assert m.schemas.get(topic) == schema, (topic, m.schemas.get(topic))
    assert {t: len(v) for t, v in m.times_ns.items()} == m.summary_counts
    for topic, times in m.times_ns.items():
        assert times == sorted(times), f"{topic}: log times go back"
        assert rec["started_utc_s"] * 1e9 <= times[0] and times[-1] <= (rec["finished_utc_s"] + 1.0) * 1e9, topic
    assert len(m.times_ns["/pile/logs"]) == len(m.times_ns["/plan"]) == len(m.times_ns["/command"]) == 1
    assert len(m.json["/verification/candidates"]) == len(rec["verification"]["candidates"])
    assert [e["kind"] for e in m.json["/trial/events"]] == [e["kind"] for e in rec["messages"]]
    assert m.times_ns["/trial/events"] == [round(e["t_utc_s"] * 1e9) for e in rec["messages"]]
    command = m.json["/command"][0]["command"]
    assert {k: v for k, v in command.items() if k != "command_id"} == rec["command"]
    assert command["command_id"] == rec["command_id"]
    assert m.json["/trial/state"][-1]["final_state"] == rec["final_state"]
    with can.BLFReader(str(record_dir / "link" / "traffic.blf")) as frames:
        blf = sorted(round(f.timestamp * 1e9) for f in frames)
    assert len(m.json["/can/frames"]) == len(blf) > 0
    assert all(f["check"] == "ok" for f in m.json["/can/frames"]), [f for f in m.json["/can/frames"]
                                                                   if f["check"] != "ok"][:2]
    assert {s["state"] for s in m.json["/crane/state"]} >= {"IDLE", "EXECUTING"}
    # the grasp is chosen before it is sent, the frames start when the link opens for sending
    assert m.times_ns["/tf"][-1] <= m.times_ns["/command"][0] <= m.times_ns["/trial/state"][-1]
    assert m.times_ns["/can/frames"][0] >= rec["confirmed_utc_s"] * 1e9
    check_decoded(record_dir, rec)
    return m


def check_decoded(record_dir: Path, rec: dict) -> None:
    """The protobuf topics decoded from the schemas the file carries (mcap-protobuf-support): the
    images are JPEGs stamped with the scan's capture time, the cloud is in frame ``scan``, the
    frames chain map -> site -> pile -> grasp, one cylinder per reconstructed log, one line per
    planned grasp."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from field.trial import captured_time
    from field.trial_view import MAX_CLOUD_POINTS
    from synth.scene.pile import read_pile

    captured = captured_time(record_dir / "inputs" / "scan", record_dir / "inputs" / "gnss.csv")
    n_logs = read_pile(record_dir / "reconstruction" / "pile.json").n_logs
    decoded: dict[str, list] = {}
    with open(record_dir / "trial.mcap", "rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/scan/pair_000/left", "/scan/points", "/tf", "/pile/logs", "/plan/grasps"]):
            decoded.setdefault(channel.topic, []).append(msg)
    image = decoded["/scan/pair_000/left"][0]
    assert image.format == "jpeg" and image.data[:2] == b"\xff\xd8"
    assert abs(image.timestamp.seconds + image.timestamp.nanos * 1e-9 - captured) < 1e-6
    cloud = decoded["/scan/points"][0]
    assert cloud.frame_id == "scan" and cloud.point_stride == 16
    assert 1000 < len(cloud.data) // cloud.point_stride <= MAX_CLOUD_POINTS
    chains = [[(t.parent_frame_id, t.child_frame_id) for t in tfs.transforms] for tfs in decoded["/tf"]]
    tree = [("map", "site"), ("site", "pile"), ("site", "scan")]
    assert chains == [tree, [*tree, ("pile", "grasp")]]  # the last message alone holds the whole tree
    assert len(decoded["/pile/logs"][0].entities) == n_logs
    assert len(decoded["/plan/grasps"][0].entities) == len(rec["plan"]["grasps"])
