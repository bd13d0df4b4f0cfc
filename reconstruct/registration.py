"""Georegistration: where the scan lies in the site frame.

* The scan pose sidecar (``scan_pose.json``, :class:`ScanPose`): the crane's own RTK/IMU pose of the
  camera, or a survey of the rig.
* **Coarse** (:func:`coarse_scan_pose`): for a scan with no pose, from the GNSS end points alone:
  the ground plane gives the vertical, a yaw/shift search puts the surveyed axes on the scan's
  raised points, the lowest log sets the height.
* **Refinement** (:func:`refine_registration`): the small correction that brings the logs fitted
  to the scan through their surveyed end points, each weighted by its accuracy, robustly, against
  the prior that the given pose is right.

:func:`reconstruct.pipeline.reconstruct` runs them; they work on plain arrays and end points.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from reconstruct.errors import ReconstructError, RegistrationError
from reconstruct.fitting.fit import CylinderFit, fit_log, log_spec_from_fit, natural_key, points_on_no_other_log
from reconstruct.fitting.fuse import SurveyEnd, scan_end_interval, seen_end
from synth.common.formats import VersionedJson
from synth.geometry.frames import apply_T, make_T
from synth.scene.pile import Georeference

if TYPE_CHECKING:
    from reconstruct.config import ReconstructConfig

SCAN_POSE_FORMAT = "loggrasp.scan-pose"
SCAN_POSE_VERSION = "1.0"
SCAN_POSE = VersionedJson(SCAN_POSE_FORMAT, SCAN_POSE_VERSION, "scan pose", RegistrationError,
                          unreadable_fix="give the scan's scan_pose.json, or --georegister gnss",
                          filename="scan_pose.json")
# three-point samples scored per batch by ransac_plane (a batch x points matrix of distances) [-]
RANSAC_BATCH = 64


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


# -- survey points as targets ---------------------------------------------------------------
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


# -- refinement: the scan pose corrected against the survey -------------------------------------
def refine_registration(points: np.ndarray, endpoints: dict, cfg: "ReconstructConfig",
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
    survey = survey if survey is not None else _survey_ends_from(endpoints, sigmas)
    priors = priors if priors is not None else {k: v for k, v in endpoints.items() if all(p is not None for p in v)}
    fits, failures = _fit_around_priors(points, priors, cfg)
    targets = _Targets.build(points, fits, survey, cfg)
    model = _CorrectionModel.for_logs(fits, targets, cfg)
    x, w = model.solve(targets, cfg)
    T = _correction(x, model.mode, model.with_scale, model.pivot)
    report = _refinement_report(targets, model, x, w, T, list(fits), failures, cfg)
    fitted = {k: log_spec_from_fit(f.with_ends(apply_T(T, f.ends)), cfg.fit)[0] for k, f in fits.items()}
    shift, angle = report["correction_m"], report["correction_deg"]
    if shift > cfg.max_correction_m or angle > cfg.max_correction_deg:
        raise RegistrationError(
            f"the scan pose needs a correction of {shift:.2f} m / {angle:.1f} deg to match the GNSS end "
            f"points (limits {cfg.max_correction_m} m / {cfg.max_correction_deg} deg); the scan pose "
            "is wrong, or the survey belongs to another pile"
        )
    return T, report, fitted


def _fit_around_priors(points: np.ndarray, priors: dict, cfg: "ReconstructConfig",
                       ) -> tuple[dict[str, CylinderFit], dict[str, str]]:
    """Each log fitted to the scan around its prior axis (in natural id order, one random stream);
    the fits and, for the logs that could not be fitted, why."""
    fits, failures = {}, {}
    rng = np.random.default_rng(cfg.fit.seed)
    for log_id in sorted(priors, key=natural_key):
        a, b = priors[log_id]
        try:
            fits[log_id] = fit_log(points, a, b, cfg.fit, log_id=log_id, rng=rng,
                                   sigma_a_m=cfg.registration_prior_sigma_m, sigma_b_m=cfg.registration_prior_sigma_m)
        except ReconstructError as exc:
            failures[log_id] = str(exc)
    if not fits:
        raise RegistrationError("no log could be fitted to the scan around its GNSS axis: "
                                + "; ".join(failures.values()))
    return fits, failures


@dataclass(frozen=True)
class _Targets:
    """The survey points on fitted logs: per point its log (``keys``: (log id, end, SurveyEnd)), the
    fitted axis (centre ``C``, direction ``U``), the point ``G`` and its horizontal / vertical
    1-sigma ``SH`` / ``SV`` [m]; where the scan itself sees that end, the seen end ``S`` (NaN where
    not) and the along-axis sigma ``SA`` [m]."""

    keys: list
    C: np.ndarray
    U: np.ndarray
    G: np.ndarray
    SH: np.ndarray
    SV: np.ndarray
    S: np.ndarray
    SA: np.ndarray

    @property
    def seen(self) -> np.ndarray:
        return np.isfinite(self.S[:, 0])

    @staticmethod
    def build(points: np.ndarray, fits: dict[str, CylinderFit], survey: dict, cfg: "ReconstructConfig") -> "_Targets":
        keys = [(k, end, e) for k in fits if k in survey for end, e in zip("ab", survey[k]) if e is not None]
        if not keys:
            raise RegistrationError("no surveyed end point lies on a log fitted to the scan: nothing to register to")
        S, SA = _seen_ends(points, fits, keys, cfg)
        return _Targets(keys, np.array([fits[k].centre for k, _, _ in keys]), np.array([fits[k].axis for k, _, _ in keys]),
                        np.array([e.position_m for _, _, e in keys]), np.array([e.sigma_h_m for _, _, e in keys]),
                        np.array([e.sigma_v_m for _, _, e in keys]), S, SA)


def _seen_ends(points: np.ndarray, fits: dict[str, CylinderFit], keys: list,
               cfg: "ReconstructConfig") -> tuple[np.ndarray, np.ndarray]:
    """Where the scan itself sees a surveyed end (its top stops, the scan sees below it): the survey
    point's place along the axis counts too, which fixes the shift along parallel logs. Walked over
    the points on no other fitted log, as the ends are placed later (a neighbour's top where it
    touches this log's end is not this log). Returns the seen ends (NaN rows where none) and their
    along-axis sigmas [m]."""
    fcfg = cfg.fit
    S = np.full((len(keys), 3), np.nan)
    SA = np.ones(len(keys))
    ids = list(fits)
    specs = [log_spec_from_fit(fits[k], fcfg)[0] for k in ids]
    mine = dict(zip(ids, points_on_no_other_log(points, specs, fcfg.inlier_band_m)))
    clear = dict(zip(ids, points_on_no_other_log(points, specs, fcfg.end_walk_band_m)))
    for i, (k, end, e) in enumerate(keys):
        f = fits[k]
        p0, p1 = f.ends
        r = 0.5 * (f.radius_a_m + f.radius_b_m)
        iv = scan_end_interval(points[mine[k]], p0, p1, r, toward_p1=(end == "b"), reach_m=cfg.fuse.end_search_m,
                               cfg=cfg.fuse, on_mask=clear[k][mine[k]])
        if iv.state == "seen":
            u_k = (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9)
            S[i] = p0 + u_k * seen_end(iv)
            SA[i] = math.hypot(e.sigma_along(u_k), cfg.fuse.scan_end_sigma_m)
    return S, SA


@dataclass(frozen=True)
class _CorrectionModel:
    """What the correction may do: ``mode`` ("6dof", "4dof" or "translation" for one log or
    parallel ones, whose common direction hides a rotation), a scale or not, about ``pivot`` (the
    fitted logs' centre)."""

    mode: str
    with_scale: bool
    pivot: np.ndarray

    @property
    def n_rot(self) -> int:
        return {"6dof": 3, "4dof": 1, "translation": 0}[self.mode]

    @staticmethod
    def for_logs(fits: dict[str, CylinderFit], targets: _Targets, cfg: "ReconstructConfig") -> "_CorrectionModel":
        directions = np.array([f.axis for f in fits.values()])
        spread = (np.degrees(np.arccos(np.clip(np.abs(directions @ directions.T), 0, 1))).max()
                  if len(fits) > 1 else 0.0)
        full = len(fits) >= 2 and spread > 10.0
        return _CorrectionModel(cfg.refine_dof if full else "translation", bool(cfg.refine_with_scale and full),
                                targets.C.mean(axis=0))

    def residuals(self, x: np.ndarray, t: _Targets) -> np.ndarray:
        """(3 per point) the point's offset from its fitted axis across and up, and along it from the end
        the scan sees (0 where it sees none), in sigmas."""
        T = _correction(x, self.mode, self.with_scale, self.pivot)
        u, d = _axis_offsets(t, T)
        n_h = np.cross(u, [0.0, 0.0, 1.0])
        n_h /= np.maximum(np.linalg.norm(n_h, axis=1, keepdims=True), 1e-9)
        n_v = np.cross(n_h, u)
        s_v = np.sqrt(t.SH ** 2 * (n_v[:, 0] ** 2 + n_v[:, 1] ** 2) + t.SV ** 2 * n_v[:, 2] ** 2)
        along = np.zeros(len(t.G))
        seen = t.seen
        if seen.any():
            s_end = t.S[seen] @ T[:3, :3].T + T[:3, 3]
            along[seen] = np.einsum("ij,ij->i", t.G[seen] - s_end, u[seen]) / t.SA[seen]
        return np.column_stack([np.einsum("ij,ij->i", d, n_h) / t.SH, np.einsum("ij,ij->i", d, n_v) / s_v, along])

    def prior(self, x: np.ndarray, cfg: "ReconstructConfig") -> np.ndarray:
        """The correction in sigmas of the given pose's accuracy (and a 2 % scale)."""
        r = [x[:self.n_rot] / math.radians(cfg.scan_pose_sigma_deg), x[self.n_rot:self.n_rot + 3] / cfg.scan_pose_sigma_m]
        if self.with_scale:
            r.append(x[-1:] / 0.02)
        return np.concatenate(r)

    def solve(self, t: _Targets, cfg: "ReconstructConfig") -> tuple[np.ndarray, np.ndarray]:
        """Cauchy-weighted least squares (``refine_iterations`` reweightings at most): the correction's
        parameters and the points' last weights."""
        from scipy.optimize import least_squares

        n_x = self.n_rot + 3 + (1 if self.with_scale else 0)
        w = np.ones(len(t.keys))
        x = np.zeros(n_x)
        for _ in range(cfg.refine_iterations):
            sw = np.sqrt(w)[:, None]
            sol = least_squares(lambda v: np.concatenate([(self.residuals(v, t) * sw).ravel(), self.prior(v, cfg)]), x,
                                x_scale=[0.01] * n_x, max_nfev=100)
            moved = float(np.max(np.abs(sol.x - x)))
            x = sol.x
            r = np.linalg.norm(self.residuals(x, t), axis=1)
            w_new = 1.0 / (1.0 + (r / cfg.registration_robust_sigma) ** 2)  # Cauchy weights
            if moved < 1e-6 and np.allclose(w_new, w, atol=1e-3):
                break
            w = w_new
        return x, w


def _axis_offsets(t: _Targets, Tm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fitted axes' directions moved by ``Tm`` and each survey point's offset [m] across its axis."""
    c = t.C @ Tm[:3, :3].T + Tm[:3, 3]
    u = t.U @ Tm[:3, :3].T
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    d = t.G - c
    d -= u * np.einsum("ij,ij->i", d, u)[:, None]
    return u, d


def _axis_distances(t: _Targets, Tm: np.ndarray) -> np.ndarray:
    """Each survey point's distance [m] from its fitted axis moved by ``Tm``."""
    return np.linalg.norm(_axis_offsets(t, Tm)[1], axis=1)


def _refinement_report(t: _Targets, model: _CorrectionModel, x: np.ndarray, w: np.ndarray, T: np.ndarray,
                       ids: list[str], failures: dict, cfg: "ReconstructConfig") -> dict:
    """The correction's size (at the logs' centre), the residuals before and after (RMS over the
    precise points: the float ones are metres of noise in comparison), the weights and outliers."""
    before, after = _axis_distances(t, np.eye(4)), _axis_distances(t, T)
    norm_after = np.linalg.norm(model.residuals(x, t), axis=1)
    good = np.array([e.sigma_h_m * math.sqrt(2) <= cfg.registration_max_sigma_m for _, _, e in t.keys])
    if not good.any():
        good[:] = True
    scale = float(np.cbrt(abs(np.linalg.det(T[:3, :3]))))
    R = T[:3, :3] / scale
    angle = math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    shift = float(np.linalg.norm(T[:3, 3] + T[:3, :3] @ model.pivot - model.pivot))  # at the logs' centre
    outliers = [{"log_id": k, "end": end, "fix": e.fix, "residual_m": float(after[i]),
                 "residual_sigma": float(norm_after[i])}
                for i, (k, end, e) in enumerate(t.keys) if norm_after[i] > cfg.registration_outlier_sigma]
    return {
        "mode": model.mode, "with_scale": model.with_scale, "scale": scale,
        "correction_m": shift, "correction_deg": angle,
        "residual_rms_before_m": float(np.sqrt(np.mean(before[good] ** 2))),
        "residual_rms_after_m": float(np.sqrt(np.mean(after[good] ** 2))),
        "residual_max_after_m": float(after[good].max()),
        "logs_used": ids, "logs_not_fitted": failures, "end_points_used": int(len(t.keys)),
        "end_points_precise": int(good.sum()), "end_points_seen": int(t.seen.sum()),
        "weights": {f"{k}.{end}": float(wi) for (k, end, _), wi in zip(t.keys, w)},
        "outliers": outliers, "T_correction": T.tolist(),
    }


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
    from reconstruct.errors import CoarseRegistrationError

    cfg = cfg or CoarseConfig()
    ground = _ground_plane(points, camera_positions, cfg)
    search = _YawSearch(ground, ends_site, cfg)
    yaws = np.radians(np.arange(-180.0, 180.0, cfg.yaw_step_deg))
    sc = np.array([search.score(float(y))[0] for y in yaws])
    i_best = int(np.argmax(sc))
    sep = np.radians(cfg.peak_separation_deg)
    dist = np.abs((yaws - yaws[i_best] + np.pi) % (2 * np.pi) - np.pi)
    peak = (sc >= np.roll(sc, 1)) & (sc >= np.roll(sc, -1))  # local maxima (circular)
    other = peak & (dist > sep)
    second = float(sc[other].max()) if other.any() else 0.0
    y_second = float(yaws[other][int(np.argmax(sc[other]))]) if other.any() else math.nan
    best_yaw, best, u = search.refine_yaw(float(yaws[i_best]))
    report = {
        "ground_plane_scan": [float(v) for v in (*ground.normal, ground.offset)], "ground_fraction": ground.fraction,
        "raised_points": int(len(ground.raised)), "axis_samples": int(len(search.samples)),
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
        best_yaw, best, u = search.resolve_by_heights(cand_yaws, report, (best_yaw, best), (y_second, second))
    T_site_level = search.site_from_level(best_yaw, u, report)
    return T_site_level @ ground.T_level_scan, report


@dataclass(frozen=True)
class _Ground:
    """The scan's ground plane (``normal`` . p + ``offset`` = 0 in the scan frame, the cameras on
    its positive side, holding ``fraction`` of the thinned points), ``T_level_scan`` (level frame:
    z = height above that plane) and the points raised above it, in the level frame."""

    normal: np.ndarray
    offset: float
    fraction: float
    T_level_scan: np.ndarray
    raised: np.ndarray


def ransac_plane(points: np.ndarray, distance_m: float, iterations: int,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The plane (n, d: n . p + d = 0, |n| = 1) holding the most ``points`` within ``distance_m``:
    RANSAC over ``iterations`` three-point samples drawn from ``rng``, refitted to its inliers by
    least squares; returns it and its inliers' indices.

    Deterministic for a seeded ``rng`` (open3d's ``segment_plane`` is not, whatever its seed: on one
    unposed twin scan it gave 14,075 / 14,108 / 14,152 inliers in repeated calls, and the coarse yaw
    and every fitted log with it changed from run to run)."""
    P = np.asarray(points, dtype=np.float64)
    best_count, best = -1, (np.array([0.0, 0.0, 1.0]), 0.0)
    for start in range(0, iterations, RANSAC_BATCH):
        idx = rng.integers(0, len(P), size=(min(RANSAC_BATCH, iterations - start), 3))
        a = P[idx[:, 0]]
        n = np.cross(P[idx[:, 1]] - a, P[idx[:, 2]] - a)
        norm = np.linalg.norm(n, axis=1)
        ok = norm > 1e-12  # three distinct, non-collinear points
        n = n / np.where(ok, norm, 1.0)[:, None]
        d = -np.einsum("ij,ij->i", n, a)
        counts = np.where(ok, (np.abs(P @ n.T + d) < distance_m).sum(axis=0), -1)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best_count, best = int(counts[j]), (n[j], float(d[j]))
    inl = np.flatnonzero(np.abs(P @ best[0] + best[1]) < distance_m)
    if len(inl) >= 3:  # least squares on the inliers, then the inliers of that plane
        c = P[inl].mean(axis=0)
        n = np.linalg.svd(P[inl] - c, full_matrices=False)[2][-1]
        best = (n, float(-n @ c))
        inl = np.flatnonzero(np.abs(P @ best[0] + best[1]) < distance_m)
    return np.r_[best[0], best[1]], inl


def _ground_plane(points: np.ndarray, camera_positions: np.ndarray, cfg: CoarseConfig) -> _Ground:
    import open3d as o3d

    from reconstruct.errors import CoarseRegistrationError

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    P = np.asarray(pc.voxel_down_sample(cfg.voxel_m).points)
    if len(P) < 100:
        raise CoarseRegistrationError(f"only {len(P)} scan points: too few to find the ground")
    plane, inl = ransac_plane(P, cfg.ground_distance_m, cfg.ground_iterations, np.random.default_rng(cfg.seed))
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
    return _Ground(n, d, float(frac), T_level_scan, raised)


class _YawSearch:
    """The surveyed axes slid over the raster of raised scan points (level frame), by yaw."""

    def __init__(self, ground: _Ground, ends_site: dict, cfg: CoarseConfig) -> None:
        import cv2
        from scipy.spatial import cKDTree

        self.cfg, self.raised = cfg, ground.raised
        # raster of raised points (level frame), dilated by the band
        self.lo = self.raised[:, :2].min(0) - 0.5
        hi = self.raised[:, :2].max(0) + 0.5
        shape = tuple(int(v) for v in np.ceil((hi - self.lo) / cfg.cell_m)[::-1] + 1)  # rows (y), cols (x)
        occ = np.zeros(shape, np.uint8)
        ij = np.floor((self.raised[:, :2] - self.lo) / cfg.cell_m).astype(np.int64)
        occ[ij[:, 1], ij[:, 0]] = 1
        occ = cv2.morphologyEx(occ, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        # how deep inside the raised region a cell lies: largest on a log's centre line (its axis seen from
        # above), so a surveyed axis scores most when it runs along the middle of a log, not just across one
        inside = cv2.distanceTransform(occ, cv2.DIST_L2, 5) * cfg.cell_m
        self.occ = (np.clip(inside, 0.0, cfg.band_m) / cfg.band_m).astype(np.float32)
        self.samples, self.owner = _axis_samples(ends_site, cfg.cell_m, cfg.end_trim_m)
        self.centre = self.samples[:, :2].mean(0)
        self.rel = self.samples[:, :2] - self.centre
        self.tree = cKDTree(self.raised[:, :2])

    def score(self, yaw: float) -> tuple[float, np.ndarray]:
        """The axis samples' mean support at ``yaw`` and the best shift (level position of their centre)."""
        import cv2

        cell = self.cfg.cell_m
        a = self.rel @ _rot_z(-yaw).T  # axis samples in the level frame, up to a shift
        amin = a.min(0)
        idx = np.floor((a - amin) / cell).astype(np.int64)
        th, tw = int(idx[:, 1].max()) + 1, int(idx[:, 0].max()) + 1
        if th >= self.occ.shape[0] or tw >= self.occ.shape[1]:
            return 0.0, np.zeros(2)
        tmpl = np.zeros((th, tw), np.float32)
        np.add.at(tmpl, (idx[:, 1], idx[:, 0]), 1.0)
        res = cv2.matchTemplate(self.occ, tmpl, cv2.TM_CCORR)
        _, best, _, loc = cv2.minMaxLoc(res)
        # level position of the samples' centre: template origin + (centre - amin)
        u = self.lo + np.array(loc, dtype=np.float64) * cell - amin
        return float(best) / len(a), u

    def refine_yaw(self, y0: float) -> tuple[float, float, np.ndarray]:
        """The best yaw on the fine grid around ``y0``, its support and shift."""
        cfg = self.cfg
        fine = np.radians(np.arange(-cfg.yaw_step_deg, cfg.yaw_step_deg + 1e-9, cfg.fine_step_deg)) + y0
        y, (b, u) = max(((float(y), self.score(float(y))) for y in fine), key=lambda t: t[1][0])
        return y, b, u

    def _level(self, yaw: float, u: np.ndarray) -> np.ndarray:
        R2 = _rot_z(yaw)
        return (self.samples[:, :2] - (self.centre - R2 @ u)) @ R2  # = R2.T @ (site - t)

    def height_spread(self, yaw: float, u: np.ndarray) -> float:
        """Median absolute deviation [m] of (surveyed axis height - scan top height under it) over
        the axis samples: nearly constant (a radius and the ground offset) at the right yaw; at a
        wrong one the survey's high logs land on low scan points and the other way round."""
        nb = self.tree.query_ball_point(self._level(yaw, u), 0.03)
        d = np.array([self.samples[k, 2] - float(np.max(self.raised[j, 2])) for k, j in enumerate(nb) if len(j)])
        if len(d) < 0.3 * len(self.samples):
            return math.inf
        return float(np.median(np.abs(d - np.median(d))))

    def resolve_by_heights(self, cand_yaws: list[float], report: dict, best: tuple[float, float],
                           second: tuple[float, float]) -> tuple[float, float, np.ndarray]:
        """Of yaws the top view cannot tell apart, the one whose heights agree clearly best with the
        survey's (``height_ambiguity_ratio``); else :class:`CoarseRegistrationError`."""
        from reconstruct.errors import CoarseRegistrationError

        cands = []
        for y0 in cand_yaws:
            y, b, uu = self.refine_yaw(y0)
            cands.append((self.height_spread(y, uu), y, b, uu))
        cands.sort(key=lambda c: c[0])
        report["height_spread_m"] = {f"{math.degrees(c[1]):.1f}": c[0] for c in cands}
        (h1, y1, b1, u1), (h2, y2, b2, _) = cands[0], cands[1]
        if not (math.isfinite(h1) and h1 * self.cfg.height_ambiguity_ratio <= h2):
            raise CoarseRegistrationError(
                f"the scan fits the surveyed logs almost equally well at yaw {math.degrees(best[0]):.0f} deg "
                f"({best[1] * 100:.0f} % support) and {math.degrees(second[0]):.0f} deg ({second[1] * 100:.0f} %), and "
                f"the heights do not tell them apart either ({h1 * 100:.1f} vs {h2 * 100:.1f} cm spread): the "
                "pile looks (nearly) symmetric. Survey a log that breaks the symmetry, or give a scan pose "
                "(scan_pose.json)")
        report.update(yaw_deg=math.degrees(y1), support=b1, resolved_by="heights")
        return y1, b1, u1

    def site_from_level(self, yaw: float, u: np.ndarray, report: dict) -> np.ndarray:
        """``T_site_level`` at ``yaw`` and shift ``u``, its height from the ground under the logs: a
        log's axis lies half its seen top height above the ground under it, if it lies on the
        ground; logs on other logs give higher grounds, so the lowest log sets the height."""
        from reconstruct.errors import CoarseRegistrationError

        R2 = _rot_z(yaw)
        t_xy = self.centre - R2 @ u  # site_xy = R2 @ level_xy + t_xy
        lvl = (self.samples[:, :2] - t_xy) @ R2  # = R2.T @ (site - t)
        grounds = []
        for k in np.unique(self.owner):
            sel = self.owner == k
            nb = self.tree.query_ball_point(lvl[sel], 0.03)
            tops = [float(np.max(self.raised[j, 2])) for j in nb if len(j)]
            if len(tops) >= 5:
                h_top = float(np.median(tops))
                grounds.append(float(np.median(self.samples[sel, 2])) - h_top / 2)
        if not grounds:
            raise CoarseRegistrationError("no surveyed log has raised scan points along its axis")
        dz = float(min(grounds))
        T_site_level = np.eye(4)
        T_site_level[:2, :2] = R2
        T_site_level[:3, 3] = (t_xy[0], t_xy[1], dz)
        report["ground_height_site_m"] = dz
        return T_site_level
