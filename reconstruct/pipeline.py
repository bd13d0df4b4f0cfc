"""The reconstruction pipeline: a stereo scan + an RTK survey of log ends → a georeferenced pile.

``reconstruct(scan_dir, gnss_path, out_dir)`` runs every stage and writes its results:

1. **Survey** (:mod:`reconstruct.survey.gnss`): the log end points, checked (RTK fixed unless
   ``allow_float``; no outliers; a log with one end measured is admitted), in the *site frame* (ENU
   at ``site_origin``), each with its accuracy (:func:`reconstruct.fitting.fuse.point_accuracy`).
2. **Scan** (:mod:`reconstruct.scan.stereo`): the fused point cloud of every pair, in the *scan
   frame* (the frame of the calibrations' ``T_pile_cam``). When the pairs carry no pose (a
   handheld/boom camera without a pose sensor; ``pair_poses``), their poses come from pycolmap
   SfM anchored to each pair's stereo depth (:mod:`reconstruct.scan.sfm`) and the scan frame is the
   first pair's left camera.
3. **Scan pose**: ``T_site_scan`` places the scan in the site frame. It comes from the config,
   or from ``scan_pose.json`` in the scan folder (:func:`write_scan_pose` /
   :func:`read_scan_pose`; e.g. the crane's own RTK/IMU pose of the camera, or a survey of the
   rig), or — for an unposed scan, or ``georegister="gnss"`` — from the GNSS end points alone
   (:func:`coarse_scan_pose`: ground plane, yaw and shift search; the site origin is then the
   mean surveyed point, and the refinement below runs in 6 DoF). ``report.json`` names the
   source (``scan_pose_source``: "config", the scan_pose.json path, or "gnss-coarse"). Every
   GNSS end point must then lie within ``max_endpoint_distance_m`` (horizontally; four sigma for an
   imprecise point) of scan points — otherwise the scan and the survey are of different places, or
   a log id is wrong, and the error names the point.
4. **Logs in the scan, matched to the survey** (:mod:`reconstruct.fitting.fuse`): the logs the scan shows
   (ridges of its top view), each surveyed log matched to one of them by its points' accuracies;
   where each log is fitted comes from the scan's axis (and from the survey for a log the scan
   does not show). A log the survey missed but the scan shows is kept (``scan0``...); geometry two
   matchings explain nearly equally well is an error naming the logs to re-measure.
5. **Registration refinement** (:func:`refine_registration`): each matched log is fitted around
   its scan axis; the correction (4 DoF: yaw + translation, or 6 DoF after a coarse pose; translation
   only for parallel logs) that brings the fitted axes — and the ends the scan sees — through the
   survey points, each weighted by its accuracy, robustly (Cauchy), against the prior that the scan
   pose is right to ``scan_pose_sigma_m`` / ``scan_pose_sigma_deg``. Its size, the residuals and the
   points it did not believe (``outliers``) are reported; a correction beyond ``max_correction_m`` /
   ``max_correction_deg`` is an error.
6. **Fit** (:mod:`reconstruct.fitting.fit`): logs, terrain and obstacles in the new *pile frame* (the
   site frame turned about the vertical so the logs' mean direction lies at ``log_direction_deg``
   when that is set, shifted to the centre of the logs, at ground level; a square patch
   of the training images' pixel pitch, :func:`patch_extent`), each log's ends placed from the scan
   where it sees them and from the survey where it does not (:func:`reconstruct.fitting.fuse.place_log_ends`:
   per end a source — scan, fixed, float, inferred — and a 1-sigma uncertainty), the pile checked in
   the twin.
7. **Outputs** in ``out_dir``: ``pile.json`` (with the site georeference), ``ortho.npz`` (the
   re-render in the training format, :func:`synth.render.render_ortho`), ``preview.png``,
   ``compare.png`` (scan seen from above beside the re-render) and ``report.json``
   (``loggrasp.reconstruction-report`` 1.2: per log length, diameters, GNSS residuals, fit
   quality and its ends as placed; the matching (``fusion``); ends on a weak estimate
   (``weak_ends``) and survey points the scan contradicts (``contradicted_points``); registration;
   obstacles; timings).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from reconstruct.errors import FitError, ReconstructError, RegistrationError, ScanError
from reconstruct.fitting.fit import (
    FitConfig, PileFit, fit_log, fit_pile, log_spec_from_fit, natural_key, points_on_no_other_log,
)
from reconstruct.fitting.fuse import (
    FuseConfig, SurveyEnd, absorb_pieces, find_scan_logs, match_survey, place_log_ends, point_accuracy, prior_axis,
    scan_end_interval, seen_end,
)
from reconstruct.scan.sfm import SfmConfig
from reconstruct.scan.stereo import ScanCloud, StereoConfig, scan_cloud
from synth.geometry.frames import apply_T, invert_T, make_T, rot_z
from synth.common.files import atomic_write_bytes
from synth.common.formats import VersionedJson
from synth.scene.pile import Georeference, PileSpec, write_pile

if TYPE_CHECKING:
    from synth.render.ortho import OrthoObservation

SCAN_POSE_FORMAT = "loggrasp.scan-pose"
SCAN_POSE_VERSION = "1.0"
REPORT_FORMAT = "loggrasp.reconstruction-report"
REPORT_VERSION = "1.2"  # 1.1: per-log "fit" (scan, partial, hidden); 1.2: per-end "ends" (source, sigma), "fusion",
#                       "weak_ends", "contradicted_points"
SCAN_POSE = VersionedJson(SCAN_POSE_FORMAT, SCAN_POSE_VERSION, "scan pose", RegistrationError,
                          unreadable_fix="give the scan's scan_pose.json, or --georegister gnss",
                          filename="scan_pose.json")
REPORT = VersionedJson(REPORT_FORMAT, REPORT_VERSION, "reconstruction report", ReconstructError,
                       unreadable_fix="reconstruct the scan again", filename="report.json")
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
    return SCAN_POSE.write(path, {**asdict(pose), "T_site_scan": [list(r) for r in pose.T_site_scan]})


def read_scan_pose(path: str | Path) -> ScanPose:
    """Read ``scan_pose.json`` (or a folder holding one). Raises :class:`RegistrationError`."""
    path = SCAN_POSE.path(path)
    d = SCAN_POSE.read(path)
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
    #                           SfM; "calibration"; "sfm" (pycolmap, reconstruct.scan.sfm)
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
    refine_rounds: int = 3  # kept for old configs: the fits start from the scan's own log axes, one round [-]
    registration_max_sigma_m: float = 0.05  # points less accurate than this (radial) are not in the reported
    #                                         residual RMS; they steer by their accuracy (weight 1/sigma^2) [m]
    registration_robust_sigma: float = 2.5  # Cauchy scale of the registration's normalised residuals [-]
    registration_outlier_sigma: float = 4.0  # a point this many sigma off its fitted axis after it is reported [-]
    registration_prior_sigma_m: float = 0.03  # how far the fitted axis may stray from its prior (scan log) [m]
    scan_pose_sigma_m: float = 0.03  # the given scan pose (the crane's RTK/IMU camera pose) is right to this
    #                                  (1 sigma, per axis; the twin's scans are made so) [m]
    scan_pose_sigma_deg: float = 0.5  # ... and its rotation to this [deg]
    fuse: FuseConfig = field(default_factory=FuseConfig)  # logs found in the scan, matched, their ends placed
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
        for name in ("registration_robust_sigma", "registration_outlier_sigma", "registration_prior_sigma_m",
                     "scan_pose_sigma_m", "scan_pose_sigma_deg", "registration_max_sigma_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")


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
    observation: OrthoObservation | None = None  # the orthographic re-render written to ortho.npz

    @property
    def time_s(self) -> float:
        return float(self.report["timings_s"]["total_s"])


# -- registration ------------------------------------------------------------------------------
def _survey_ends_from(endpoints: dict, sigmas: dict | None) -> dict:
    """:class:`reconstruct.fitting.fuse.SurveyEnd` pairs from plain end points and 1-sigma 3-D accuracies
    (``sigmas``: ``{log_id: (sigma_a, sigma_b)}``; default RTK fixed)."""
    from reconstruct.fitting.fuse import SurveyEnd

    out = {}
    for k, ends in endpoints.items():
        pair = []
        for end, p in zip("ab", ends):
            if p is None:
                pair.append(None)
                continue
            s = (sigmas or {}).get(k, (None, None))["ab".index(end)]
            s = 0.02 if s is None or not np.isfinite(s) else float(s)
            pair.append(SurveyEnd(np.asarray(p, dtype=float), s / math.sqrt(3.0), s / math.sqrt(3.0),
                                  "rtk_fixed" if s <= 0.05 else "rtk_float"))
        out[k] = tuple(pair)
    return out


def _correction(x: np.ndarray, mode: str, with_scale: bool, pivot: np.ndarray) -> np.ndarray:
    """The 4x4 correction of parameters ``x`` (small rotation about ``pivot``, translation, log scale)."""
    import cv2

    if mode == "6dof":
        rvec, t = x[:3], x[3:6]
    elif mode == "4dof":
        rvec, t = np.array([0.0, 0.0, x[0]]), x[1:4]
    else:
        rvec, t = np.zeros(3), x[:3]
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    s = math.exp(float(x[-1])) if with_scale else 1.0
    T = np.eye(4)
    T[:3, :3] = s * R
    T[:3, 3] = pivot + np.asarray(t, dtype=float) - s * R @ pivot
    return T


def refine_registration(points: np.ndarray, endpoints: dict, cfg: ReconstructConfig,
                        sigmas: dict | None = None, priors: dict | None = None, survey: dict | None = None,
                        ) -> tuple[np.ndarray, dict, dict]:
    """Correction ``T`` (4x4, applied to ``points``) that brings the logs fitted to the scan
    through their surveyed end points, a report and the fitted logs (``{log_id: LogSpec}``, moved by
    ``T``). Points and end points in the same frame.

    Each log is fitted around its ``priors`` axis (``{log_id: (a, b)}``; default ``endpoints``);
    the survey points (``survey``: ``{log_id: (SurveyEnd | None, SurveyEnd | None)}``, or
    ``endpoints`` with ``sigmas``, 1-sigma 3-D [m]) are the targets. Each point's distance from its
    fitted axis counts by its own accuracy, robustly (Cauchy-weighted least squares: a float or wrong
    point cannot drag the scan), against a prior that the given scan pose is right to
    ``scan_pose_sigma_m`` / ``scan_pose_sigma_deg``. With one log (or parallel ones) a rotation about
    their common direction is unobservable: translation only. Points whose normalised residual stays
    above ``registration_outlier_sigma`` are reported (``outliers``)."""
    from scipy.optimize import least_squares

    fcfg = cfg.fit
    survey = survey if survey is not None else _survey_ends_from(endpoints, sigmas)
    priors = priors if priors is not None else {k: v for k, v in endpoints.items() if all(p is not None for p in v)}
    axes, failures = {}, {}
    rng = np.random.default_rng(fcfg.seed)
    for log_id in sorted(priors, key=natural_key):
        a, b = priors[log_id]
        try:
            f = fit_log(points, a, b, fcfg, log_id=log_id, rng=rng, sigma_a_m=cfg.registration_prior_sigma_m,
                        sigma_b_m=cfg.registration_prior_sigma_m)
        except ReconstructError as exc:
            failures[log_id] = str(exc)
            continue
        axes[log_id] = (f.centre, f.axis, f)
    if not axes:
        raise RegistrationError("no log could be fitted to the scan around its GNSS axis: "
                                + "; ".join(failures.values()))
    ids = list(axes)
    targets = [(k, end, e) for k in ids if k in survey for end, e in zip("ab", survey[k]) if e is not None]
    if not targets:
        raise RegistrationError("no surveyed end point lies on a log fitted to the scan: nothing to register to")
    C = np.array([axes[k][0] for k, _, _ in targets])
    U = np.array([axes[k][1] for k, _, _ in targets])
    G = np.array([e.position_m for _, _, e in targets])
    SH = np.array([e.sigma_h_m for _, _, e in targets])
    SV = np.array([e.sigma_v_m for _, _, e in targets])
    # where the scan itself sees a surveyed end (its top stops, the scan sees below it): the survey point's
    # place along the axis counts too, which fixes the shift along parallel logs
    # (walked over the points on no other fitted log, as the ends are placed later: a neighbour's top
    # where it touches this log's end is not this log)
    S = np.full((len(targets), 3), np.nan)
    SA = np.ones(len(targets))
    specs = [log_spec_from_fit(axes[k][2], fcfg)[0] for k in ids]
    mine = dict(zip(ids, points_on_no_other_log(points, specs, fcfg.inlier_band_m)))
    clear = dict(zip(ids, points_on_no_other_log(points, specs, fcfg.end_walk_band_m)))
    for i, (k, end, e) in enumerate(targets):
        f = axes[k][2]
        p0, p1 = f.ends
        r = 0.5 * (f.radius_a_m + f.radius_b_m)
        iv = scan_end_interval(points[mine[k]], p0, p1, r, toward_p1=(end == "b"), reach_m=cfg.fuse.end_search_m,
                               cfg=cfg.fuse, on_mask=clear[k][mine[k]])
        if iv.state == "seen":
            u_k = (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9)
            S[i] = p0 + u_k * seen_end(iv)
            SA[i] = math.hypot(e.sigma_along(u_k), cfg.fuse.scan_end_sigma_m)
    seen = np.isfinite(S[:, 0])
    directions = np.array([axes[k][1] for k in ids])
    spread = np.degrees(np.arccos(np.clip(np.abs(directions @ directions.T), 0, 1))).max() if len(ids) > 1 else 0.0
    full = len(ids) >= 2 and spread > 10.0
    mode = cfg.refine_dof if full else "translation"
    with_scale = bool(cfg.refine_with_scale and full)
    pivot = C.mean(axis=0)
    n_rot = {"6dof": 3, "4dof": 1, "translation": 0}[mode]
    x0 = np.zeros(n_rot + 3 + (1 if with_scale else 0))
    sig_rot = math.radians(cfg.scan_pose_sigma_deg)

    def point_residuals(x: np.ndarray) -> np.ndarray:
        """(3 per point) the point's offset from its fitted axis across and up, and along it from the end
        the scan sees (0 where it sees none), in sigmas."""
        T = _correction(x, mode, with_scale, pivot)
        c = C @ T[:3, :3].T + T[:3, 3]
        u = U @ T[:3, :3].T
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        d = G - c
        d -= u * np.einsum("ij,ij->i", d, u)[:, None]
        n_h = np.cross(u, [0.0, 0.0, 1.0])
        n_h /= np.maximum(np.linalg.norm(n_h, axis=1, keepdims=True), 1e-9)
        n_v = np.cross(n_h, u)
        s_v = np.sqrt(SH ** 2 * (n_v[:, 0] ** 2 + n_v[:, 1] ** 2) + SV ** 2 * n_v[:, 2] ** 2)
        along = np.zeros(len(G))
        if seen.any():
            s_end = S[seen] @ T[:3, :3].T + T[:3, 3]
            along[seen] = np.einsum("ij,ij->i", G[seen] - s_end, u[seen]) / SA[seen]
        return np.column_stack([np.einsum("ij,ij->i", d, n_h) / SH, np.einsum("ij,ij->i", d, n_v) / s_v, along])

    def prior(x: np.ndarray) -> np.ndarray:
        r = [x[:n_rot] / sig_rot, x[n_rot:n_rot + 3] / cfg.scan_pose_sigma_m]
        if with_scale:
            r.append(x[-1:] / 0.02)
        return np.concatenate(r)

    w = np.ones(len(targets))
    c_robust = cfg.registration_robust_sigma
    x = x0
    for _ in range(cfg.refine_iterations):
        sw = np.sqrt(w)[:, None]
        sol = least_squares(lambda v: np.concatenate([(point_residuals(v) * sw).ravel(), prior(v)]), x,
                            x_scale=[0.01] * len(x0), max_nfev=100)
        moved = float(np.max(np.abs(sol.x - x)))
        x = sol.x
        r = np.linalg.norm(point_residuals(x), axis=1)
        w_new = 1.0 / (1.0 + (r / c_robust) ** 2)  # Cauchy weights
        if moved < 1e-6 and np.allclose(w_new, w, atol=1e-3):
            break
        w = w_new
    T = _correction(x, mode, with_scale, pivot)

    def metric(Tm: np.ndarray) -> np.ndarray:
        c = C @ Tm[:3, :3].T + Tm[:3, 3]
        u = U @ Tm[:3, :3].T
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        d = G - c
        d -= u * np.einsum("ij,ij->i", d, u)[:, None]
        return np.linalg.norm(d, axis=1)

    before, after = metric(np.eye(4)), metric(T)
    norm_after = np.linalg.norm(point_residuals(x), axis=1)
    good = np.array([e.sigma_h_m * math.sqrt(2) <= cfg.registration_max_sigma_m for _, _, e in targets])
    if not good.any():
        good[:] = True
    scale = float(np.cbrt(abs(np.linalg.det(T[:3, :3]))))
    R = T[:3, :3] / scale
    angle = math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    shift = float(np.linalg.norm(T[:3, 3] + T[:3, :3] @ pivot - pivot))  # at the logs' centre
    outliers = [{"log_id": k, "end": end, "fix": e.fix, "residual_m": float(after[i]),
                 "residual_sigma": float(norm_after[i])}
                for i, (k, end, e) in enumerate(targets) if norm_after[i] > cfg.registration_outlier_sigma]
    report = {
        "mode": mode, "with_scale": with_scale, "scale": scale,
        "correction_m": shift, "correction_deg": angle,
        # RMS over the precise points (RTK fixed): the float ones are metres of noise in comparison
        "residual_rms_before_m": float(np.sqrt(np.mean(before[good] ** 2))),
        "residual_rms_after_m": float(np.sqrt(np.mean(after[good] ** 2))),
        "residual_max_after_m": float(after[good].max()),
        "logs_used": ids, "logs_not_fitted": failures, "end_points_used": int(len(targets)),
        "end_points_precise": int(good.sum()), "end_points_seen": int(seen.sum()), "weights": {f"{k}.{end}": float(wi) for (k, end, _), wi in zip(targets, w)},
        "outliers": outliers, "T_correction": T.tolist(),
    }
    fitted = {}
    for k in ids:
        f = axes[k][2]
        fitted[k] = log_spec_from_fit(f.with_ends(apply_T(T, f.ends)), fcfg)[0]
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
    pose_sigma_m: float = 0.15  # the coarse pose is right to this (1 sigma, the refinement's prior) [m]
    pose_sigma_deg: float = 3.0  # [deg]
    seed: int = 0  # RANSAC seed [-]

    def __post_init__(self) -> None:
        for name in ("voxel_m", "ground_distance_m", "log_min_height_m", "cell_m", "band_m", "yaw_step_deg",
                     "fine_step_deg", "peak_separation_deg", "max_correction_m", "max_correction_deg", "pose_sigma_m",
                     "pose_sigma_deg"):
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


def _survey_ends(survey: Any, origin: Any) -> dict[str, tuple[SurveyEnd | None, SurveyEnd | None]]:
    """Every surveyed log's ends in the site frame at ``origin`` with their accuracies
    (:func:`reconstruct.fitting.fuse.point_accuracy`); ``None`` for an end not measured."""
    site = survey.ends_site(origin)
    out = {}
    for k, (a, b) in site.items():
        pair = []
        for end, p in zip("ab", (a, b)):
            if p is None:
                pair.append(None)
                continue
            gp = survey.point(k, end)
            h, v = point_accuracy(gp)
            pair.append(SurveyEnd(np.asarray(p, dtype=float), h / math.sqrt(2.0), v, gp.fix))
        out[k] = tuple(pair)
    return out


def _new_log_ids(indices: list[int], survey: dict) -> dict[str, int]:
    """Ids for logs the survey missed (``scan0``, ``scan1``, ... not clashing with surveyed ones)."""
    out, n = {}, 0
    for j in indices:
        while f"scan{n}" in survey:
            n += 1
        out[f"scan{n}"] = j
        n += 1
    return out


def _check_coverage(points_xy: np.ndarray, endpoints: dict[str, tuple[Any, Any]],
                    limit_m: float) -> dict[str, list[float | None]]:
    """Horizontal distance from every end point (a :class:`~reconstruct.fitting.fuse.SurveyEnd`, a point, or
    None: not surveyed) to the nearest scan point; an error beyond ``limit_m`` (or four times an
    imprecise point's accuracy)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points_xy)
    out: dict[str, list[float | None]] = {}
    worst = []
    for log_id, ends in endpoints.items():
        out[log_id] = []
        for end, e in zip("ab", ends):
            if e is None:
                out[log_id].append(None)
                continue
            p = e.position_m if isinstance(e, SurveyEnd) else np.asarray(e, dtype=float)
            lim = max(limit_m, 4 * math.sqrt(2) * e.sigma_h_m) if isinstance(e, SurveyEnd) else limit_m
            dist = float(tree.query(p[:2])[0])
            out[log_id].append(dist)
            if dist > lim:
                worst.append((dist, log_id, end, p))
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
    from synth.geometry.frames import OrthoGrid

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

    from synth.render.preview import log_colour_bgr

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
    from reconstruct.scan.calibration import pair_pose_present
    from reconstruct.scan.sfm import camera_clouds, estimate_pair_poses, fuse_pairs
    from reconstruct.scan.stereo import find_pairs, read_pair

    folders = find_pairs(scan_dir)
    posed = [pair_pose_present(f) for f in folders]
    mode = cfg.pair_poses
    if mode == "auto":
        mode = "calibration" if all(posed) or len(folders) == 1 else "sfm"
    if mode == "calibration":
        if len(folders) > 1 and not all(posed):
            missing = [f.name for f, ok in zip(folders, posed) if not ok]
            raise ScanError(f"pairs {missing} have no T_pile_cam in their calibration; estimate the pair poses "
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
                progress: Callable[[str], None] | None = None,
                cloud: ScanCloud | None = None) -> ReconstructionResult:
    """Reconstruct a pile from a stereo scan folder and an RTK survey of the log ends.

    ``scan_dir``: one pair folder (``left.png``, ``right.png``, ``calibration.yaml``) or a folder
    of pair folders, plus ``scan_pose.json`` unless ``config.scan_pose`` is given.
    ``gnss_path``: a survey CSV (:func:`reconstruct.survey.gnss.read_gnss`). ``out_dir``: created; gets
    ``pile.json``, ``ortho.npz``, ``preview.png``, ``compare.png``, ``report.json``.
    ``progress``: called with a short line per stage. ``cloud``: this scan's fused cloud from an
    earlier run (``ReconstructionResult.cloud``), to reconstruct it again with another survey or
    config without matching the stereo pairs again (its pair poses are reported as "given").

    Raises a :class:`~reconstruct.errors.ReconstructError` subclass (``ScanError``,
    ``GnssError``, ``RegistrationError``, ``FitError``) naming the file, log or point at fault.
    """
    from reconstruct.survey.gnss import read_gnss
    from reconstruct.scan.calibration import pair_pose_present
    from reconstruct.scan.stereo import find_pairs
    from synth.errors import SynthError
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.render.preview import preview_image, write_png
    from synth.physics.world import World

    cfg = config or ReconstructConfig()
    say = progress or (lambda s: None)
    scan_dir, out_dir = Path(scan_dir), Path(out_dir)
    timings: dict[str, float] = {}
    t_start = time.perf_counter()

    say(f"reading survey {gnss_path}")
    unposed = not any(pair_pose_present(f) for f in find_pairs(scan_dir))
    pose, pose_source = _pose(scan_dir, cfg, unposed=unposed)
    survey = read_gnss(gnss_path, allow_float=cfg.allow_float, area=None if pose is None else pose.origin,
                       require_both_ends=False)
    origin = survey.default_origin() if pose is None else pose.origin
    survey_site = _survey_ends(survey, origin)
    ends_site = {k: (e[0].position_m, e[1].position_m) for k, e in survey_site.items() if None not in e}
    timings["survey_s"] = time.perf_counter() - t_start

    t = time.perf_counter()
    if cloud is None:
        say(f"matching stereo pairs in {scan_dir}")
        cloud, pair_pose_source, sfm_report = _scan(scan_dir, cfg, say)
    else:
        pair_pose_source, sfm_report = "given", None
    timings["stereo_s"] = time.perf_counter() - t
    if sfm_report is not None:
        timings["sfm_s"] = float(sfm_report["timings_s"].get("total_s", math.nan))

    coarse_report = None
    reg_cfg = cfg
    fuse_cfg = cfg.fuse
    if pose is None:
        t = time.perf_counter()
        say("placing the scan from the GNSS end points (ground plane, yaw search)")
        if not ends_site:
            raise RegistrationError("no log has both ends surveyed: the scan cannot be placed from the survey alone; "
                                    "give a scan pose (scan_pose.json)")
        T_coarse, coarse_report = coarse_scan_pose(cloud.points, cloud.camera_positions, ends_site, cfg.coarse)
        pose = ScanPose(*origin, T_site_scan=tuple(tuple(float(v) for v in r) for r in T_coarse))
        reg_cfg = replace(cfg, refine_dof=cfg.coarse.refine_dof, max_correction_m=cfg.coarse.max_correction_m,
                          max_correction_deg=cfg.coarse.max_correction_deg, scan_pose_sigma_m=cfg.coarse.pose_sigma_m,
                          scan_pose_sigma_deg=cfg.coarse.pose_sigma_deg)
        fuse_cfg = replace(cfg.fuse, pose_sigma_m=max(cfg.fuse.pose_sigma_m, cfg.coarse.pose_sigma_m / 2))
        timings["georegistration_s"] = time.perf_counter() - t

    T_site_scan = pose.matrix()
    pts_site = apply_T(T_site_scan, cloud.points)
    coverage = _check_coverage(pts_site[:, :2], survey_site, cfg.max_endpoint_distance_m)

    # the logs in the scan, matched to the survey: where each log is fitted
    t = time.perf_counter()
    say("finding the logs in the scan and matching them to the survey")
    scan_logs = find_scan_logs(pts_site, fuse_cfg)
    matches, unmatched = match_survey(survey_site, scan_logs, fuse_cfg)
    unmatched = absorb_pieces(matches, unmatched, scan_logs)
    for k, m in matches.items():
        if m.scan_index is None and None in survey_site[k]:
            end = "ab"[survey_site[k].index(None)]
            raise FitError(f"log {k!r} has no end {end!r} in the survey and the scan shows no log near its other end: "
                           f"measure both ends of log {k!r}, or remove it from the survey")
    new_ids = _new_log_ids([j for j in unmatched if scan_logs[j].seen_m >= fuse_cfg.min_new_log_m], survey_site)
    timings["matching_s"] = time.perf_counter() - t

    def priors_for(logs_found: list) -> dict:
        out = {}
        for k, m in matches.items():
            found = None if m.scan_index is None else logs_found[m.scan_index]
            out[k] = prior_axis(survey_ends[k], found, m.reversed, fuse_cfg)
        for k, j in new_ids.items():
            out[k] = (logs_found[j].start_m.copy(), logs_found[j].end_m.copy(), fuse_cfg.axis_sigma_m)
        return out

    survey_ends = survey_site
    priors_site = priors_for(scan_logs)
    # the pile frame: the site frame turned (log_direction_deg) and shifted to the centre of the logs, at
    # ground level
    prior_ends = {k: (a, b) for k, (a, b, _) in priors_site.items()}
    yaw = 0.0 if cfg.log_direction_deg is None else logs_direction(prior_ends) - math.radians(cfg.log_direction_deg)
    R_site_pile = rot_z(yaw)
    all_ends = np.array([p for ends in prior_ends.values() for p in ends]) @ R_site_pile  # turned site axes
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
    survey_ends = {k: tuple(None if e is None else e.moved(T_pile_site) for e in v) for k, v in survey_site.items()}
    logs_pile = [s.moved(T_pile_site) for s in scan_logs]

    t = time.perf_counter()
    reg_report: dict = {"mode": "none"}
    first_pass: dict = {}
    T_corr = np.eye(4)
    # registration: the logs the scan and the survey both show, fitted around their scan axes
    matched = {k: m for k, m in matches.items() if m.scan_index is not None and any(survey_ends[k])}
    if cfg.refine and matched:
        # the fits start from the scan's own log axes, which move with the scan: one round (fit, then the
        # correction) is all; a second would fit the same points the same way
        say("refining the scan pose against the GNSS end points")
        pri = {key: prior_axis(survey_ends[key], logs_pile[m.scan_index], m.reversed, fuse_cfg)[:2]
               for key, m in matched.items()}
        T_corr, reg_report, first_pass = refine_registration(pts[near], {}, reg_cfg, priors=pri,
                                                             survey={key: survey_ends[key] for key in matched})
        reg_report.update({"total_correction_m": reg_report["correction_m"],
                           "total_correction_deg": reg_report["correction_deg"]})
        pts = apply_T(T_corr, pts)
    timings["registration_s"] = time.perf_counter() - t
    # T_site_scan after refinement: site <- pile <- (corrected) <- scan
    T_site_scan_refined = T_site_pile @ T_corr @ T_pile_site @ T_site_scan
    logs_pile = [s.moved(T_corr) for s in logs_pile]

    t = time.perf_counter()
    georef = Georeference(origin_lat_deg=pose.origin_lat_deg, origin_lon_deg=pose.origin_lon_deg,
                          origin_h_m=pose.origin_h_m,
                          T_site_pile=tuple(tuple(float(v) for v in row) for row in T_site_pile))
    in_patch = np.all(np.abs(pts[:, :2]) < extent / 2, axis=1)
    priors = priors_for(logs_pile)
    # logs the survey missed: kept when the scan shows a log there, fitted over most of what it saw
    dropped_new = {}
    for k in list(new_ids):
        a, b, s = priors[k]
        try:
            f = fit_log(pts[in_patch], a, b, cfg.fit, log_id=k, sigma_a_m=s, sigma_b_m=s)
            ok = f.coverage >= fuse_cfg.min_new_log_coverage
            why = f"its fit covers {f.coverage * 100:.0f} % of it"
        except ReconstructError as exc:
            ok, why = False, str(exc)
        if ok:
            first_pass[k] = log_spec_from_fit(f, cfg.fit)[0]
        else:
            dropped_new[k] = why
            del new_ids[k], priors[k]
    lateral = {k: s for k, (_, _, s) in priors.items()}

    def placer(log_id: str, spec, how: str, points: np.ndarray, swapped: bool, on_mask: np.ndarray):
        ends_k = survey_ends.get(log_id, (None, None))
        if how == "scan":
            sig = 0.005  # a fitted axis: a few millimetres across
        elif how == "partial":
            sig = max(lateral[log_id], 0.04)  # seen in part: its axis is a few centimetres sure
        else:
            sig = max((e.sigma_h_m for e in ends_k if e is not None), default=lateral[log_id])
        try:
            return place_log_ends(points, spec, how, ends_k, swapped, sig, fuse_cfg, on_mask=on_mask)
        except FitError as exc:
            raise FitError(f"log {log_id!r}: {exc}") from exc

    fit = fit_pile(pts[in_patch], {k: (a, b) for k, (a, b, _) in priors.items()}, extent, cfg.fit, progress=say,
                   georef=georef, notes=f"reconstructed from {scan_dir} and {gnss_path}", first_pass=first_pass,
                   sigmas={k: (s, s) for k, s in lateral.items()}, place_ends=placer, optional=set(new_ids))
    for k, why in fit.dropped.items():  # a log the survey missed whose points the other logs took: not a log
        dropped_new[k] = why
        del new_ids[k]
    timings["fit_s"] = time.perf_counter() - t
    fusion = {
        "scan_logs": [s.to_dict() for s in logs_pile],
        "matches": {k: m.to_dict() for k, m in matches.items()},
        "new_logs": {k: new_j for k, new_j in new_ids.items()},
        "new_logs_dropped": dropped_new,
        "unmatched_scan_logs": [j for j in unmatched if j not in new_ids.values()],
    }

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
    if pair_pose_source != "given":
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
        "fusion": fusion, "weak_ends": weak_ends(fit.logs, fuse_cfg),
        "contradicted_points": contradicted_points(fit.logs),
        "terrain_coverage": fit.terrain_coverage, "obstacles": fit.obstacles, "moves": fit.moves,
        "timings_s": timings,
    }
    report_path = out_dir / "report.json"
    atomic_write_bytes(report_path, json.dumps(report, indent=1, default=_json_default).encode())
    files["report"] = report_path
    say(f"done in {timings['total_s']:.1f} s")
    return ReconstructionResult(pile=fit.pile, fit=fit, report=report, out_dir=out_dir, files=files, cloud=cloud,
                                observation=obs)


