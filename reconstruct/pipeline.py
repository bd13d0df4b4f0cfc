"""The reconstruction pipeline: a stereo scan + an RTK survey of log ends → a georeferenced pile.

``reconstruct(scan_dir, gnss_path, out_dir)`` runs every stage and writes its results:

1. **Survey** (:mod:`reconstruct.gnss`): the log end points, checked (RTK fixed, both ends of
   every log, no outliers), in the *site frame* (ENU at ``site_origin``).
2. **Scan** (:mod:`reconstruct.stereo`): the fused point cloud of every pair, in the *scan
   frame* (the frame of the calibrations' ``T_pile_cam``). When the pairs carry no pose (a
   handheld/boom camera without a pose sensor; ``pair_poses``), their poses come from pycolmap
   SfM anchored to each pair's stereo depth (:mod:`reconstruct.sfm`) and the scan frame is the
   first pair's left camera.
3. **Scan pose**: ``T_site_scan`` places the scan in the site frame. It comes from the config,
   or from ``scan_pose.json`` in the scan folder (:func:`write_scan_pose` /
   :func:`read_scan_pose`; e.g. the crane's own RTK/IMU pose of the camera, or a survey of the
   rig), or — for an unposed scan, or ``georegister="gnss"`` — from the GNSS end points alone
   (:func:`coarse_scan_pose`: ground plane, yaw and shift search; the site origin is then the
   mean surveyed point, and the refinement below runs in 6 DoF). ``report.json`` names the
   source (``scan_pose_source``: "config", the scan_pose.json path, or "gnss-coarse"). Every
   GNSS end point must then lie within ``max_endpoint_distance_m`` (horizontally) of
   scan points — otherwise the scan and the survey are of different places, or a log id is
   wrong, and the error names the point.
4. **Registration refinement**: each log is fitted to the scan around its GNSS axis; the rigid
   transform (open3d's point-to-point estimation, Umeyama's method; scale optional) that brings
   the fitted axes through the GNSS end points is found by iterating closest points on the
   axes (point-to-line ICP over the end points); the logs are refitted and this repeated until
   the correction is negligible (``refine_rounds``). Its size and the residuals before/after are
   reported; a correction beyond ``max_correction_m`` / ``max_correction_deg`` is an error (the
   fits start from the GNSS axes, so the given pose must be right to a few centimetres).
5. **Fit** (:mod:`reconstruct.fit`): logs, terrain and obstacles in the new *pile frame* (the
   site frame turned about the vertical so the logs' mean direction lies at ``log_direction_deg``
   when that is set, shifted to the centre of the surveyed logs, at ground level; a square patch
   of the training images' pixel pitch, :func:`patch_extent`), the pile checked in the twin.
6. **Outputs** in ``out_dir``: ``pile.json`` (with the site georeference), ``ortho.npz`` (the
   re-render in the training format, :func:`synth.render.render_ortho`), ``preview.png``,
   ``compare.png`` (scan seen from above beside the re-render) and ``report.json``
   (``loggrasp.reconstruction-report`` 1.0: per log length, diameters, GNSS residuals, fit
   quality; registration; obstacles; timings).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from reconstruct.errors import FitError, ReconstructError, RegistrationError, ScanError
from reconstruct.fit import FitConfig, PileFit, fit_log, fit_pile, log_spec_from_fit, natural_key
from reconstruct.sfm import SfmConfig
from reconstruct.stereo import ScanCloud, StereoConfig, scan_cloud
from synth.frames import apply_T, invert_T, make_T, rot_z
from synth.pile import Georeference, PileSpec, atomic_write_bytes, write_pile

SCAN_POSE_FORMAT = "loggrasp.scan-pose"
SCAN_POSE_VERSION = "1.0"
REPORT_FORMAT = "loggrasp.reconstruction-report"
REPORT_VERSION = "1.1"  # 1.1: per-log "fit" (scan, partial, hidden)
PAIR_POSES = ("auto", "calibration", "sfm")
GEOREGISTER = ("auto", "scan-pose", "gnss")
RENDER_PX_MULTIPLE = 16  # re-render sides are a multiple of this (a depth-4 U-Net pools 4 times) [px]
MAX_EXTENT_M = 100.0  # largest pile patch [m]


# -- the scan pose sidecar ---------------------------------------------------------------------
@dataclass(frozen=True)
class ScanPose:
    """Where a scan lies on Earth: the site origin and the scan frame's pose in that site frame."""

    origin_lat_deg: float  # SWEREF 99 [deg]
    origin_lon_deg: float  # SWEREF 99 [deg]
    origin_h_m: float  # ellipsoidal height [m]
    T_site_scan: tuple[tuple[float, ...], ...]  # 4x4, scan frame -> site ENU frame

    def __post_init__(self) -> None:
        Georeference(self.origin_lat_deg, self.origin_lon_deg, self.origin_h_m, self.T_site_scan)

    @property
    def origin(self) -> tuple[float, float, float]:
        return (self.origin_lat_deg, self.origin_lon_deg, self.origin_h_m)

    def matrix(self) -> np.ndarray:
        return np.asarray(self.T_site_scan, dtype=np.float64)


def write_scan_pose(pose: ScanPose, path: str | Path) -> Path:
    """Write ``scan_pose.json`` (a folder: inside it) atomically. Returns the path."""
    path = Path(path)
    if path.is_dir():
        path = path / "scan_pose.json"
    d = {"format": SCAN_POSE_FORMAT, "format_version": SCAN_POSE_VERSION, **asdict(pose)}
    d["T_site_scan"] = [list(r) for r in pose.T_site_scan]
    atomic_write_bytes(path, json.dumps(d, indent=1).encode())
    return path


