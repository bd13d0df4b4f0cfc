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
   or from ``scan_pose.json`` in the scan folder (:func:`reconstruct.registration.write_scan_pose` /
   :func:`~reconstruct.registration.read_scan_pose`; e.g. the crane's own RTK/IMU pose of the camera, or a survey of the
   rig), or — for an unposed scan, or ``georegister="gnss"`` — from the GNSS end points alone
   (:func:`reconstruct.scan.coarse_pose.coarse_scan_pose`: ground plane, yaw and shift search; the site origin is then the
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
5. **Registration refinement** (:func:`reconstruct.registration.refine_registration`): each matched log is fitted around
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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from reconstruct.config import ReconstructConfig, logs_direction, patch_extent
from reconstruct.errors import FitError, ReconstructError, RegistrationError, ScanError
from reconstruct.fitting.coverage import check_coverage
from reconstruct.fitting.ends import axis_sigma_m
from reconstruct.fitting.fit import PileFit, fit_log, fit_pile, log_spec_from_fit
from reconstruct.fitting.joint_config import JOINT_REVISION
from reconstruct.fitting.joint_ends import JointEndPlacer, dropped_point_lines, joint_after_check
from reconstruct.fitting.joint_view import scan_views
from reconstruct.fitting.joint_match import joint_match
from reconstruct.fitting.joint_ridge import ridge_evidence
from reconstruct.fitting.joint_settle import JointSettler
from reconstruct.fitting.fuse import (
    FuseConfig, SurveyEnd, a_piece_of_a_surveyed_log, absorb_pieces, after_pile_check, find_scan_logs, match_survey,
    place_log_ends, point_accuracy, prior_axis,
)
from reconstruct.registration import ScanPose, read_scan_pose, refine_registration
from reconstruct.scan.coarse_pose import coarse_scan_pose
from reconstruct.report import REPORT_FORMAT, REPORT_VERSION, contradicted_points, json_default, weak_ends
from reconstruct.scan.pictures import comparison_image
from reconstruct.scan.stereo import ScanCloud, scan_cloud
from synth.geometry.frames import apply_T, invert_T, make_T, rot_z
from synth.common.files import atomic_write_bytes
from synth.scene.pile import Georeference, PileSpec, write_pile

if TYPE_CHECKING:
    from synth.render.ortho import OrthoObservation



# -- the result ------------------------------------------------------------------
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
            "the site frame. Write one with reconstruct.registration.write_scan_pose (site origin + "
            "T_site_scan of the scan frame), pass ReconstructConfig(scan_pose=...), or place it from the "
            "GNSS end points (ReconstructConfig(georegister='gnss'), loggrasp reconstruct --georegister gnss)"
        )
    return read_scan_pose(path), str(path)