def weak_ends(logs: list, cfg: FuseConfig | None = None) -> list[str]:
    """One line per log end placed on a weak estimate (less certain than ``weak_sigma_m``, or against
    its survey point): what placed it and how sure it is."""
    cfg = cfg or FuseConfig()
    out = []
    for lf in logs:
        for end, e in zip("ab", lf.ends or []):
            if e["sigma_m"] > cfg.weak_sigma_m or e["contradicted"]:
                out.append(f"{lf.log_id} end {end}: {e['source']} (scan: {e['scan']}), +-{e['sigma_m'] * 100:.0f} cm")
    return out


def contradicted_points(logs: list) -> list[str]:
    """One line per survey point the scan contradicts (not used): how far it is from the placed end."""
    out = []
    for lf in logs:
        for end, e in zip("ab", lf.ends or []):
            if e["contradicted"]:
                out.append(f"{lf.log_id} end {end} ({e['gnss_fix']}): {e['gnss_residual_m'] * 100:.0f} cm from where "
                           f"the scan puts it ({e['gnss_residual_sigma']:.1f} sigma); check or re-measure it")
    return out


def read_report(path: str | Path) -> dict:
    """Read a ``report.json`` written by :func:`reconstruct` (the version is checked)."""
    return REPORT.read(path)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot serialise {type(o).__name__}")
