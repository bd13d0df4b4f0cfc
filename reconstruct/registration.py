"""Georegistration: where the scan lies in the site frame.

* The scan pose sidecar (``scan_pose.json``, :class:`ScanPose`): the crane's own RTK/IMU pose of the
  camera, or a survey of the rig.
* **Coarse** (:func:`reconstruct.scan.coarse_pose.coarse_scan_pose`): for a scan with no pose, from
  the GNSS end points alone: the ground plane gives the vertical, a yaw/shift search puts the
  surveyed axes on the scan's raised points, the lowest log sets the height.
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
from reconstruct.fitting.ends import MIN_LOG_LENGTH_M
from reconstruct.fitting.fit import CylinderFit, fit_log, log_spec_from_fit, natural_key, points_on_no_other_log
from reconstruct.fitting.fuse import scan_end_interval, seen_end
from synth.common.formats import VersionedJson
from synth.geometry.frames import apply_T
from synth.scene.pile import Georeference

if TYPE_CHECKING:
    from reconstruct.config import ReconstructConfig

SCAN_POSE_FORMAT = "loggrasp.scan-pose"
SCAN_POSE_VERSION = "1.0"
SCAN_POSE = VersionedJson(SCAN_POSE_FORMAT, SCAN_POSE_VERSION, "scan pose", RegistrationError,
                          unreadable_fix="give the scan's scan_pose.json, or --georegister gnss",
                          filename="scan_pose.json")


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
            f = fit_log(points, a, b, cfg.fit, log_id=log_id, rng=rng,
                        sigma_a_m=cfg.registration_prior_sigma_m, sigma_b_m=cfg.registration_prior_sigma_m)
        except ReconstructError as exc:
            failures[log_id] = str(exc)
            continue
        seen_m = float(np.linalg.norm(f.ends[1] - f.ends[0]))
        if seen_m < MIN_LOG_LENGTH_M:  # a piece shorter than any log: no axis to register to, nor a log spec
            failures[log_id] = (f"the scan shows {seen_m:.2f} m of it, less than the shortest log "
                                f"({MIN_LOG_LENGTH_M} m)")
        else:
            fits[log_id] = f
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