def _scan(scan_dir: Path, cfg: ReconstructConfig, say: Callable[[str], None]) -> tuple[ScanCloud, str, dict | None]:
    """The fused cloud (scan frame), where the pair poses came from ("calibration", "sfm",
    "single pair") and the SfM report (None without SfM)."""
    from reconstruct.scan.calibration import pair_pose_present
    from reconstruct.scan.sfm import estimate_pair_poses
    from reconstruct.scan.stereo import camera_clouds, fuse_pairs
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
    ``gnss_path``: a survey CSV, or raw logs and their windows (a :class:`reconstruct.survey.windows.RawGnss`; :func:`reconstruct.survey.gnss.read_gnss`). ``out_dir``: created; gets
    ``pile.json``, ``ortho.npz``, ``preview.png``, ``compare.png``, ``report.json``.
    ``progress``: called with a short line per stage. ``cloud``: this scan's fused cloud from an
    earlier run (``ReconstructionResult.cloud``), to reconstruct it again with another survey or
    config without matching the stereo pairs again (its pair poses are reported as "given").

    Raises a :class:`~reconstruct.errors.ReconstructError` subclass (``ScanError``,
    ``GnssError``, ``RegistrationError``, ``FitError``) naming the file, log or point at fault.
    """
    # Over 80 lines on purpose: the stages in order, each a call to a named step, and the report
    # that records them; splitting it would only hand the same dozen intermediate frames around.
    cfg = config or ReconstructConfig()
    say = progress or (lambda s: None)
    scan_dir, out_dir = Path(scan_dir), Path(out_dir)
    clock = _Clock()
    survey, pose, pose_source, origin, survey_site = _read_survey(scan_dir, gnss_path, cfg, say)
    clock.lap("survey_s")
    if cloud is None:
        say(f"matching stereo pairs in {scan_dir}")
        cloud, pair_pose_source, sfm_report = _scan(scan_dir, cfg, say)
    else:
        pair_pose_source, sfm_report = "given", None
    clock.lap("stereo_s")
    if sfm_report is not None:
        clock.timings["sfm_s"] = float(sfm_report["timings_s"].get("total_s", math.nan))
    placed = _Placed(pose, None, cfg, cfg.fuse)
    if pose is None:
        placed = _place_from_gnss(cloud, survey_site, origin, cfg, say)
        clock.lap("georegistration_s")
    T_site_scan = placed.pose.matrix()
    pts_site = apply_T(T_site_scan, cloud.points)
    coverage = check_coverage(pts_site[:, :2], survey_site, cfg.max_endpoint_distance_m, cfg.coverage)
    clock.reset()
    say("finding the logs in the scan and matching them to the survey")
    matching = _match_logs(pts_site, survey_site, placed.fuse_cfg, cfg)
    matching.over_scan_share.update(coverage.over_scan_share)
    clock.lap("matching_s")
    frame = _pile_frame(pts_site, matching.priors(survey_site, matching.scan_logs, placed.fuse_cfg), cfg)
    pts = apply_T(frame.T_pile_site, pts_site)
    survey_ends = {k: tuple(None if e is None else e.moved(frame.T_pile_site) for e in v) for k, v in survey_site.items()}
    logs_pile = [s.moved(frame.T_pile_site) for s in matching.scan_logs]
    clock.reset()
    T_corr, reg_report, first_pass = _refine(pts[frame.near], matching, survey_ends, logs_pile, placed, cfg, say)
    if reg_report["mode"] != "none":
        pts = apply_T(T_corr, pts)
    clock.lap("registration_s")
    T_site_scan_refined = frame.T_site_pile @ T_corr @ frame.T_pile_site @ T_site_scan  # site <- pile <- scan
    logs_pile = [s.moved(T_corr) for s in logs_pile]
    in_patch = np.all(np.abs(pts[:, :2]) < frame.extent / 2, axis=1)
    views = (scan_views(scan_dir, T_corr @ frame.T_pile_site @ T_site_scan)  # the pairs' cameras, as pts
             if cfg.estimator == "joint" and cfg.joint.view_test and pair_pose_source in ("given", "calibration")
             else None)
    fit, fusion = _fit(pts[in_patch], matching, survey_ends, logs_pile, first_pass, frame, placed, cfg, say,
                       notes=f"reconstructed from {scan_dir} and {gnss_path}", georef=frame.georef(placed.pose),
                       views=views)
    clock.lap("fit_s")
    say(f"writing {out_dir}")
    obs, files = _write_outputs(fit, frame.render_px, cfg, out_dir, pts[in_patch], cloud.colours[in_patch])
    clock.lap("outputs_s")
    timings = _timings(clock, None if pair_pose_source == "given" else cloud, fit)
    report = {
        "format": REPORT_FORMAT, "format_version": REPORT_VERSION,
        "scan_dir": str(scan_dir), "gnss": str(gnss_path), "pairs": cloud.pairs,
        "n_points": int(len(cloud.points)), "matched_fraction": cloud.valid_fractions,
        "scan_pose_source": pose_source, "site_origin": list(placed.pose.origin),
        "pair_poses_source": pair_pose_source, "sfm": sfm_report, "coarse_registration": placed.coarse_report,
        "T_site_scan_given": T_site_scan.tolist(), "T_site_scan_refined": T_site_scan_refined.tolist(),
        "T_site_pile": frame.T_site_pile.tolist(), "extent_m": frame.extent,
        "registration": reg_report, "endpoint_scan_distance_m": coverage.distances_m,
        "ends_outside_scan": [o.to_dict() for o in coverage.outside],
        "survey_warnings": list(survey.warnings) + [o.line() for o in coverage.outside],
        "logs": [lf.to_dict() for lf in fit.logs],
        "fusion": fusion, "weak_ends": weak_ends(fit.logs, placed.fuse_cfg),
        "contradicted_points": contradicted_points(fit.logs) + dropped_point_lines(matching.dropped, survey_site),
        "terrain_coverage": fit.terrain_coverage, "obstacles": fit.obstacles, "moves": fit.moves, "end_moves": fit.end_moves,
        "timings_s": timings,
    }
    if cfg.estimator != "rules22":  # revision 22's reports stay as they were
        report.update(estimator=cfg.estimator, estimator_revision=JOINT_REVISION, survey_logs_dropped=matching.dropped)
        report["survey_warnings"] += matching.ambiguous
    files["report"] = out_dir / "report.json"
    atomic_write_bytes(files["report"], json.dumps(report, indent=1, default=json_default).encode())
    say(f"done in {timings['total_s']:.1f} s")
    return ReconstructionResult(pile=fit.pile, fit=fit, report=report, out_dir=out_dir, files=files, cloud=cloud,
                                observation=obs)


def _timings(clock: "_Clock", cloud: ScanCloud | None, fit: PileFit) -> dict[str, float]:
    """The stages' wall times [s], with the stereo matching's (``cloud``: matched in this run) and the fit's."""
    timings = clock.total()
    if cloud is not None:
        timings.update({f"stereo_{k}": v for k, v in cloud.timings_s.items()})
    timings.update({f"fit_{k}": v for k, v in fit.timings_s.items()})
    return timings