def read_scan_pose(path: str | Path) -> ScanPose:
    """Read ``scan_pose.json`` (or a folder holding one). Raises :class:`RegistrationError`."""
    path = Path(path)
    if path.is_dir():
        path = path / "scan_pose.json"
    try:
        d = json.loads(path.read_text())
    except OSError as exc:
        raise RegistrationError(f"cannot read scan pose {path}: {exc.strerror or exc}") from exc
    except json.JSONDecodeError as exc:
        raise RegistrationError(f"{path} is not valid JSON: {exc}") from exc
    if not isinstance(d, dict) or d.get("format") != SCAN_POSE_FORMAT:
        raise RegistrationError(f"{path} is not a loggrasp scan pose (format {SCAN_POSE_FORMAT})")
    if str(d.get("format_version", "")).split(".")[0] != SCAN_POSE_VERSION.split(".")[0]:
        raise RegistrationError(f"{path}: scan pose version {d.get('format_version')!r} is not supported "
                                f"(reads {SCAN_POSE_VERSION.split('.')[0]}.x)")
    try:
        return ScanPose(float(d["origin_lat_deg"]), float(d["origin_lon_deg"]), float(d["origin_h_m"]),
                        tuple(tuple(float(v) for v in row) for row in d["T_site_scan"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise RegistrationError(f"malformed scan pose {path}: {exc}") from exc


# -- configuration and result ------------------------------------------------------------------
@dataclass(frozen=True)
class ReconstructConfig:
    """Every setting of :func:`reconstruct` (units in the names/comments)."""

    stereo: StereoConfig = field(default_factory=StereoConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    scan_pose: ScanPose | None = None  # None: read scan_pose.json from the scan folder
    pair_poses: str = "auto"  # "auto": the calibrations' T_pile_cam when every pair has one, else
    #                           SfM; "calibration"; "sfm" (pycolmap, reconstruct.sfm)
    georegister: str = "auto"  # "auto": the scan pose (scan_pose / scan_pose.json); for an unposed
    #                            scan (no pair poses, no scan pose) from the GNSS end points;
    #                            "scan-pose": a scan pose is required; "gnss": from the GNSS end points
    sfm: SfmConfig = field(default_factory=SfmConfig)
    coarse: "CoarseConfig" = field(default_factory=lambda: CoarseConfig())
    allow_float: bool = False  # accept RTK float end points
    max_endpoint_distance_m: float = 1.0  # an end point this far from every scan point is an error [m]
    refine: bool = True  # refine the scan pose against the GNSS end points
    refine_dof: str = "4dof"  # "4dof": yaw + translation (gravity from the camera's IMU kept),
    #                           "6dof": full rotation (roll about a parallel pile is weakly seen)
    refine_with_scale: bool = False  # let the refinement scale the scan (a stereo baseline error)
    refine_iterations: int = 10  # point-to-line iterations per round [-]
    refine_rounds: int = 3  # fit logs + estimate the correction, at most this often [-]
    registration_max_sigma_m: float = 0.05  # less accurate GNSS points do not steer it [m]
    max_correction_m: float = 0.30  # larger refinement translations are an error [m]
    max_correction_deg: float = 5.0  # larger refinement rotations are an error [deg]
    terrain_margin_m: float = 0.75  # terrain reaches this far beyond the outermost log end [m]
    min_extent_m: float = 5.0  # smallest terrain patch [m]
    log_direction_deg: float | None = 45.0  # the pile frame is turned so the logs' mean direction lies at this
    # angle from its +x axis [deg]: the render does not depend on the site's axes, and at 45 deg a long pile lies
    # along the square patch's diagonal (more of them fit the training images' 5 m); None: site axes
    render_size_px: int = 128  # re-render pixels over render_extent_m (the training format) [px]
    render_extent_m: float = 5.0  # side of the training images [m]; a larger patch keeps their pixel pitch
    # (render_extent_m / render_size_px) with more pixels, a multiple of RENDER_PX_MULTIPLE
    render_n: int = 3  # intensity renders [-]
    seed: int = 0  # render colours [-]

    def __post_init__(self) -> None:
        if not self.max_endpoint_distance_m > 0:
            raise ValueError("max_endpoint_distance_m must be > 0 m")
        if self.max_correction_m < 0 or self.max_correction_deg < 0 or self.terrain_margin_m < 0:
            raise ValueError("max_correction_m, max_correction_deg and terrain_margin_m must be >= 0")
        if not 1.0 <= self.min_extent_m <= 100.0:
            raise ValueError("min_extent_m must be in [1, 100] m")
        if self.log_direction_deg is not None and not -180.0 <= self.log_direction_deg <= 180.0:
            raise ValueError(f"log_direction_deg must be in [-180, 180] deg or None, got {self.log_direction_deg}")
        if not 16 <= self.render_size_px <= 2048 or self.render_size_px % RENDER_PX_MULTIPLE:
            raise ValueError(f"render_size_px must be a multiple of {RENDER_PX_MULTIPLE} in [16, 2048], "
                             f"got {self.render_size_px}")
        if not 0.5 <= self.render_extent_m <= 100.0:
            raise ValueError(f"render_extent_m must be in [0.5, 100] m, got {self.render_extent_m}")
        if self.refine_dof not in ("4dof", "6dof"):
            raise ValueError(f"refine_dof must be '4dof' or '6dof', got {self.refine_dof!r}")
        if self.pair_poses not in PAIR_POSES:
            raise ValueError(f"pair_poses must be one of {PAIR_POSES}, got {self.pair_poses!r}")
        if self.georegister not in GEOREGISTER:
            raise ValueError(f"georegister must be one of {GEOREGISTER}, got {self.georegister!r}")
        if self.refine_iterations < 1 or self.refine_rounds < 1:
            raise ValueError("refine_iterations and refine_rounds must be >= 1")


def parse_log_direction(text: str) -> float | None:
    """A command line's ``--log-direction``: an angle [deg], or ``site`` for the site's axes (None)."""
    if text.strip().lower() == "site":
        return None
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--log-direction must be an angle in degrees or 'site', got {text!r}") from None


def logs_direction(ends: dict) -> float:
    """The logs' mean direction [rad] in the horizontal plane of ``ends`` (``{log_id: (a, b)}`` end
    points), in (-pi/2, pi/2]: the length-weighted mean of the axes' directions, which are
    pi-periodic (which end was surveyed first does not matter), so taken on doubled angles."""
    d = np.array([np.asarray(b, dtype=float)[:2] - np.asarray(a, dtype=float)[:2] for a, b in ends.values()])
    length = np.linalg.norm(d, axis=1)
    doubled = length * np.exp(2j * np.arctan2(d[:, 1], d[:, 0]))
    direction = 0.5 * math.atan2(float(doubled.sum().imag), float(doubled.sum().real))
    return direction if direction > -math.pi / 2 else direction + math.pi


def patch_extent(span_m: float, cfg: ReconstructConfig) -> tuple[float, int]:
    """The side of the square pile patch [m] and its re-render size [px] for logs spanning
    ``span_m`` (with margins): at least ``cfg.min_extent_m``, at the training images' pixel pitch
    (``render_extent_m / render_size_px``), a whole multiple of ``RENDER_PX_MULTIPLE`` pixels, so the
    planner sees logs at the size it learned them whatever the pile's spread."""
    pitch = cfg.render_extent_m / cfg.render_size_px
    step = RENDER_PX_MULTIPLE * pitch
    n = RENDER_PX_MULTIPLE * max(math.ceil(cfg.min_extent_m / step - 1e-9), math.ceil(span_m / step - 1e-9), 1)
    if n * pitch > MAX_EXTENT_M + 1e-9:
        raise RegistrationError(f"the surveyed log ends span {span_m:.1f} m with margins; a pile patch is at most "
                                f"{MAX_EXTENT_M:g} m: check the GNSS file for points of another pile")
    return n * pitch, n


@dataclass
class ReconstructionResult:
    """What :func:`reconstruct` produced."""

    pile: PileSpec
    fit: PileFit
    report: dict
    out_dir: Path
    files: dict[str, Path]
    cloud: ScanCloud | None = None  # the scan (scan frame), when kept

    @property
    def time_s(self) -> float:
        return float(self.report["timings_s"]["total_s"])


# -- registration ------------------------------------------------------------------------------
def _rigid_from_correspondences(src: np.ndarray, dst: np.ndarray, with_scale: bool) -> np.ndarray:
    """Similarity/rigid transform (4x4) taking ``src`` points onto ``dst`` (Umeyama, via open3d)."""
    import open3d as o3d

    a = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(src, dtype=np.float64)))
    b = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(dst, dtype=np.float64)))
    corr = o3d.utility.Vector2iVector(np.column_stack([np.arange(len(src)), np.arange(len(src))]).astype(np.int32))
    est = o3d.pipelines.registration.TransformationEstimationPointToPoint(with_scaling=with_scale)
    return np.asarray(est.compute_transformation(a, b, corr), dtype=np.float64)


