"""A picture of a trial's recording (``trial.mcap``) drawn with matplotlib -- NOT a Foxglove screenshot.

Foxglove's app cannot be installed on the offline build machine, so this script shows what the
recording holds the way a reader of it would: the file is read back with the ``mcap`` package's
reader and the protobuf schemas stored in it (``mcap-protobuf-support``), not with the SDK that
wrote it. Panels: the scan's left image; a top view in the pile frame (the point cloud moved
through the recorded frames, the reconstructed logs, the planned grasps and the twin's verdict on
each tried one); and the trial's time line (the stages, the crane's state and every CAN frame).
The picture says in its title that it is not Foxglove.

    .venv/bin/python scripts/mcap_overview.py out/demo/trial/trial.mcap docs/img/trial_mcap_overview.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

TOPICS = ("/scan/pair_000/left", "/scan/points", "/tf", "/pile/logs", "/plan/grasps", "/verification/grasps",
          "/trial/log")
STAGES = {"/scan/pair_000/left": "scan read", "/pile/logs": "pile reconstructed", "/plan": "plan", "/verification/grasps": "verified in the twin",
          "/command": "command sent"}


def read(path: Path) -> tuple[dict, dict]:
    """(protobuf topics -> [(log time ns, message)], JSON topics -> [(log time ns, dict)])."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    proto: dict[str, list] = {}
    js: dict[str, list] = {}
    factory, decoders = DecoderFactory(), {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding == "json":
                js.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
            elif channel.topic in TOPICS:
                if schema.id not in decoders:
                    decoders[schema.id] = factory.decoder_for(channel.message_encoding, schema)
                proto.setdefault(channel.topic, []).append((message.log_time, decoders[schema.id](message.data)))
    return proto, js


def _T(tf) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    q = tf.rotation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = (tf.translation.x, tf.translation.y, tf.translation.z)
    return T


def _cloud_in_pile(proto: dict) -> tuple[np.ndarray, np.ndarray]:
    tfs = {(t.parent_frame_id, t.child_frame_id): _T(t) for _, m in proto["/tf"] for t in m.transforms}
    cloud = proto["/scan/points"][0][1]
    raw = np.frombuffer(cloud.data, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgba", "u1", 4)])
    pts = np.stack([raw["x"], raw["y"], raw["z"], np.ones(len(raw), np.float32)], axis=1).astype(float)
    T_pile_scan = np.linalg.inv(tfs[("site", "pile")]) @ tfs[("site", "scan")]
    return (pts @ T_pile_scan.T)[:, :3], raw["rgba"][:, :3] / 255.0


def _draw_top(ax, proto: dict) -> None:
    from scipy.spatial.transform import Rotation

    xyz, rgb = _cloud_in_pile(proto)
    keep = (np.abs(xyz[:, 0]) < 2.6) & (np.abs(xyz[:, 1]) < 2.6)
    ax.scatter(xyz[keep, 0], xyz[keep, 1], c=rgb[keep], s=0.3, linewidths=0, rasterized=True)
    for ent in proto["/pile/logs"][0][1].entities:
        cyl = ent.cylinders[0]
        p, q = cyl.pose.position, cyl.pose.orientation
        axis = Rotation.from_quat([q.x, q.y, q.z, q.w]).apply([0, 0, 1.0])[:2]
        c = np.array([p.x, p.y])
        a, b = c - axis * cyl.size.z / 2, c + axis * cyl.size.z / 2
        ax.plot([a[0], b[0]], [a[1], b[1]], color="saddlebrown", lw=2.0, alpha=0.8)
        ax.annotate(ent.texts[0].text, c, color="white", fontsize=7, ha="center",
                    bbox=dict(boxstyle="round,pad=0.15", fc="saddlebrown", ec="none", alpha=0.8))
    for topic, lw in (("/plan/grasps", 1.2), ("/verification/grasps", 2.6)):
        for ent in proto[topic][0][1].entities:
            line = ent.lines[0]
            xs, ys = [pt.x for pt in line.points], [pt.y for pt in line.points]
            col = (line.color.r, line.color.g, line.color.b)
            ax.plot(xs, ys, color=col, lw=lw if "chosen" not in ent.texts[0].text else 4.0, solid_capstyle="round")
            if topic == "/verification/grasps":
                ax.annotate(ent.texts[0].text, (xs[1], ys[1]), color=col, fontsize=6)
    ax.set_aspect("equal")
    ax.set_xlim(-2.6, 2.6)
    ax.set_ylim(-2.6, 2.6)
    ax.set_xlabel("pile x [m]")
    ax.set_ylabel("pile y [m]")
    ax.set_title("/scan/points, /pile/logs, /plan/grasps (thin), /verification/grasps (thick: green\n"
                 "succeeded, red failed, blue pruned, grey not checked; the chosen one thickest) in frame pile",
                 fontsize=8)


def _draw_timeline(ax, js: dict, proto: dict) -> None:
    t0 = proto["/trial/log"][0][0]
    s = lambda t: (t - t0) / 1e9  # noqa: E731
    kinds = sorted({f["kind"] for _, f in js["/can/frames"]})
    for t, f in js["/can/frames"]:
        ax.plot(s(t), kinds.index(f["kind"]), "|", color="tab:blue" if f["direction"] == "tx" else "tab:orange", ms=8)
    states = ["IDLE", "EXECUTING", "DONE", "FAULT", "ESTOP"]
    ts = [s(t) for t, _ in js["/crane/state"]]
    ys = [len(kinds) + 1 + states.index(st["state"]) * 0.5 for _, st in js["/crane/state"]]
    ax.step(ts, ys, where="post", color="tab:green", lw=1.5)
    ticks = list(range(len(kinds))) + [len(kinds) + 1 + i * 0.5 for i in range(3)]
    ax.set_yticks(ticks, [f"CAN {k}" for k in kinds] + [f"crane {st}" for st in states[:3]], fontsize=7)
    for topic, label in STAGES.items():
        msgs = proto.get(topic) or js.get(topic)
        if msgs:
            ax.axvline(s(msgs[0][0]), color="grey", ls=":", lw=1)
            ax.annotate(label, (s(msgs[0][0]), ax.get_ylim()[1]), rotation=90, fontsize=7, va="top", ha="right")
    ax.set_xlabel("seconds since the trial's first progress line (log time)")
    ax.set_title("/can/frames (blue: laptop -> crane, orange: crane -> laptop) and /crane/state over the trial",
                 fontsize=8)


def main() -> None:
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mcap", type=Path)
    ap.add_argument("out", type=Path)
    args = ap.parse_args()
    proto, js = read(args.mcap)
    fig = plt.figure(figsize=(14, 9), dpi=90)
    grid = fig.add_gridspec(2, 2, height_ratios=(1.25, 1))
    ax_img, ax_top, ax_t = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, :])
    img = cv2.imdecode(np.frombuffer(proto["/scan/pair_000/left"][0][1].data, np.uint8), cv2.IMREAD_COLOR)
    ax_img.imshow(img[::2, ::2, ::-1])  # half resolution: a smaller picture
    ax_img.set_axis_off()
    ax_img.set_title("/scan/pair_000/left (CompressedImage, JPEG)", fontsize=8)
    _draw_top(ax_top, proto)
    _draw_timeline(ax_t, js, proto)
    fig.suptitle(f"{args.mcap.name} read back with the mcap reader and drawn with matplotlib "
                 "(scripts/mcap_overview.py) -- NOT a Foxglove screenshot", fontsize=11)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