class _Clock:
    """The stage timings of one reconstruction [s]: ``lap(name)`` records the time since the last
    lap (or ``reset``); ``total()`` adds ``total_s`` since the start."""

    def __init__(self) -> None:
        self.start = self.t = time.perf_counter()
        self.timings: dict[str, float] = {}

    def reset(self) -> None:
        self.t = time.perf_counter()

    def lap(self, name: str) -> None:
        self.timings[name] = time.perf_counter() - self.t
        self.t = time.perf_counter()

    def total(self) -> dict[str, float]:
        self.timings["total_s"] = time.perf_counter() - self.start
        return self.timings


def _read_survey(scan_dir: Path, gnss_path: str | Path, cfg: ReconstructConfig, say: Callable[[str], None]):
    """The survey, the given scan pose (None: to be found from the survey) and its source, the site
    origin, and every surveyed log's ends in the site frame with their accuracies."""
    from reconstruct.scan.calibration import pair_pose_present
    from reconstruct.scan.stereo import find_pairs
    from reconstruct.survey.gnss import read_gnss

    say(f"reading survey {gnss_path}")
    unposed = not any(pair_pose_present(f) for f in find_pairs(scan_dir))
    pose, pose_source = _pose(scan_dir, cfg, unposed=unposed)
    survey = read_gnss(gnss_path, allow_float=cfg.allow_float, area=None if pose is None else pose.origin,
                       require_both_ends=False)
    origin = survey.default_origin() if pose is None else pose.origin
    return survey, pose, pose_source, origin, _survey_ends(survey, origin)


@dataclass(frozen=True)
class _Placed:
    """The scan's pose in the site frame, the coarse placement's report (None: the pose was given)
    and the refinement and fusion settings that go with how sure that pose is."""

    pose: ScanPose
    coarse_report: dict | None
    reg_cfg: ReconstructConfig
    fuse_cfg: FuseConfig


def _place_from_gnss(cloud: ScanCloud, survey_site: dict, origin, cfg: ReconstructConfig,
                     say: Callable[[str], None]) -> _Placed:
    """The scan placed from the GNSS end points alone (:func:`coarse_scan_pose`); the refinement then
    runs with the coarse pose's looser prior and limits."""
    say("placing the scan from the GNSS end points (ground plane, yaw search)")
    ends_site = {k: (e[0].position_m, e[1].position_m) for k, e in survey_site.items() if None not in e}
    if not ends_site:
        raise RegistrationError("no log has both ends surveyed: the scan cannot be placed from the survey alone; "
                                "give a scan pose (scan_pose.json)")
    T_coarse, coarse_report = coarse_scan_pose(cloud.points, cloud.camera_positions, ends_site, cfg.coarse)
    pose = ScanPose(*origin, T_site_scan=tuple(tuple(float(v) for v in r) for r in T_coarse))
    reg_cfg = replace(cfg, refine_dof=cfg.coarse.refine_dof, max_correction_m=cfg.coarse.max_correction_m,
                      max_correction_deg=cfg.coarse.max_correction_deg, scan_pose_sigma_m=cfg.coarse.pose_sigma_m,
                      scan_pose_sigma_deg=cfg.coarse.pose_sigma_deg)
    fuse_cfg = replace(cfg.fuse, pose_sigma_m=max(cfg.fuse.pose_sigma_m, cfg.coarse.pose_sigma_m / 2))
    return _Placed(pose, coarse_report, reg_cfg, fuse_cfg)