def refine_registration(points: np.ndarray, endpoints: dict[str, tuple[np.ndarray, np.ndarray]],
                        cfg: ReconstructConfig, sigmas: dict[str, tuple[float, float]] | None = None,
                        ) -> tuple[np.ndarray, dict, dict]:
    """Correction ``T`` (4x4, applied to ``points``) that brings the logs fitted to the scan
    through their GNSS end points, a report (residuals before/after, size of the correction)
    and the fitted logs (``{log_id: LogSpec}``, moved by ``T``). Points and endpoints in the
    same frame. ``sigmas``: ``{log_id: (sigma_a, sigma_b)}`` 1-sigma accuracy of the GNSS points
    [m]; points worse than ``registration_max_sigma_m`` (RTK float) do not steer the transform."""
    fcfg = cfg.fit
    axes = {}
    failures = {}
    rng = np.random.default_rng(fcfg.seed)
    for log_id in sorted(endpoints, key=natural_key):
        a, b = endpoints[log_id]
        try:
            sa, sb = (sigmas or {}).get(log_id, (None, None))
            f = fit_log(points, a, b, fcfg, log_id=log_id, rng=rng, sigma_a_m=sa, sigma_b_m=sb)
        except ReconstructError as exc:
            failures[log_id] = str(exc)
            continue
        axes[log_id] = (f["centre"], f["axis"], f)
    if not axes:
        raise RegistrationError("no log could be fitted to the scan around its GNSS axis: "
                                + "; ".join(failures.values()))
    ids = list(axes)
    sig = np.array([s for k in ids for s in (sigmas or {}).get(k, (0.0, 0.0))], dtype=np.float64)
    good = ~(sig > cfg.registration_max_sigma_m)  # NaN (unknown) counts as good
    if good.sum() < 2:
        good[:] = True
    gnss = np.array([p for k in ids for p in endpoints[k]], dtype=np.float64)[good]
    C = np.array([axes[k][0] for k in ids for _ in range(2)])[good]  # a point on each fitted axis
    U = np.array([axes[k][1] for k in ids for _ in range(2)])[good]
    directions = np.array([axes[k][1] for k in ids])
    # with one log (or parallel ones) a rotation about the common axis is unobservable: translate only
    spread = np.degrees(np.arccos(np.clip(np.abs(directions @ directions.T), 0, 1))).max() if len(ids) > 1 else 0.0
    full = len(ids) >= 2 and spread > 10.0

    def residuals(T):
        c = apply_T(T, C)
        u = U @ T[:3, :3].T
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        t = np.einsum("ij,ij->i", gnss - c, u)
        proj = c + u * t[:, None]
        return proj, np.linalg.norm(gnss - proj, axis=1)

    T = np.eye(4)
    _, before = residuals(T)
    for _ in range(cfg.refine_iterations):
        proj, _ = residuals(T)
        if full and cfg.refine_dof == "6dof":
            dT = _rigid_from_correspondences(proj, gnss, cfg.refine_with_scale)
        elif full:  # yaw about the vertical + translation: the scan's gravity direction is kept
            flat_src, flat_dst = proj.copy(), gnss.copy()
            flat_src[:, 2] = 0.0
            flat_dst[:, 2] = 0.0
            dT = _rigid_from_correspondences(flat_src, flat_dst, cfg.refine_with_scale)
            dT[2, 3] = float(np.mean(gnss[:, 2] - (proj @ dT[:3, :3].T)[:, 2]))
        else:
            dT = make_T(t=np.mean(gnss - proj, axis=0))
        T = dT @ T
        if np.linalg.norm(dT[:3, 3]) < 1e-5 and np.allclose(dT[:3, :3], np.eye(3), atol=1e-7):
            break
    _, after = residuals(T)
    scale = float(np.cbrt(abs(np.linalg.det(T[:3, :3]))))
    R = T[:3, :3] / scale
    angle = math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    shift = float(np.linalg.norm(T[:3, 3]))
    report = {
        "mode": (cfg.refine_dof if full else "translation"),
        "with_scale": bool(cfg.refine_with_scale and full), "scale": scale,
        "correction_m": shift, "correction_deg": angle,
        "residual_rms_before_m": float(np.sqrt(np.mean(before ** 2))),
        "residual_rms_after_m": float(np.sqrt(np.mean(after ** 2))),
        "residual_max_after_m": float(after.max()),
        "logs_used": ids, "logs_not_fitted": failures, "end_points_used": int(good.sum()),
        "T_correction": T.tolist(),
    }
    # the fitted logs, moved with the correction: the first pass of fit_pile
    fitted = {}
    for k in ids:
        f = dict(axes[k][2])
        f["ends"] = apply_T(T, f["ends"])
        fitted[k] = log_spec_from_fit(f, fcfg)[0]
    if shift > cfg.max_correction_m or angle > cfg.max_correction_deg:
        raise RegistrationError(
            f"the scan pose needs a correction of {shift:.2f} m / {angle:.1f} deg to match the GNSS end "
            f"points (limits {cfg.max_correction_m} m / {cfg.max_correction_deg} deg); the scan pose "
            "is wrong, or the survey belongs to another pile"
        )
    return T, report, fitted


