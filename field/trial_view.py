"""A field trial as a Foxglove recording (``RECORD/trial.mcap``) and, optionally, live.

:class:`TrialView` logs what a trial does, when it does it, through the Foxglove SDK: to an MCAP
file (zstd chunks, Foxglove's well-known schemas where one fits, JSON with a JSON schema
otherwise) and, with a port, to a Foxglove WebSocket server on the loopback interface, so the
same channels can be watched live and scrubbed through afterwards. Every message's log time is
the real UTC time the event happened in the trial (when the trial read the scan, when a stage
finished, a CAN frame's recorded time), never going backwards within a topic (a message that
would is logged at its topic's last time); the stamp inside a message (``timestamp``) is when its
data was acquired -- the scan's images and cloud carry the scan's capture time, which for the
bundled demo scan is days before the trial.

Topics (frames: docs/robotics-interfaces.md)::

    /scan/<pair>/left|right  foxglove.CompressedImage  the scan's images (JPEG of the recorded PNGs)
    /scan/points             foxglove.PointCloud       the fused stereo cloud (frame scan; at most MAX_CLOUD_POINTS)
    /tf                      foxglove.FrameTransforms  map -> site -> pile, site -> scan; when the grasp is
                                                       chosen, the same tree again with pile -> grasp
    /pile/logs               foxglove.SceneUpdate      the reconstructed logs as cylinders (frame pile)
    /plan/grasps             foxglove.SceneUpdate      every planned grasp, numbered by rank (frame pile)
    /plan                    JSON                      the plan (plan.json's content)
    /verification/grasps     foxglove.SceneUpdate      the twin-tried grasps coloured by outcome (frame pile)
    /verification/candidates JSON                      one message per tried candidate, with its twin trials
    /command                 JSON                      the command's fields and its SWEREF 99 TM grasp, when sent
    /trial/events            JSON                      the link's events (command, ack, outcome, ...)
    /trial/state             JSON                      record.json's final_state as it changes
    /trial/log               foxglove.Log              every progress line the operator saw
    /can/frames              JSON                      every CAN frame of the session with its decoded signals
    /crane/state             JSON                      the controller's state from its Status and heartbeat frames

The view never stops a trial: a failure to log is counted, warned about once and listed in
``errors`` (the trial record keeps them as ``view_errors``).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from field.errors import FieldError

log = logging.getLogger(__name__)

MCAP_NAME = "trial.mcap"
MAX_CLOUD_POINTS = 100_000  # the point cloud is subsampled evenly to at most this many [-]
JPEG_QUALITY = 90  # of the scan images in the recording [-]
GRASP_DRAW_HEIGHT_M = 0.3  # planned grasps are drawn this far above the highest log top [m]
OUTCOME_COLOURS = {"success": (0.1, 0.8, 0.2), "checked": (0.9, 0.3, 0.1), "not_checked": (0.6, 0.6, 0.6),
                   "pruned": (0.4, 0.4, 0.8)}


class ViewError(FieldError):
    """The live view or the recording cannot start (a port in use, a file that cannot be written)."""


def _ns(t_s: float) -> int:
    return int(round(t_s * 1e9))


def _quat_of(R: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)[:3, :3]).as_quat()
    return float(x), float(y), float(z), float(w)


def _quat_mul(a, b) -> tuple[float, float, float, float]:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


class TrialView:
    """Channels of one trial on a private Foxglove context: an MCAP file at ``part_path`` (renamed
    by :meth:`close`) and, when ``port`` is given, a WebSocket server on ``host``:``port``."""

    def __init__(self, part_path: str | Path, port: int | None = None, host: str = "127.0.0.1") -> None:
        import foxglove

        self._fg = foxglove
        self.part_path = Path(part_path)
        self.errors: list[str] = []
        self.busy_s: dict[str, float] = {}  # wall time spent logging (converting, writing) per item [s]
        self.counts: dict[str, int] = {}
        self._channels: dict[str, Any] = {}
        self._last_ns: dict[str, int] = {}
        self._tree: list[tuple[str, str, np.ndarray]] = []  # the static frames (parent, child, T) once known
        self._lock = threading.RLock()
        self.ctx = foxglove.Context()
        self.server = None
        if port is not None:
            try:
                self.server = foxglove.start_server(name="loggrasp trial", host=host, port=port, context=self.ctx)
            except Exception as exc:  # the SDK raises its own error for a port in use
                raise ViewError(f"cannot serve the live Foxglove view on {host}:{port} ({exc}); choose another "
                                "--foxglove port") from exc
        try:
            self.writer = foxglove.open_mcap(self.part_path, allow_overwrite=True, context=self.ctx)
        except Exception as exc:
            if self.server is not None:
                self.server.stop()
            raise ViewError(f"cannot write {self.part_path}: {exc}") from exc
        self._closed = False

    @property
    def port(self) -> int | None:
        return None if self.server is None else self.server.port

    # -- the logging primitives ------------------------------------------------------------------
    def _channel(self, topic: str, kind: str) -> Any:
        ch = self._channels.get(topic)
        if ch is None:
            if kind == "json":
                ch = self._fg.Channel(topic, schema={"type": "object", "title": topic}, context=self.ctx)
            else:
                ch = getattr(self._fg.channels, f"{kind}Channel")(topic, context=self.ctx)
            self._channels[topic] = ch
        return ch

    def _log(self, topic: str, kind: str, msg: Any, t_s: float) -> None:
        with self._lock:
            if self._closed:
                return
            t = max(_ns(t_s), self._last_ns.get(topic, 0))
            self._last_ns[topic] = t
            self._channel(topic, kind).log(msg, log_time=t)
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def guarded(self, what: str, fn: Callable[..., None], *args: Any, **kwargs: Any) -> None:
        """``fn(*args)``; a failure is logged and kept in :attr:`errors`, never raised into the trial."""
        t0 = time.perf_counter()
        try:
            fn(*args, **kwargs)
        except Exception as exc:
            if not self.errors:
                log.warning("the trial's recording (%s) could not log %s: %s: %s", MCAP_NAME, what,
                            type(exc).__name__, exc, exc_info=True)
            self.errors.append(f"{what}: {type(exc).__name__}: {exc}")
        finally:
            self.busy_s[what] = self.busy_s.get(what, 0.0) + time.perf_counter() - t0

    def _stamp(self, t_s: float) -> Any:
        sec = math.floor(t_s)
        return self._fg.messages.Timestamp(sec, min(999_999_999, round((t_s - sec) * 1e9)))

    def _pose(self, xyz, q=(0.0, 0.0, 0.0, 1.0)) -> Any:
        m = self._fg.messages
        return m.Pose(position=m.Vector3(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
                      orientation=m.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))

    def _tf(self, parent: str, child: str, T: np.ndarray, t_s: float) -> Any:
        m = self._fg.messages
        T = np.asarray(T, dtype=float)
        x, y, z, w = _quat_of(T)
        return m.FrameTransform(timestamp=self._stamp(t_s), parent_frame_id=parent, child_frame_id=child,
                                translation=m.Vector3(x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                                rotation=m.Quaternion(x=x, y=y, z=z, w=w))

    # -- what a trial logs -----------------------------------------------------------------------
    def line(self, text: str, t_s: float | None = None, level: str = "Info") -> None:
        m = self._fg.messages
        t = time.time() if t_s is None else t_s
        self.guarded("a progress line", self._log, "/trial/log", "Log",
                     m.Log(timestamp=self._stamp(t), level=getattr(m.LogLevel, level), message=str(text),
                           name="loggrasp.trial"), t)

    def state(self, final_state: str, t_s: float, **extra: Any) -> None:
        self.guarded("the trial state", self._log, "/trial/state", "json",
                     {"final_state": final_state, "t_utc_s": t_s, **extra}, t_s)

    def scan_images(self, scan_dir: Path, captured_s: float, t_s: float | None = None) -> None:
        """The scan's images, logged at ``t_s`` (when the trial read them), stamped ``captured_s``."""
        t = time.time() if t_s is None else t_s
        self.guarded("the scan images", self._scan_images, Path(scan_dir), captured_s, t)

    def _scan_images(self, scan_dir: Path, captured_s: float, t_s: float) -> None:
        import cv2

        for png in sorted(scan_dir.rglob("*.png")):
            side = png.stem
            if side not in ("left", "right"):
                continue
            img = cv2.imread(str(png), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{png} is not a readable PNG")
            ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            pair = png.parent.name if png.parent != scan_dir else "pair"
            msg = self._fg.messages.CompressedImage(timestamp=self._stamp(captured_s), frame_id=f"{pair}_{side}",
                                                    data=jpg.tobytes(), format="jpeg")
            self._log(f"/scan/{pair}/{side}", "CompressedImage", msg, t_s)

    def reconstructed(self, result: Any, captured_s: float, t_s: float | None = None) -> None:
        """The cloud (stamped with the capture time), the frames and the pile's logs, logged at
        ``t_s`` (when the reconstruction finished)."""
        t = time.time() if t_s is None else t_s
        self.guarded("the point cloud", self._cloud, result, captured_s, t)
        self.guarded("the frames", self._frames, result, t)
        self.guarded("the pile", self._pile, result.pile, t)

    def _cloud(self, result: Any, captured_s: float, t_s: float) -> None:
        cloud = result.cloud
        if cloud is None or len(cloud.points) == 0:
            return
        m = self._fg.messages
        step = max(1, math.ceil(len(cloud.points) / MAX_CLOUD_POINTS))
        pts = np.asarray(cloud.points[::step], dtype=np.float32)
        rgb = (np.clip(np.asarray(cloud.colours[::step]), 0, 1) * 255).astype(np.uint8)
        packed = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgba", "u1", 4)])
        packed["x"], packed["y"], packed["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
        packed["rgba"][:, :3], packed["rgba"][:, 3] = rgb, 255
        F = m.PackedElementFieldNumericType
        fields = [m.PackedElementField(name=n, offset=4 * i, type=F.Float32) for i, n in enumerate("xyz")]
        fields += [m.PackedElementField(name=c, offset=12 + i, type=F.Uint8) for i, c in enumerate(("red", "green",
                                                                                                       "blue", "alpha"))]
        msg = m.PointCloud(timestamp=self._stamp(captured_s), frame_id="scan", pose=self._pose((0, 0, 0)),
                           point_stride=16, fields=fields, data=packed.tobytes())
        self._log("/scan/points", "PointCloud", msg, t_s)

    def _frames(self, result: Any, t_s: float) -> None:
        from synth.geometry.geodesy import site_to_tm

        pile = result.pile
        e, n, h = (np.ravel(v) for v in site_to_tm(pile.georef, np.array([[0.0, 0, 0], [1.0, 0, 0]])))
        yaw = math.atan2(n[1] - n[0], e[1] - e[0])  # the site's east axis in the grid: -convergence
        T_map_site = np.eye(4)
        T_map_site[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        T_map_site[:3, 3] = (e[0], n[0], h[0])
        self._tree = [("map", "site", T_map_site), ("site", "pile", pile.georef.matrix())]
        T_site_scan = (result.report or {}).get("T_site_scan_refined")
        if T_site_scan is not None:
            self._tree.append(("site", "scan", np.asarray(T_site_scan)))
        tfs = [self._tf(parent, child, T, t_s) for parent, child, T in self._tree]
        self._log("/tf", "FrameTransforms", self._fg.messages.FrameTransforms(transforms=tfs), t_s)

    def _pile(self, pile: Any, t_s: float) -> None:
        m = self._fg.messages
        x_to_z = (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5))  # a cylinder's axis is z; a log's is x
        entities = []
        for i, lg in enumerate(pile.logs):
            top = (lg.top_diameter_m or lg.diameter_m) / lg.diameter_m
            r, g, b = lg.colour
            cyl = m.CylinderPrimitive(pose=self._pose(lg.centre_m, _quat_mul(tuple(lg.orientation), x_to_z)),
                                      size=m.Vector3(x=lg.diameter_m, y=lg.diameter_m, z=lg.length_m),
                                      bottom_scale=1.0, top_scale=top, color=m.Color(r=r, g=g, b=b, a=1.0))
            label = m.TextPrimitive(pose=self._pose(np.add(lg.centre_m, (0, 0, lg.diameter_m))), billboard=True,
                                    font_size=14.0, scale_invariant=True, color=m.Color(r=1, g=1, b=1, a=1),
                                    text=f"log {i}")
            entities.append(m.SceneEntity(timestamp=self._stamp(t_s), frame_id="pile", id=f"log{i}",
                                          cylinders=[cyl], texts=[label]))
        self._log("/pile/logs", "SceneUpdate", m.SceneUpdate(entities=entities), t_s)

    def _grasp_entity(self, g: Any, key: str, label: str, z: float, rgb, thick_m: float, t_s: float) -> Any:
        m = self._fg.messages
        d = 0.5 * g.width_m * np.array([math.cos(g.phi_rad), math.sin(g.phi_rad), 0.0])
        c = np.array([g.x_m, g.y_m, z])
        line = m.LinePrimitive(type=m.LinePrimitiveLineType.LineStrip, pose=self._pose((0, 0, 0)),
                               thickness=thick_m, points=[m.Point3(x=p[0], y=p[1], z=p[2]) for p in (c - d, c + d)],
                               color=m.Color(r=rgb[0], g=rgb[1], b=rgb[2], a=1.0))
        text = m.TextPrimitive(pose=self._pose(c + (0, 0, 0.15)), billboard=True, font_size=14.0, scale_invariant=True,
                               color=m.Color(r=rgb[0], g=rgb[1], b=rgb[2], a=1.0), text=label)
        return m.SceneEntity(timestamp=self._stamp(t_s), frame_id="pile", id=key, lines=[line], texts=[text])

    @staticmethod
    def _draw_z(pile: Any) -> float:
        return max(lg.centre_m[2] + lg.diameter_m / 2 for lg in pile.logs) + GRASP_DRAW_HEIGHT_M

    def planned(self, the_plan: Any, pile: Any, t_s: float | None = None) -> None:
        import json

        t = time.time() if t_s is None else t_s
        self.guarded("the plan", lambda: self._log("/plan", "json", json.loads(the_plan.to_json()), t))
        self.guarded("the planned grasps", self._planned, the_plan, pile, t)

    def _planned(self, the_plan: Any, pile: Any, t_s: float) -> None:
        z = self._draw_z(pile)
        ents = [self._grasp_entity(pg.grasp, f"plan{i}", f"#{i + 1} {list(pg.targets)} q={pg.quality:.2f}", z,
                                   (1.0, 0.2, 0.2) if i == 0 else (1.0, 0.85, 0.2), 0.06 if i == 0 else 0.03, t_s)
                for i, pg in enumerate(the_plan.grasps)]
        self._log("/plan/grasps", "SceneUpdate", self._fg.messages.SceneUpdate(entities=ents), t_s)

    def verified(self, verification: Any, pile: Any, t_s: float | None = None) -> None:
        """One message per tried candidate at the time the verification ended (the trials run in
        parallel workers and carry no clock of their own)."""
        if verification is None:
            return
        t = time.time() if t_s is None else t_s
        self.guarded("the verification", self._verified, verification, pile, t)

    def _verified(self, v: Any, pile: Any, t_s: float) -> None:
        from synth.common.files import json_safe

        z = self._draw_z(pile) + 0.05
        ents = []
        for c in v.candidates:
            self._log("/verification/candidates", "json",
                      {**json_safe(c.to_dict()), "chosen": v.chosen is c, "verification_elapsed_s": v.elapsed_s}, t_s)
            colour = OUTCOME_COLOURS["success" if c.verified else c.status]
            ents.append(self._grasp_entity(c.planned.grasp, f"verify{c.rank}",
                                           f"#{c.rank + 1} {c.outcome}" + (" (chosen)" if v.chosen is c else ""), z,
                                           colour, 0.06 if v.chosen is c else 0.03, t_s))
        self._log("/verification/grasps", "SceneUpdate", self._fg.messages.SceneUpdate(entities=ents), t_s)

    def chosen(self, best: Any, pile: Any, t_s: float) -> None:
        """The grasp the command carries as frame ``grasp`` (x: the closing axis, z up) under ``pile``."""
        def log_it() -> None:
            g = best.grasp
            T = np.eye(4)
            T[:2, :2] = [[math.cos(g.phi_rad), -math.sin(g.phi_rad)], [math.sin(g.phi_rad), math.cos(g.phi_rad)]]
            T[:3, 3] = (g.x_m, g.y_m, float(pile.terrain.height_at(g.x_m, g.y_m)))
            # the whole tree again with the grasp: a viewer that seeks past this point (and reads
            # only the last message of /tf) still has map -> site -> pile and the scan
            tree = [self._tf(parent, child, T_pc, t_s) for parent, child, T_pc in self._tree]
            self._log("/tf", "FrameTransforms",
                      self._fg.messages.FrameTransforms(transforms=[*tree, self._tf("pile", "grasp", T, t_s)]), t_s)

        self.guarded("the chosen grasp", log_it)

    def command(self, fields: dict, geo: dict | None, t_s: float) -> None:
        self.guarded("the command", self._log, "/command", "json", {"command": fields, "geo": geo}, t_s)

    def events(self, messages: list[dict]) -> None:
        for msg in sorted(messages, key=lambda d: d.get("t_utc_s", 0.0)):
            self.guarded("a link event", self._log, "/trial/events", "json", msg, msg.get("t_utc_s", time.time()))

    def can_traffic(self, blf_path: Path, secured: bool = False) -> None:
        """Every frame of a CAN recording with its decoded signals (``secured``: the link carried
        authenticated frames); Status and heartbeat frames also as the crane's state."""
        from field.trial_can import decode_recording

        def log_it() -> None:
            for frame in decode_recording(blf_path, secured):
                self._log("/can/frames", "json", frame, frame["t_utc_s"])
                state = frame.get("crane_state")
                if state is not None:
                    self._log("/crane/state", "json", state, frame["t_utc_s"])

        self.guarded("the CAN frames", log_it)

    # -- the end ---------------------------------------------------------------------------------
    def close(self, dest_dir: Path | None) -> Path | None:
        """Finish the file and rename it ``dest_dir/trial.mcap`` (None, or a folder that is gone:
        the recording is dropped with the record); stop the server. Safe twice."""
        with self._lock:
            if self._closed:
                return None
            self._closed = True
        try:
            self.writer.close()
        finally:
            if self.server is not None:
                self.server.stop()
        if dest_dir is None or not Path(dest_dir).is_dir():
            self.part_path.unlink(missing_ok=True)
            return None
        part = Path(dest_dir) / self.part_path.name  # the record folder may have been renamed under it
        dest = Path(dest_dir) / MCAP_NAME
        os.replace(part, dest)
        return dest


def open_live_view(record_dir: Path, port: int | None) -> TrialView | None:
    """A view whose live server is up on 127.0.0.1:``port`` before the trial starts (its recording
    beside ``record_dir`` until :func:`record_view` moves it in); None without a port. Raises
    :class:`ViewError` for a port in use."""
    if port is None:
        return None
    record_dir = Path(record_dir)
    record_dir.parent.mkdir(parents=True, exist_ok=True)
    return TrialView(record_dir.parent / f".{record_dir.name}.{os.getpid()}.mcap.part", port=port)


def record_view(tmp: Path, live: TrialView | None, say: Callable[[str], None]) -> TrialView | None:
    """The view logging into the staged record folder ``tmp`` (``live``'s recording moved there),
    or None when the recording cannot start (said; the trial goes on without it)."""
    if live is not None:
        os.replace(live.part_path, tmp / live.part_path.name)
        live.part_path = tmp / live.part_path.name
        return live
    try:
        return TrialView(tmp / f".{MCAP_NAME}.part")
    except ViewError as exc:
        say(f"WARNING: no {MCAP_NAME} for this trial: {exc}")
        return None