@dataclass
class _Matching:
    """The logs the scan shows, each surveyed log's match among them, the scan logs left unmatched
    and the ids of those kept as logs the survey missed (``{log_id: scan index}``; fitting may drop
    some)."""

    scan_logs: list
    matches: dict
    unmatched: list
    new_ids: dict[str, int]
    dropped: dict[str, str] = field(default_factory=dict)  # surveyed logs left out (joint estimator): why
    outliers: dict[str, set[int]] = field(default_factory=dict)  # points (0: a, 1: b) that set no prior axis
    ambiguous: list[str] = field(default_factory=list)  # logs another pile explains as well (joint estimator)
    over_scan_share: dict[str, float] = field(default_factory=dict)  # each log's survey axis over the scan [-]

    def priors(self, survey_ends: dict, logs_found: list, fuse_cfg: FuseConfig) -> dict:
        """Each log's prior axis ``(a, b, lateral sigma)``: from its match in ``logs_found`` and its
        survey points, or for a new log from the scan alone."""
        out = {}
        for k, m in self.matches.items():
            found = None if m.scan_index is None else logs_found[m.scan_index]
            ends = survey_ends[k]
            share = self.over_scan_share.get(k, 1.0)
            if found is None or not a_piece_of_a_surveyed_log(ends, found, fuse_cfg, share):
                # a point the matching did not believe sets no prior axis; but not when the scan log is a piece
                # of the log by both its points: the log is then seen in part on them (``in_part``), and an axis
                # without one of them runs along the piece, not the log (docs/reconstruction.md, joint revision 11)
                ends = tuple(None if n in self.outliers.get(k, ()) else e for n, e in enumerate(ends))
            out[k] = prior_axis(ends, found, m.reversed, fuse_cfg, share)
        for k, j in self.new_ids.items():
            out[k] = (logs_found[j].start_m.copy(), logs_found[j].end_m.copy(), fuse_cfg.axis_sigma_m)
        return out


def _match_logs(pts_site: np.ndarray, survey_site: dict, fuse_cfg: FuseConfig, cfg: ReconstructConfig) -> _Matching:
    scan_logs = find_scan_logs(pts_site, fuse_cfg)
    dropped, outliers, ambiguous = {}, {}, []
    if cfg.estimator == "joint":
        evidence = ridge_evidence(pts_site, scan_logs, cfg.joint, fuse_cfg)
        jm = joint_match(survey_site, scan_logs, cfg.joint, fuse_cfg, evidence)
        matches, unmatched, dropped, outliers, ambiguous = jm.matches, jm.unmatched, jm.dropped, jm.outliers, jm.ambiguous
    else:
        matches, unmatched = match_survey(survey_site, scan_logs, fuse_cfg)
    unmatched = absorb_pieces(matches, unmatched, scan_logs)
    for k, m in matches.items():
        if m.scan_index is None and None in survey_site[k]:
            end = "ab"[survey_site[k].index(None)]
            raise FitError(f"log {k!r} has no end {end!r} in the survey and the scan shows no log near its other end: "
                           f"measure both ends of log {k!r}, or remove it from the survey")
    new_ids = _new_log_ids([j for j in unmatched if scan_logs[j].seen_m >= fuse_cfg.min_new_log_m], survey_site)
    return _Matching(scan_logs, matches, unmatched, new_ids, dropped, outliers, ambiguous)