# -- coarse georegistration: the scan placed from the GNSS end points alone -----------------------
@dataclass(frozen=True)
class CoarseConfig:
    """Coarse placement of a scan in the site frame from the GNSS end points alone (no scan pose):
    ground plane -> vertical; yaw and horizontal shift by matching the surveyed log axes to the
    scan's raised points; height from the ground under the logs (units in the names/comments)."""

    voxel_m: float = 0.03  # cloud thinned to this first [m]
    ground_distance_m: float = 0.04  # RANSAC ground-plane inlier distance [m]
    ground_iterations: int = 2000  # RANSAC iterations [-]
    min_ground_fraction: float = 0.15  # the dominant plane must hold this share of the points [-]
    log_min_height_m: float = 0.05  # points this far above the ground plane may be logs [m]
    log_max_height_m: float = 2.0  # ... and at most this far [m]
    cell_m: float = 0.02  # raster cell of the yaw/shift search [m]
    band_m: float = 0.05  # support of an axis sample: its depth inside the raised region, full at this [m]
    end_trim_m: float = 0.15  # axis samples this close to a surveyed end are not used [m]
    yaw_step_deg: float = 2.0  # coarse yaw grid [deg]
    fine_step_deg: float = 0.25  # refined yaw grid around the best coarse yaw [deg]
    min_support: float = 0.4  # mean support of the axis samples needed [-]
    ambiguity_ratio: float = 0.9  # a distinct second yaw scoring this share of the best: error [-]
    peak_separation_deg: float = 15.0  # yaws closer than this belong to one peak [deg]
    height_ambiguity_ratio: float = 1.5  # ambiguous yaws: the chosen one's height spread must be
    #                                      this many times smaller than every other's [-]
    refine_dof: str = "6dof"  # refinement after the coarse pose: the vertical came from the ground plane
    max_correction_m: float = 0.30  # refinement limits after the coarse pose [m]
    max_correction_deg: float = 5.0  # [deg]
    seed: int = 0  # RANSAC seed [-]

    def __post_init__(self) -> None:
        for name in ("voxel_m", "ground_distance_m", "log_min_height_m", "cell_m", "band_m", "yaw_step_deg",
                     "fine_step_deg", "peak_separation_deg", "max_correction_m", "max_correction_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.log_max_height_m > self.log_min_height_m:
            raise ValueError("log_max_height_m must be > log_min_height_m")
        if self.end_trim_m < 0 or self.ground_iterations < 10:
            raise ValueError("end_trim_m must be >= 0 and ground_iterations >= 10")
        if not self.height_ambiguity_ratio >= 1:
            raise ValueError(f"height_ambiguity_ratio must be >= 1, got {self.height_ambiguity_ratio}")
        for name in ("min_ground_fraction", "min_support", "ambiguity_ratio"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if self.refine_dof not in ("4dof", "6dof"):
            raise ValueError(f"refine_dof must be '4dof' or '6dof', got {self.refine_dof!r}")


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


def _axis_samples(ends: dict[str, tuple[np.ndarray, np.ndarray]], step_m: float,
                  trim_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along every surveyed axis (site frame, (N, 3)) and their log index."""
    pts, owner = [], []
    for k, (a, b) in enumerate(ends.values()):
        L = float(np.linalg.norm(b[:2] - a[:2]))
        if L <= 2 * trim_m:
            continue
        t = np.arange(trim_m, L - trim_m + 1e-9, step_m) / L
        pts.append(a + np.outer(t, b - a))
        owner.append(np.full(len(t), k))
    if not pts:
        raise RegistrationError("the surveyed logs are too short to place the scan from them")
    return np.concatenate(pts), np.concatenate(owner)


def coarse_scan_pose(points: np.ndarray, camera_positions: np.ndarray,
                     ends_site: dict[str, tuple[np.ndarray, np.ndarray]],
                     cfg: CoarseConfig | None = None) -> tuple[np.ndarray, dict]:
    """``T_site_scan`` (4x4) of a scan whose pose is unknown, from the GNSS end points alone.

    ``points``: the fused cloud (scan frame); ``camera_positions``: the pairs' left cameras
    (scan frame; they tell which side of the ground is up); ``ends_site``: ``{log_id: (a, b)}``
    log end centres in the site frame. Steps: the ground is the dominant plane (open3d
    ``segment_plane``) -> the vertical; points raised above it are rasterised; for every yaw on
    a grid the surveyed axes are rasterised and slid over that raster
    (``cv2.matchTemplate``): the yaw and horizontal shift putting the most axis samples on
    raised points wins (then a finer yaw grid); the height puts the lowest log on the ground
    (a log's axis lies half its seen top height above the ground under it). Returns the pose and
    a report (ground, scores, peaks). Raises :class:`CoarseRegistrationError` when there is no
    ground plane, the best yaw supports too few axis samples, or a distinct second yaw scores
    nearly as well (a symmetric pile: survey another log, or give a scan pose)."""
    import cv2
    import open3d as o3d

    from reconstruct.errors import CoarseRegistrationError

    cfg = cfg or CoarseConfig()
    o3d.utility.random.seed(cfg.seed)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    pc = pc.voxel_down_sample(cfg.voxel_m)
    P = np.asarray(pc.points)
    if len(P) < 100:
        raise CoarseRegistrationError(f"only {len(P)} scan points: too few to find the ground")
    plane, inl = pc.segment_plane(cfg.ground_distance_m, 3, cfg.ground_iterations)
    frac = len(inl) / len(P)
    if frac < cfg.min_ground_fraction:
        raise CoarseRegistrationError(
            f"no dominant ground plane in the scan (the best plane holds {frac * 100:.0f} % of the points, need "
            f"{cfg.min_ground_fraction * 100:.0f} %): the scan must show the ground around the pile, or give a "
            "scan pose (scan_pose.json)")
    n, d = np.asarray(plane[:3], dtype=np.float64), float(plane[3])
    norm = float(np.linalg.norm(n))
    n, d = n / norm, d / norm
    cams = np.atleast_2d(np.asarray(camera_positions, dtype=np.float64))
    if len(cams) and np.median(cams @ n + d) < 0:  # the cameras are above the ground
        n, d = -n, -d
    # R_level: the shortest rotation taking n to +z
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(n, z), float(n @ z)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    R_level = np.eye(3) + vx + vx @ vx / (1 + c) if c > -0.999999 else np.diag([1.0, -1.0, -1.0])
    T_level_scan = make_T(R_level, (0.0, 0.0, d))  # level z = height above the ground plane
    Q = apply_T(T_level_scan, P)
    raised = Q[(Q[:, 2] > cfg.log_min_height_m) & (Q[:, 2] < cfg.log_max_height_m)]
    if len(raised) < 50:
        raise CoarseRegistrationError("the scan shows (almost) nothing above the ground plane: no logs to match")
    # raster of raised points (level frame), dilated by the band
    lo = raised[:, :2].min(0) - 0.5
    hi = raised[:, :2].max(0) + 0.5
    shape = tuple(int(v) for v in np.ceil((hi - lo) / cfg.cell_m)[::-1] + 1)  # rows (y), cols (x)
    occ = np.zeros(shape, np.uint8)
    ij = np.floor((raised[:, :2] - lo) / cfg.cell_m).astype(np.int64)
    occ[ij[:, 1], ij[:, 0]] = 1
    occ = cv2.morphologyEx(occ, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    # how deep inside the raised region a cell lies: largest on a log's centre line (its axis seen from
    # above), so a surveyed axis scores most when it runs along the middle of a log, not just across one
    inside = cv2.distanceTransform(occ, cv2.DIST_L2, 5) * cfg.cell_m
    occ = (np.clip(inside, 0.0, cfg.band_m) / cfg.band_m).astype(np.float32)
    samples, owner = _axis_samples(ends_site, cfg.cell_m, cfg.end_trim_m)
    centre = samples[:, :2].mean(0)
    rel = samples[:, :2] - centre

    def score(yaw: float) -> tuple[float, np.ndarray]:
        a = rel @ _rot_z(-yaw).T  # axis samples in the level frame, up to a shift
        amin = a.min(0)
        idx = np.floor((a - amin) / cfg.cell_m).astype(np.int64)
        th, tw = int(idx[:, 1].max()) + 1, int(idx[:, 0].max()) + 1
        if th >= occ.shape[0] or tw >= occ.shape[1]:
            return 0.0, np.zeros(2)
        tmpl = np.zeros((th, tw), np.float32)
        np.add.at(tmpl, (idx[:, 1], idx[:, 0]), 1.0)
        res = cv2.matchTemplate(occ, tmpl, cv2.TM_CCORR)
        _, best, _, loc = cv2.minMaxLoc(res)
        # level position of the samples' centre: template origin + (centre - amin)
        u = lo + np.array(loc, dtype=np.float64) * cfg.cell_m - amin
        return float(best) / len(a), u

    from scipy.spatial import cKDTree

    tree = cKDTree(raised[:, :2])

    def height_spread(yaw: float, u: np.ndarray) -> float:
        """Median absolute deviation [m] of (surveyed axis height - scan top height under it) over
        the axis samples: nearly constant (a radius and the ground offset) at the right yaw; at a
        wrong one the survey's high logs land on low scan points and the other way round."""
        R2 = _rot_z(yaw)
        lvl = (samples[:, :2] - (centre - R2 @ u)) @ R2
        nb = tree.query_ball_point(lvl, 0.03)
        d = np.array([samples[k, 2] - float(np.max(raised[j, 2])) for k, j in enumerate(nb) if len(j)])
        if len(d) < 0.3 * len(samples):
            return math.inf
        return float(np.median(np.abs(d - np.median(d))))

    def refine_yaw(y0: float) -> tuple[float, float, np.ndarray]:
        fine = np.radians(np.arange(-cfg.yaw_step_deg, cfg.yaw_step_deg + 1e-9, cfg.fine_step_deg)) + y0
        y, (b, u) = max(((float(y), score(float(y))) for y in fine), key=lambda t: t[1][0])
        return y, b, u

    yaws = np.radians(np.arange(-180.0, 180.0, cfg.yaw_step_deg))
    coarse = [score(float(y)) for y in yaws]
    sc = np.array([c[0] for c in coarse])
    i_best = int(np.argmax(sc))
    sep = np.radians(cfg.peak_separation_deg)
    dist = np.abs((yaws - yaws[i_best] + np.pi) % (2 * np.pi) - np.pi)
    peak = (sc >= np.roll(sc, 1)) & (sc >= np.roll(sc, -1))  # local maxima (circular)
    other = peak & (dist > sep)
    second = float(sc[other].max()) if other.any() else 0.0
    y_second = float(yaws[other][int(np.argmax(sc[other]))]) if other.any() else math.nan
    best_yaw, best, u = refine_yaw(float(yaws[i_best]))
    report = {
        "ground_plane_scan": [float(v) for v in (*n, d)], "ground_fraction": float(frac),
        "raised_points": int(len(raised)), "axis_samples": int(len(samples)),
        "yaw_deg": math.degrees(best_yaw), "support": best,
        "second_peak_yaw_deg": math.degrees(y_second) if np.isfinite(y_second) else None,
        "second_peak_support": second,
        "yaw_scores": {"step_deg": cfg.yaw_step_deg, "support": [round(float(v), 4) for v in sc]},
    }
    if best < cfg.min_support:
        raise CoarseRegistrationError(
            f"no yaw puts the surveyed logs on the scan: at best {best * 100:.0f} % of the axis samples lie on "
            f"raised scan points (need {cfg.min_support * 100:.0f} %). The survey belongs to another pile, the "
            "scan misses part of it, or the ground was not found; give a scan pose (scan_pose.json)")
    if second >= cfg.ambiguity_ratio * best:
        # the top view alone cannot tell: every yaw peak scoring nearly as well is placed and judged by
        # the heights (the survey's 3-D ends against the scan's tops); one must be clearly more consistent
        cand_yaws = [float(yaws[i_best])]
        for i in np.argsort(-sc):
            far = all(abs((yaws[i] - y + np.pi) % (2 * np.pi) - np.pi) > sep for y in cand_yaws)
            if peak[i] and far and sc[i] >= cfg.ambiguity_ratio * sc[i_best]:
                cand_yaws.append(float(yaws[i]))
        cands = []
        for y0 in cand_yaws:
            y, b, uu = refine_yaw(y0)
            cands.append((height_spread(y, uu), y, b, uu))
        cands.sort(key=lambda c: c[0])
        report["height_spread_m"] = {f"{math.degrees(c[1]):.1f}": c[0] for c in cands}
        (h1, y1, b1, u1), (h2, y2, b2, _) = cands[0], cands[1]
        if not (math.isfinite(h1) and h1 * cfg.height_ambiguity_ratio <= h2):
            raise CoarseRegistrationError(
                f"the scan fits the surveyed logs almost equally well at yaw {math.degrees(best_yaw):.0f} deg "
                f"({best * 100:.0f} % support) and {math.degrees(y_second):.0f} deg ({second * 100:.0f} %), and "
                f"the heights do not tell them apart either ({h1 * 100:.1f} vs {h2 * 100:.1f} cm spread): the "
                "pile looks (nearly) symmetric. Survey a log that breaks the symmetry, or give a scan pose "
                "(scan_pose.json)")
        best_yaw, best, u = y1, b1, u1
        report.update(yaw_deg=math.degrees(best_yaw), support=best, resolved_by="heights")
    # height: a log's axis lies half its seen top height above the ground under it, if it lies on the
    # ground; logs on other logs give higher grounds, so the lowest log sets the height
    R2 = _rot_z(best_yaw)
    t_xy = centre - R2 @ u  # site_xy = R2 @ level_xy + t_xy
    lvl = (samples[:, :2] - t_xy) @ R2  # = R2.T @ (site - t)
    grounds = []
    for k in np.unique(owner):
        sel = owner == k
        nb = tree.query_ball_point(lvl[sel], 0.03)
        tops = [float(np.max(raised[j, 2])) for j in nb if len(j)]
        if len(tops) >= 5:
            h_top = float(np.median(tops))
            grounds.append(float(np.median(samples[sel, 2])) - h_top / 2)
    if not grounds:
        raise CoarseRegistrationError("no surveyed log has raised scan points along its axis")
    dz = float(min(grounds))
    T_site_level = np.eye(4)
    T_site_level[:2, :2] = R2
    T_site_level[:3, 3] = (t_xy[0], t_xy[1], dz)
    report["ground_height_site_m"] = dz
    return T_site_level @ T_level_scan, report


def _point_sigma(p: Any) -> float:
    """1-sigma 3-D accuracy [m] of a GNSS point: its receiver estimates (and epoch scatter), or
    typical RTK values (fixed 1.5/2.5 cm, float 25/40 cm) when unknown."""
    fixed = p.fix == "rtk_fixed"
    h = p.h_acc_m if np.isfinite(p.h_acc_m) else (0.015 if fixed else 0.25)
    v = p.v_acc_m if np.isfinite(p.v_acc_m) else (0.025 if fixed else 0.40)
    h = max(h, p.spread_h_m)
    v = max(v, p.spread_v_m)
    return float(max(h, v))


def _check_coverage(points_xy: np.ndarray, endpoints: dict[str, tuple[np.ndarray, np.ndarray]],
                    limit_m: float) -> dict[str, list[float]]:
    """Horizontal distance from every end point to the nearest scan point; error beyond ``limit_m``."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points_xy)
    out = {}
    worst = []
    for log_id, ends in endpoints.items():
        d, _ = tree.query(np.array([e[:2] for e in ends]))
        out[log_id] = [float(v) for v in d]
        for end, dist in zip("ab", d):
            if dist > limit_m:
                worst.append((float(dist), log_id, end, ends["ab".index(end)]))
    if worst:
        worst.sort(reverse=True)
        dist, log_id, end, p = worst[0]
        raise RegistrationError(
            f"GNSS point of log {log_id!r} end {end!r} (site E {p[0]:.2f} m, N {p[1]:.2f} m) is {dist:.2f} m "
            f"from the nearest scan point (limit {limit_m} m); {len(worst)} end point(s) lie outside the "
            "scanned area. Check the log id and the scan pose, or scan the whole pile"
        )
    return out


# -- pictures ---------------------------------------------------------------------------------
def scan_top_view(points: np.ndarray, colours: np.ndarray, extent_m: float, size_px: int) -> np.ndarray:
    """BGR uint8 top view of a coloured cloud (pile frame) on the ortho grid: the highest point
    per pixel; grey where nothing was seen."""
    from synth.frames import OrthoGrid

    g = OrthoGrid(size_px, extent_m)
    r, c = g.pile_to_pixel(points[:, 0], points[:, 1])
    r, c = np.rint(r).astype(np.int64), np.rint(c).astype(np.int64)
    ok = (r >= 0) & (r < size_px) & (c >= 0) & (c < size_px)
    r, c, z, col = r[ok], c[ok], points[ok, 2], colours[ok]
    order = np.argsort(z)  # later (higher) points overwrite lower ones
    img = np.full((size_px, size_px, 3), 128, np.uint8)
    img[r[order], c[order]] = (np.clip(col[order][:, ::-1], 0, 1) * 255).astype(np.uint8)
    return img


def comparison_image(points: np.ndarray, colours: np.ndarray, obs: Any, scale: int = 4) -> np.ndarray:
    """The scan from above (left) beside the re-render with log outlines (right), BGR uint8."""
    import cv2

    from synth.preview import log_colour_bgr

    n = obs.depth.shape[0]
    size = n * scale
    left = scan_top_view(points, colours, obs.extent_m, size)
    grey = (np.clip(obs.intensity[0], 0, 1) * 255).astype(np.uint8)
    right = cv2.cvtColor(cv2.resize(grey, (size, size), interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
    inst = cv2.resize(obs.instance.astype(np.int32), (size, size), interpolation=cv2.INTER_NEAREST)
    for i in range(obs.n_logs):
        mask = (inst == i + 1).astype(np.uint8)
        if mask.any():
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(left, contours, -1, log_colour_bgr(i), 1)  # thin: the scan stays visible
            cv2.drawContours(right, contours, -1, log_colour_bgr(i), 2)
    cv2.putText(left, "scan (top view) + fitted logs", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1)
    cv2.putText(right, "re-render (training format)", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1)
    return np.concatenate([left, np.full((size, 4, 3), 255, np.uint8), right], axis=1)


# -- the pipeline -----------------------------------------------------------------------------
def _pose(scan_dir: Path, cfg: ReconstructConfig, unposed: bool = False) -> tuple[ScanPose | None, str]:
    """The given scan pose and where it came from; ``(None, "gnss-coarse")`` when it is to be
    found from the GNSS end points (``georegister="gnss"``, or "auto" for an unposed scan)."""
    if cfg.georegister == "gnss":
        return None, "gnss-coarse"
    if cfg.scan_pose is not None:
        return cfg.scan_pose, "config"
    path = scan_dir / "scan_pose.json"
    if not path.exists():
        if cfg.georegister == "auto" and unposed:
            return None, "gnss-coarse"
        raise RegistrationError(
            f"{scan_dir} has no scan_pose.json and no scan pose was given: the scan cannot be placed in "
            "the site frame. Write one with reconstruct.pipeline.write_scan_pose (site origin + "
            "T_site_scan of the scan frame), pass ReconstructConfig(scan_pose=...), or place it from the "
            "GNSS end points (ReconstructConfig(georegister='gnss'), loggrasp reconstruct --georegister gnss)"
        )
    return read_scan_pose(path), str(path)


def _scan(scan_dir: Path, cfg: ReconstructConfig, say: Callable[[str], None]) -> tuple[ScanCloud, str, dict | None]:
    """The fused cloud (scan frame), where the pair poses came from ("calibration", "sfm",
    "single pair") and the SfM report (None without SfM)."""
    from reconstruct.sfm import camera_clouds, estimate_pair_poses, fuse_pairs, pair_has_pose
    from reconstruct.stereo import find_pairs, read_pair

    folders = find_pairs(scan_dir)
    posed = [pair_has_pose(f / "calibration.yaml") for f in folders]
    mode = cfg.pair_poses
    if mode == "auto":
        mode = "calibration" if all(posed) or len(folders) == 1 else "sfm"
    if mode == "calibration":
        if len(folders) > 1 and not all(posed):
            missing = [f.name for f, ok in zip(folders, posed) if not ok]
            raise ScanError(f"pairs {missing} have no T_pile_cam in calibration.yaml; estimate the pair poses "
                            "by SfM (pair_poses='sfm' / --pair-poses sfm) or add them")
        return scan_cloud(scan_dir, cfg.stereo, progress=say), ("calibration" if all(posed) else "single pair"), None
    if len(folders) < 2:
        raise ScanError(f"{scan_dir} holds one stereo pair: SfM needs two or more (pair_poses='calibration')")
    say(f"reading {len(folders)} pairs")
    pairs = [read_pair(f) for f in folders]
    t = time.perf_counter()
    clouds = camera_clouds(pairs, cfg.stereo, progress=say)
    t_match = time.perf_counter() - t
    poses = estimate_pair_poses(pairs, cfg.sfm, clouds=clouds, progress=say)
    cloud = fuse_pairs(pairs, poses.T_scan_cam, cfg.stereo, clouds=clouds, progress=say)
    cloud.timings_s["match_s"] = t_match
    cloud.timings_s["total_s"] += t_match
    return cloud, "sfm", poses.to_dict()


def reconstruct(scan_dir: str | Path, gnss_path: str | Path, out_dir: str | Path,
                config: ReconstructConfig | None = None,
                progress: Callable[[str], None] | None = None) -> ReconstructionResult:
    """Reconstruct a pile from a stereo scan folder and an RTK survey of the log ends.

    ``scan_dir``: one pair folder (``left.png``, ``right.png``, ``calibration.yaml``) or a folder
    of pair folders, plus ``scan_pose.json`` unless ``config.scan_pose`` is given.
    ``gnss_path``: a survey CSV (:func:`reconstruct.gnss.read_gnss`). ``out_dir``: created; gets
    ``pile.json``, ``ortho.npz``, ``preview.png``, ``compare.png``, ``report.json``.
    ``progress``: called with a short line per stage.

    Raises a :class:`~reconstruct.errors.ReconstructError` subclass (``ScanError``,
    ``GnssError``, ``RegistrationError``, ``FitError``) naming the file, log or point at fault.
    """
    from reconstruct.gnss import read_gnss
    from reconstruct.sfm import pair_has_pose
    from reconstruct.stereo import find_pairs
    from synth.errors import SynthError
    from synth.render import OrthoRenderConfig, render_ortho
    from synth.preview import preview_image, write_png
    from synth.world import World

    cfg = config or ReconstructConfig()
    say = progress or (lambda s: None)
    scan_dir, out_dir = Path(scan_dir), Path(out_dir)
    timings: dict[str, float] = {}
    t_start = time.perf_counter()

    say(f"reading survey {gnss_path}")
    unposed = not any(pair_has_pose(f / "calibration.yaml") for f in find_pairs(scan_dir))
    pose, pose_source = _pose(scan_dir, cfg, unposed=unposed)
    survey = read_gnss(gnss_path, allow_float=cfg.allow_float, area=None if pose is None else pose.origin)
    origin = survey.default_origin() if pose is None else pose.origin
    ends_site = {k: (np.asarray(a, float), np.asarray(b, float))
                 for k, (a, b) in survey.endpoints_site(origin).items()}
    sigmas = {k: tuple(_point_sigma(survey.point(k, end)) for end in ("a", "b")) for k in ends_site}
    timings["survey_s"] = time.perf_counter() - t_start

    t = time.perf_counter()
    say(f"matching stereo pairs in {scan_dir}")
    cloud, pair_pose_source, sfm_report = _scan(scan_dir, cfg, say)
    timings["stereo_s"] = time.perf_counter() - t
    if sfm_report is not None:
        timings["sfm_s"] = float(sfm_report["timings_s"].get("total_s", math.nan))

    coarse_report = None
    reg_cfg = cfg
    if pose is None:
        t = time.perf_counter()
        say("placing the scan from the GNSS end points (ground plane, yaw search)")
        T_coarse, coarse_report = coarse_scan_pose(cloud.points, cloud.camera_positions, ends_site, cfg.coarse)
        pose = ScanPose(*origin, T_site_scan=tuple(tuple(float(v) for v in r) for r in T_coarse))
        reg_cfg = replace(cfg, refine_dof=cfg.coarse.refine_dof, max_correction_m=cfg.coarse.max_correction_m,
                          max_correction_deg=cfg.coarse.max_correction_deg)
        timings["georegistration_s"] = time.perf_counter() - t

    # site frame, then the pile frame: the site frame turned (log_direction_deg) and shifted to the
    # centre of the logs, at ground level
    T_site_scan = pose.matrix()
    pts_site = apply_T(T_site_scan, cloud.points)
    coverage = _check_coverage(pts_site[:, :2], ends_site, cfg.max_endpoint_distance_m)
    yaw = 0.0 if cfg.log_direction_deg is None else logs_direction(ends_site) - math.radians(cfg.log_direction_deg)
    R_site_pile = rot_z(yaw)
    all_ends = np.array([p for ends in ends_site.values() for p in ends]) @ R_site_pile  # turned site axes
    centre_xy = 0.5 * (all_ends[:, :2].min(0) + all_ends[:, :2].max(0))
    reach = float(np.max(np.abs(all_ends[:, :2] - centre_xy))) + cfg.terrain_margin_m
    extent, render_px = patch_extent(2 * reach, cfg)
    pts_turned = pts_site @ R_site_pile
    near = np.all(np.abs(pts_turned[:, :2] - centre_xy) < extent / 2, axis=1)
    if near.sum() < 100:
        raise RegistrationError(f"only {int(near.sum())} scan points lie on the {extent} m patch around the logs")
    z0 = float(np.percentile(pts_site[near, 2], 10))
    T_site_pile = make_T(R_site_pile, R_site_pile @ np.array([centre_xy[0], centre_xy[1], z0]))
    T_pile_site = invert_T(T_site_pile)
    pts = apply_T(T_pile_site, pts_site)
    ends = {k: (apply_T(T_pile_site, a), apply_T(T_pile_site, b)) for k, (a, b) in ends_site.items()}

    t = time.perf_counter()
    reg_report: dict = {"mode": "none"}
    first_pass = None
    T_corr = np.eye(4)
    if cfg.refine:
        # rounds: the logs are refitted after each correction (a pose error of several cm
        # moves the scan away from the GNSS axes the fits start from)
        rounds = []
        best = None
        for k in range(cfg.refine_rounds):
            say(f"refining the scan pose against the GNSS end points (round {k + 1})")
            T_k, rep_k, fp_k = refine_registration(apply_T(T_corr, pts[near]), ends, reg_cfg, sigmas)
            rounds.append({key: rep_k[key] for key in (
                "correction_m", "correction_deg", "residual_rms_before_m", "residual_rms_after_m")})
            if best is not None and rep_k["residual_rms_after_m"] >= best:
                rounds[-1]["kept"] = False  # refitting did not help: keep the previous round
                break
            rounds[-1]["kept"] = True
            best = rep_k["residual_rms_after_m"]
            T_corr, reg_report, first_pass = T_k @ T_corr, rep_k, fp_k
            if rep_k["correction_m"] < 0.005 and rep_k["correction_deg"] < 0.2:
                break
        R = T_corr[:3, :3] / np.cbrt(abs(np.linalg.det(T_corr[:3, :3])))
        reg_report.update({
            "rounds": rounds, "T_correction": T_corr.tolist(),
            "total_correction_m": float(np.linalg.norm(T_corr[:3, 3])),
            "total_correction_deg": math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1, 1)))),
            "residual_rms_before_m": rounds[0]["residual_rms_before_m"],
        })
        pts = apply_T(T_corr, pts)
    timings["registration_s"] = time.perf_counter() - t
    # T_site_scan after refinement: site <- pile <- (corrected) <- scan
    T_site_scan_refined = T_site_pile @ T_corr @ T_pile_site @ T_site_scan

    t = time.perf_counter()
    georef = Georeference(origin_lat_deg=pose.origin_lat_deg, origin_lon_deg=pose.origin_lon_deg,
                          origin_h_m=pose.origin_h_m,
                          T_site_pile=tuple(tuple(float(v) for v in row) for row in T_site_pile))
    in_patch = np.all(np.abs(pts[:, :2]) < extent / 2, axis=1)
    fit = fit_pile(pts[in_patch], ends, extent, cfg.fit, progress=say, georef=georef,
                   notes=f"reconstructed from {scan_dir} and {gnss_path}", first_pass=first_pass,
                   sigmas=sigmas)
    timings["fit_s"] = time.perf_counter() - t

    t = time.perf_counter()
    say(f"writing {out_dir}")
    try:
        with World(fit.pile) as world:
            obs = render_ortho(world, OrthoRenderConfig(size_px=render_px, n_renders=cfg.render_n),
                               seed=cfg.seed)
    except SynthError as exc:  # nothing written: no pile that the twin cannot show
        raise FitError(f"the reconstructed pile cannot be re-rendered ({exc}); check the per-log fits "
                       "(a log seen only in part may have been fitted astray) and the GNSS end points") from exc
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {"pile": write_pile(fit.pile, out_dir / "pile.json")}
    obs.meta["source"] = "reconstructed"
    files["ortho"] = obs.save(out_dir / "ortho.npz")
    files["preview"] = write_png(out_dir / "preview.png", preview_image(obs))
    files["compare"] = write_png(out_dir / "compare.png", comparison_image(pts[in_patch], cloud.colours[in_patch], obs))
    timings["outputs_s"] = time.perf_counter() - t
    timings["total_s"] = time.perf_counter() - t_start
    timings.update({f"stereo_{k}": v for k, v in cloud.timings_s.items()})
    timings.update({f"fit_{k}": v for k, v in fit.timings_s.items()})

    report = {
        "format": REPORT_FORMAT, "format_version": REPORT_VERSION,
        "scan_dir": str(scan_dir), "gnss": str(gnss_path), "pairs": cloud.pairs,
        "n_points": int(len(cloud.points)), "matched_fraction": cloud.valid_fractions,
        "scan_pose_source": pose_source, "site_origin": list(pose.origin),
        "pair_poses_source": pair_pose_source, "sfm": sfm_report, "coarse_registration": coarse_report,
        "T_site_scan_given": T_site_scan.tolist(), "T_site_scan_refined": T_site_scan_refined.tolist(),
        "T_site_pile": T_site_pile.tolist(), "extent_m": extent,
        "registration": reg_report, "endpoint_scan_distance_m": coverage,
        "survey_warnings": list(survey.warnings),
        "logs": [lf.to_dict() for lf in fit.logs],
        "terrain_coverage": fit.terrain_coverage, "obstacles": fit.obstacles, "moves": fit.moves,
        "timings_s": timings,
    }
    report_path = out_dir / "report.json"
    atomic_write_bytes(report_path, json.dumps(report, indent=1, default=_json_default).encode())
    files["report"] = report_path
    say(f"done in {timings['total_s']:.1f} s")
    return ReconstructionResult(pile=fit.pile, fit=fit, report=report, out_dir=out_dir, files=files, cloud=cloud)


def read_report(path: str | Path) -> dict:
    """Read a ``report.json`` written by :func:`reconstruct` (the version is checked)."""
    path = Path(path)
    if path.is_dir():
        path = path / "report.json"
    try:
        d = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ReconstructError(f"cannot read reconstruction report {path}: {exc}") from exc
    if d.get("format") != REPORT_FORMAT or str(d.get("format_version", "")).split(".")[0] != REPORT_VERSION.split(".")[0]:
        raise ReconstructError(f"{path} is not a {REPORT_FORMAT} {REPORT_VERSION.split('.')[0]}.x report")
    return d


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot serialise {type(o).__name__}")