@dataclass(frozen=True)
class _PileFrame:
    """The pile frame (``T_site_pile``: the site frame turned so the logs lie at ``log_direction_deg``,
    shifted to their centre at ground level), the square patch's side [m] and re-render size [px],
    and which scan points lie on the patch (``near``)."""

    T_site_pile: np.ndarray
    T_pile_site: np.ndarray
    extent: float
    render_px: int
    near: np.ndarray

    def georef(self, pose: ScanPose) -> Georeference:
        return Georeference(origin_lat_deg=pose.origin_lat_deg, origin_lon_deg=pose.origin_lon_deg,
                            origin_h_m=pose.origin_h_m,
                            T_site_pile=tuple(tuple(float(v) for v in row) for row in self.T_site_pile))


def _pile_frame(pts_site: np.ndarray, priors_site: dict, cfg: ReconstructConfig) -> _PileFrame:
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
    return _PileFrame(T_site_pile, invert_T(T_site_pile), extent, render_px, near)


def _refine(pts_near: np.ndarray, matching: _Matching, survey_ends: dict, logs_pile: list, placed: _Placed,
            cfg: ReconstructConfig, say: Callable[[str], None]) -> tuple[np.ndarray, dict, dict]:
    """The registration correction (pile frame), its report and the first-pass fits of the logs
    the scan and the survey both show, fitted around their scan axes (identity and no fits with
    ``refine`` off or no such log). The fits start from the scan's own log axes, which move with
    the scan: one round (fit, then the correction) is all; a second would fit the same points the
    same way."""
    matched = {k: m for k, m in matching.matches.items() if m.scan_index is not None and any(survey_ends[k])}
    if not (cfg.refine and matched):
        return np.eye(4), {"mode": "none"}, {}
    say("refining the scan pose against the GNSS end points")
    pri = {key: prior_axis(survey_ends[key], logs_pile[m.scan_index], m.reversed, placed.fuse_cfg)[:2]
           for key, m in matched.items()}
    T_corr, reg_report, first_pass = refine_registration(pts_near, {}, placed.reg_cfg, priors=pri,
                                                         survey={key: survey_ends[key] for key in matched})
    reg_report.update({"total_correction_m": reg_report["correction_m"],
                       "total_correction_deg": reg_report["correction_deg"]})
    return T_corr, reg_report, first_pass


def _fit(pts: np.ndarray, matching: _Matching, survey_ends: dict, logs_pile: list, first_pass: dict,
         frame: _PileFrame, placed: _Placed, cfg: ReconstructConfig, say: Callable[[str], None], notes: str,
         georef: Georeference, views: list | None = None) -> tuple[PileFit, dict]:
    """The pile fitted on the patch's points (pile frame): new logs kept where the scan shows one,
    every log's ends placed (:class:`_EndPlacer`), terrain and obstacles; and the fusion report
    (``views``: the scan's pairs in the pile frame, for the joint end model, :mod:`joint_view`)."""
    priors = matching.priors(survey_ends, logs_pile, placed.fuse_cfg)
    new_ids = dict(matching.new_ids)
    dropped_new = _fit_new_logs(pts, new_ids, priors, first_pass, cfg, placed.fuse_cfg)
    lateral = {k: s for k, (_, _, s) in priors.items()}
    joint = cfg.estimator == "joint"
    placer = (JointEndPlacer(survey_ends, lateral, cfg.joint, placed.fuse_cfg, views=views) if joint
              else _EndPlacer(survey_ends, lateral, placed.fuse_cfg))
    fit = fit_pile(pts, {k: (a, b) for k, (a, b, _) in priors.items()}, frame.extent, cfg.fit, progress=say,
                   georef=georef, notes=notes, first_pass=first_pass,
                   sigmas={k: (s, s) for k, s in lateral.items()},
                   place_ends=placer, optional=set(new_ids),
                   settle=(JointSettler(survey_ends, lateral, cfg.joint, cfg.fit.penetration_tolerance_m,
                                        cfg.fit.roll_steps, points=pts, band_m=cfg.fit.inlier_band_m)
                           if joint else None),
                   in_part={k for k, m in matching.matches.items() if m.scan_index is not None
                            and a_piece_of_a_surveyed_log(survey_ends[k], logs_pile[m.scan_index], placed.fuse_cfg,
                                                          matching.over_scan_share.get(k, 1.0))})
    for lf in fit.logs:  # ends where the pile check left their log, tested against the survey again
        if lf.ends:
            check_args = (lf.ends, (np.asarray(lf.butt_m), np.asarray(lf.top_m)), survey_ends.get(lf.log_id, (None, None)))
            lf.ends = (joint_after_check(*check_args, cfg.joint) if joint
                       else after_pile_check(*check_args, placed.fuse_cfg))
            lf.gnss_residual_a_m, lf.gnss_residual_b_m = (
                math.nan if e.get("gnss_axis_distance_m") is None else float(e["gnss_axis_distance_m"]) for e in lf.ends)
    for k, why in fit.dropped.items():  # a log the survey missed whose points the other logs took: not a log
        dropped_new[k] = why
        del new_ids[k]
    fusion = {
        "scan_logs": [s.to_dict() for s in logs_pile],
        "matches": {k: m.to_dict() for k, m in matching.matches.items()},
        "new_logs": {k: new_j for k, new_j in new_ids.items()},
        "new_logs_dropped": dropped_new,
        "unmatched_scan_logs": [j for j in matching.unmatched if j not in new_ids.values()],
    }
    return fit, fusion


def _fit_new_logs(pts: np.ndarray, new_ids: dict, priors: dict, first_pass: dict, cfg: ReconstructConfig,
                  fuse_cfg: FuseConfig) -> dict[str, str]:
    """Logs the survey missed: kept (a first-pass fit) when the scan shows a log there, fitted over
    most of what it saw; the others leave ``new_ids`` and ``priors``. Returns why each was dropped."""
    dropped = {}
    for k in list(new_ids):
        a, b, s = priors[k]
        try:
            f = fit_log(pts, a, b, cfg.fit, log_id=k, sigma_a_m=s, sigma_b_m=s)
            ok = f.coverage >= fuse_cfg.min_new_log_coverage
            why = f"its fit covers {f.coverage * 100:.0f} % of it"
        except ReconstructError as exc:
            ok, why = False, str(exc)
        if ok:
            first_pass[k] = log_spec_from_fit(f, cfg.fit)[0]
        else:
            dropped[k] = why
            del new_ids[k], priors[k]
    return dropped


class _EndPlacer:
    """``fit_pile``'s ``place_ends``: a log's ends from the scan where it sees them, else from its
    survey points (:func:`place_log_ends`), its axis as sure as how it was fitted."""

    def __init__(self, survey_ends: dict, lateral: dict[str, float], fuse_cfg: FuseConfig) -> None:
        self.survey_ends, self.lateral, self.fuse_cfg = survey_ends, lateral, fuse_cfg

    def __call__(self, log_id: str, spec, how: str, points: np.ndarray, swapped: bool, on_mask: np.ndarray):
        ends_k = self.survey_ends.get(log_id, (None, None))
        sig = axis_sigma_m(how, self.lateral[log_id], ends_k)
        try:
            return place_log_ends(points, spec, how, ends_k, swapped, sig, self.fuse_cfg, on_mask=on_mask)
        except FitError as exc:
            raise FitError(f"log {log_id!r}: {exc}") from exc


def _write_outputs(fit: PileFit, render_px: int, cfg: ReconstructConfig, out_dir: Path, pts: np.ndarray,
                   colours: np.ndarray) -> tuple["OrthoObservation", dict[str, Path]]:
    """The re-render (nothing is written for a pile the twin cannot show), then pile.json,
    ortho.npz, preview.png and compare.png in ``out_dir``."""
    from synth.errors import SynthError
    from synth.physics.world import World
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.render.preview import preview_image, write_png

    try:
        with World(fit.pile) as world:
            obs = render_ortho(world, OrthoRenderConfig(size_px=render_px, n_renders=cfg.render_n), seed=cfg.seed)
    except SynthError as exc:
        raise FitError(f"the reconstructed pile cannot be re-rendered ({exc}); check the per-log fits "
                       "(a log seen only in part may have been fitted astray) and the GNSS end points") from exc
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {"pile": write_pile(fit.pile, out_dir / "pile.json")}
    obs.meta["source"] = "reconstructed"
    files["ortho"] = obs.save(out_dir / "ortho.npz")
    files["preview"] = write_png(out_dir / "preview.png", preview_image(obs))
    files["compare"] = write_png(out_dir / "compare.png", comparison_image(pts, colours, obs))
    return obs, files
