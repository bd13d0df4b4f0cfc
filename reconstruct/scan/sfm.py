"""Relative poses of stereo pairs from structure from motion (pycolmap), when the rig moved and
no pose was recorded.

A scan made with a handheld or boom-mounted stereo camera without a pose sensor has pairs whose
calibrations carry no ``T_pile_cam`` (:func:`pair_has_pose`). :func:`estimate_pair_poses`:

1. **SfM** (pycolmap, in a temporary folder removed afterwards): SIFT features of every left and
   right image with the calibrated intrinsics held fixed, exhaustive matching, incremental
   mapping. Left and right of a pair form one frame of a two-camera *rig* whose right camera is
   held at the calibration's ``R``, ``T`` (COLMAP's rig support), so the model is metric: the
   rig's known baseline fixes the scale. Every image must be placed, else
   :class:`~reconstruct.errors.SfmRegistrationError` names the pairs left out.
2. **Scale check**: per pair, the median ratio of its own stereo depth (SGBM, metric through
   the calibrated baseline) to SfM's depth of the SfM points its left image sees. The relative
   spread (max - min) / median over the pairs is reported; beyond ``max_scale_spread`` it is an
   :class:`~reconstruct.errors.SfmScaleError` (a distorted model or a wrong calibration).
3. **Stereo anchoring**: over a nearly flat scene seen from above, SfM confuses a small tilt of
   a pair with a sideways shift (measured: 10-20 cm and 2-4 deg between pairs 1-1.7 m apart,
   with a 0.2 px reprojection error). Each SfM point seen by two or more pairs' left images has
   a metric 3-D position in each of those pairs (its stereo depth at that pixel); the poses of
   all pairs but the first are solved (robust least squares) so that these positions agree.

The result is ``T_scan_cam`` of every pair's left camera in the *scan frame* = the first pair's
left camera frame (OpenCV axes: x right, y down, z forward). :func:`fuse_pairs` turns pairs and
poses into the fused :class:`~reconstruct.scan.stereo.ScanCloud` (as
:func:`reconstruct.scan.stereo.scan_cloud` does with the calibrations' own poses).

Errors are :class:`~reconstruct.errors.SfmError` subclasses that name the pair at fault and say
what to do.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from reconstruct.errors import SfmError, SfmRegistrationError, SfmScaleError
from reconstruct.scan.stereo import ScanPair, camera_clouds

POSE_KEY = "T_pile_cam"


@dataclass(frozen=True)
class SfmConfig:
    """pycolmap structure from motion for unposed scans (units in the names/comments)."""

    max_image_size_px: int = 1280  # SIFT runs on images scaled to this longest side [px]
    max_features: int = 4096  # SIFT features per image [-]
    init_min_tri_angle_deg: float = 8.0  # initial image pair's smallest triangulation angle [deg]
    min_matches: int = 15  # fewer verified matches: two images are not connected [-]
    max_scale_spread: float = 0.05  # (max - min) / median of the per-pair scales beyond this: error [-]
    depth_patch_px: int = 7  # stereo depth of a feature: median over this square [px], odd
    depth_step_m: float = 0.02  # ... unused when its 10-90 % depth range exceeds this (an edge) [m]
    min_correspondences: int = 30  # stereo points of shared SfM features a pair needs [-]
    min_link_tracks: int = 10  # shared depth-checked SfM points that tie two pairs together [-]
    anchor_max_evaluations: int = 300  # least-squares function evaluations per solve [-]
    anchor_min_threshold_m: float = 0.01  # outlier threshold: 3 robust sigmas, at least this [m]
    anchor_max_threshold_m: float = 0.10  # ... and at most this [m]
    max_anchor_rms_m: float = 0.03  # a pair's stereo points farther (RMS) from the tracks: error [m]
    num_threads: int = 1  # pycolmap threads [-]; 1 = deterministic (several threads gave a different
    #                       model from run to run under load, one leaving a pair 11 shared points
    #                       instead of ~340); -1 = all cores, ~30 % faster
    seed: int = 0  # pycolmap's RANSAC seed [-]
    rig: bool = True  # left + right as one rig frame with the calibrated R, T (metric, tied)
    keep_workdir: str | None = None  # copy the pycolmap database/model here (debugging) [path]

    def __post_init__(self) -> None:
        if not 64 <= self.max_image_size_px <= 8192:
            raise ValueError(f"max_image_size_px must be in [64, 8192], got {self.max_image_size_px}")
        if self.max_features < 100:
            raise ValueError(f"max_features must be >= 100, got {self.max_features}")
        if not 0.5 <= self.init_min_tri_angle_deg <= 60:
            raise ValueError("init_min_tri_angle_deg must be in [0.5, 60] deg")
        if self.min_matches < 5:
            raise ValueError("min_matches must be >= 5")
        if not 0 < self.max_scale_spread < 1:
            raise ValueError("max_scale_spread must be in (0, 1)")
        if self.depth_patch_px < 1 or self.depth_patch_px % 2 == 0:
            raise ValueError(f"depth_patch_px must be odd and >= 1, got {self.depth_patch_px}")
        for name in ("anchor_min_threshold_m", "anchor_max_threshold_m", "max_anchor_rms_m", "depth_step_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.min_correspondences < 3 or self.anchor_max_evaluations < 10 or self.min_link_tracks < 1:
            raise ValueError("min_correspondences must be >= 3, anchor_max_evaluations >= 10 and min_link_tracks >= 1")


@dataclass
class PairPoses:
    """What :func:`estimate_pair_poses` found. ``T_scan_cam``: pair folder name -> 4x4 pose of its
    left camera in the scan frame (the first pair's left camera frame), metric."""

    T_scan_cam: dict[str, np.ndarray]
    scale: float  # metres per SfM unit (median over pairs of stereo depth / SfM depth) [m]
    pair_scales: dict[str, float]  # per pair [m]
    scale_spread: float  # (max - min) / median of pair_scales [-]
    n_images: int  # images given [-]
    n_registered: int  # images SfM placed [-]
    n_points3d: int  # triangulated SIFT points [-]
    reprojection_error_px: float  # mean [px]
    right_rotation_deg: dict[str, float]  # per pair: SfM left->right rotation vs the calibration's R [deg]
    baseline_ratio: dict[str, float]  # per pair: SfM left-right distance / calibrated baseline [-]
    anchor: dict[str, dict] = field(default_factory=dict)  # per pair: correspondences, residual, correction
    timings_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "frame": "left camera of the first pair (OpenCV axes)",
            "T_scan_cam": {k: v.tolist() for k, v in self.T_scan_cam.items()},
            "scale_m_per_unit": self.scale, "pair_scales": self.pair_scales, "scale_spread": self.scale_spread,
            "n_images": self.n_images, "n_registered": self.n_registered, "n_points3d": self.n_points3d,
            "reprojection_error_px": self.reprojection_error_px, "right_rotation_deg": self.right_rotation_deg,
            "baseline_ratio": self.baseline_ratio, "anchor": self.anchor, "timings_s": self.timings_s,
        }


def pair_has_pose(calibration_path: str | Path) -> bool:
    """Whether a pair's ``calibration.yaml`` holds its camera pose (``T_pile_cam``)."""
    import cv2

    path = Path(calibration_path)
    try:
        fs = cv2.FileStorage(path.read_text(), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (OSError, cv2.error):
        return False
    try:
        return not fs.getNode(POSE_KEY).empty()
    finally:
        fs.release()


def _angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def _camera(pairs: Sequence[ScanPair]) -> tuple[str, str]:
    """pycolmap camera model and parameters shared by every image (COLMAP puts pixel centres at
    +0.5, OpenCV at integers). Raises :class:`SfmError` when the images' intrinsics differ."""
    c0 = pairs[0].calibration
    K, D = c0.K_left, c0.D_left
    for p in pairs:
        c = p.calibration
        for name, K2, D2 in (("K1", c.K_left, c.D_left), ("K2", c.K_right, c.D_right)):
            if c.image_size != c0.image_size or not np.allclose(K2, K, rtol=0.01, atol=1.0) \
                    or not np.allclose(D2, D, atol=1e-3):
                raise SfmError(
                    f"{p.folder}: {name} differs from {pairs[0].folder}'s left camera; SfM here assumes one "
                    "camera for every image (one ZED, one resolution). Rectify/undistort the images to a "
                    "common camera first, or give the pairs their poses (T_pile_cam)"
                )
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5
    if not np.any(D):
        return "PINHOLE", ",".join(repr(float(v)) for v in (fx, fy, cx, cy))
    k1, k2, p1, p2, k3 = (float(v) for v in D)
    return "FULL_OPENCV", ",".join(repr(float(v)) for v in (fx, fy, cx, cy, k1, k2, p1, p2, k3, 0, 0, 0))


def _image_name(stem: str, side: str) -> str:
    return f"{side}/{stem}.png"


def _run_colmap(pairs: Sequence[ScanPair], names: list[str], work: Path, cfg: SfmConfig):
    """Write the images, run extraction, matching and mapping; the largest model and timings.

    With ``cfg.rig`` the left and right images of a pair are one frame of a two-camera rig whose
    right camera is held at the calibration's ``R``, ``T`` (COLMAP's rig support): the model
    comes out metric and each right camera is tied to its left one."""
    import cv2
    import pycolmap

    images = work / "images"
    for side in ("left", "right"):
        (images / side).mkdir(parents=True)
    for p, stem in zip(pairs, names):
        for side, img in (("left", p.left), ("right", p.right)):
            cv2.imwrite(str(images / _image_name(stem, side)), np.ascontiguousarray(img[..., ::-1]))
    db = work / "database.db"
    model, params = _camera(pairs)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = model
    reader.camera_params = params
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = cfg.max_image_size_px
    extraction.num_threads = cfg.num_threads
    extraction.sift.max_num_features = cfg.max_features
    image_names = [_image_name(stem, side) for stem in names for side in ("left", "right")]
    t0 = time.perf_counter()
    pycolmap.extract_features(db, images, image_names=image_names,
                              camera_mode=pycolmap.CameraMode.PER_FOLDER if cfg.rig else pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    if cfg.rig:
        c = pairs[0].calibration
        rig = pycolmap.RigConfig(cameras=[
            pycolmap.RigConfigCamera(ref_sensor=True, image_prefix="left/"),
            pycolmap.RigConfigCamera(image_prefix="right/",
                                     cam_from_rig=pycolmap.Rigid3d(np.column_stack([c.R, c.T]))),
        ])
        database = pycolmap.Database.open(db)
        try:
            pycolmap.apply_rig_config([rig], database)
        finally:
            database.close()
    t1 = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = cfg.num_threads
    pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
    t2 = time.perf_counter()
    opts = pycolmap.IncrementalPipelineOptions()
    opts.min_num_matches = cfg.min_matches
    opts.multiple_models = True
    opts.num_threads = cfg.num_threads
    opts.random_seed = cfg.seed
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.ba_refine_sensor_from_rig = False
    opts.mapper.abs_pose_refine_focal_length = False
    opts.mapper.abs_pose_refine_extra_params = False
    opts.mapper.init_min_tri_angle = cfg.init_min_tri_angle_deg
    opts.mapper.random_seed = cfg.seed
    opts.triangulation.ignore_two_view_tracks = False  # left-right tracks tie each right camera
    out = work / "sparse"
    out.mkdir()
    models = pycolmap.incremental_mapping(db, images, out, options=opts)
    t3 = time.perf_counter()
    best = max(models.values(), key=lambda r: r.num_reg_images()) if models else None
    return best, {"sift_s": t1 - t0, "match_s": t2 - t1, "mapping_s": t3 - t2}


def estimate_pair_poses(pairs: Sequence[ScanPair], config: SfmConfig | None = None,
                        clouds: Sequence[tuple[np.ndarray, np.ndarray, float]] | None = None,
                        progress: Callable[[str], None] | None = None) -> PairPoses:
    """``T_scan_cam`` of every pair's left camera (scan frame = the first pair's left camera),
    from pycolmap SfM on all left and right images (a rig with the calibrated baseline), checked
    against and anchored to each pair's stereo depth (see the module docstring). ``clouds``:
    :func:`camera_clouds` of the pairs (computed with default matching settings when not given).

    Raises :class:`SfmRegistrationError` naming the pairs SfM could not place,
    :class:`SfmScaleError` when the pairs' scales disagree, :class:`SfmError` otherwise."""
    cfg = config or SfmConfig()
    say = progress or (lambda s: None)
    if len(pairs) < 2:
        raise SfmError("SfM needs at least two stereo pairs; a single pair's scan frame is its left camera")
    t0 = time.perf_counter()
    names = [f"p{k:03d}" for k in range(len(pairs))]
    label = {n: p.folder.name for n, p in zip(names, pairs)}
    labels = [label[n] for n in names]
    rec, timings = _sfm_model(pairs, names, cfg, say)
    poses = _placed_images(rec, names, label, len(pairs))
    T_w_cam = [poses[_image_name(n, "left")] for n in names]
    baseline_ratio, rot_err = _rig_check(poses, names, label, pairs)
    # metric scale: the stereo depth of each pair (its calibrated baseline) against SfM's depth
    t = time.perf_counter()
    say("anchoring the pair poses to their stereo depth")
    clouds = list(clouds) if clouds is not None else camera_clouds(pairs)
    tracks, who, Y = _track_observations(rec, names, pairs, clouds, cfg)
    _check_correspondences(who, pairs, cfg)
    _check_linked(tracks, who, labels, pairs, cfg)
    pair_scales, scale, spread = _metric_scale(rec, names, labels, pairs, clouds, cfg)
    for T in T_w_cam:
        T[:3, 3] *= scale
    T_anchor, anchor = _stereo_anchor(T_w_cam, tracks, who, Y, cfg, labels)
    T_scan_cam = _scan_frame_poses(T_w_cam, T_anchor, anchor, labels)
    _check_anchor(anchor, cfg)
    result = PairPoses(
        T_scan_cam=T_scan_cam, scale=scale, pair_scales=pair_scales, scale_spread=spread,
        n_images=2 * len(pairs), n_registered=int(rec.num_reg_images()), n_points3d=int(rec.num_points3D()),
        reprojection_error_px=float(rec.compute_mean_reprojection_error()), right_rotation_deg=rot_err,
        baseline_ratio=baseline_ratio, anchor=anchor, timings_s=dict(timings),
    )
    result.timings_s["anchor_s"] = time.perf_counter() - t
    result.timings_s["total_s"] = time.perf_counter() - t0
    return result


def _sfm_model(pairs: Sequence[ScanPair], names: list[str], cfg: SfmConfig, say: Callable[[str], None]):
    """pycolmap's reconstruction of all the pairs' images (in a temporary folder) and its timings."""
    work = Path(tempfile.mkdtemp(prefix="loggrasp-sfm-"))
    try:
        say(f"SfM (pycolmap) on {2 * len(pairs)} images")
        try:
            rec, timings = _run_colmap(pairs, names, work, cfg)
        except (RuntimeError, ValueError) as exc:
            raise SfmError(f"pycolmap failed on the scan's images: {exc}") from exc
        if cfg.keep_workdir:
            shutil.copytree(work, cfg.keep_workdir, dirs_exist_ok=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return rec, timings


def _placed_images(rec, names: list[str], label: dict[str, str], n_pairs: int) -> dict[str, np.ndarray]:
    """``T_world_cam`` of every image SfM placed; an error naming the pairs' images it did not place."""
    poses = {}
    if rec is not None:
        for img in dict(rec.images).values():
            if img.has_pose:
                m = np.eye(4)
                m[:3] = np.asarray(img.cam_from_world().matrix(), dtype=np.float64)
                poses[img.name] = np.linalg.inv(m)  # T_world_cam
    missing = [label[n] + f" ({side})" for n in names for side in ("left", "right")
               if _image_name(n, side) not in poses]
    if missing:
        raise SfmRegistrationError(
            f"SfM placed {len(poses)} of {2 * n_pairs} images; not placed: {', '.join(missing)}. These pairs do "
            "not overlap the others enough (or see too little texture): take pairs that overlap their "
            "neighbours by about a third of the image, remove the stray pairs, or give the pairs their "
            "poses (T_pile_cam in calibration.yaml)"
        )
    return poses


def _rig_check(poses: dict[str, np.ndarray], names: list[str], label: dict[str, str],
               pairs: Sequence[ScanPair]) -> tuple[dict[str, float], dict[str, float]]:
    """The rig's right camera as SfM placed it vs the calibration (R, T), the metric check: per pair,
    SfM's baseline over the calibrated one [-] and the rotation between them [deg]."""
    baseline_ratio, rot_err = {}, {}
    for n, p in zip(names, pairs):
        Tl, Tr = poses[_image_name(n, "left")], poses[_image_name(n, "right")]
        baseline_ratio[label[n]] = float(np.linalg.norm(Tl[:3, 3] - Tr[:3, 3])) / p.calibration.baseline_m
        rot_err[label[n]] = _angle_deg((Tr[:3, :3].T @ Tl[:3, :3]) @ p.calibration.R.T)
    return baseline_ratio, rot_err


def _check_correspondences(who: np.ndarray, pairs: Sequence[ScanPair], cfg: SfmConfig) -> None:
    """Every pair has ``min_correspondences`` SfM points seen by another pair, with stereo depth."""
    for i, pair in enumerate(pairs):
        n = int((who == i).sum())
        if n < cfg.min_correspondences:
            raise SfmRegistrationError(
                f"{pair.folder}: only {n} SfM points of its left image are also seen by another "
                f"pair and have stereo depth (need {cfg.min_correspondences}); it overlaps the other pairs too "
                "little. Re-take it overlapping its neighbours by about a third, drop it, or give the pairs "
                "their poses"
            )


def _metric_scale(rec, names: list[str], labels: list[str], pairs: Sequence[ScanPair], clouds,
                  cfg: SfmConfig) -> tuple[dict[str, float], float, float]:
    """Each pair's scale (stereo depth / SfM depth), their median and relative spread; an error when
    they disagree by more than ``max_scale_spread``."""
    pair_scales = dict(zip(labels, _pair_scales(rec, names, pairs, clouds)))
    vals = np.array([v for v in pair_scales.values() if np.isfinite(v)])
    scale = float(np.median(vals)) if vals.size else math.nan
    spread = float((vals.max() - vals.min()) / scale) if vals.size else math.nan
    if not np.isfinite(spread) or spread > cfg.max_scale_spread:
        worst = max(pair_scales, key=lambda k: abs(pair_scales[k] - scale) if np.isfinite(pair_scales[k]) else np.inf)
        raise SfmScaleError(
            f"the pairs' scales (stereo depth / SfM depth) disagree by {spread * 100:.1f} % (limit "
            f"{cfg.max_scale_spread * 100:.0f} %; worst: {worst}): the SfM model is distorted, or a pair's "
            "calibration (baseline T) is not its camera's. Check the calibrations, or give the pairs their poses"
        )
    return pair_scales, scale, spread


def _scan_frame_poses(T_w_cam: list[np.ndarray], T_anchor: list[np.ndarray], anchor: dict[str, dict],
                      labels: list[str]) -> dict[str, np.ndarray]:
    """The anchored poses in the scan frame (the first pair's left camera); each pair's ``anchor``
    entry gets how far the anchoring moved it from SfM's (metric) pose."""
    T0_inv = np.linalg.inv(T_anchor[0])
    S0_inv = np.linalg.inv(T_w_cam[0])
    T_scan_cam = {}
    for i, lab in enumerate(labels):
        T_scan_cam[lab] = T0_inv @ T_anchor[i]
        sfm_rel = S0_inv @ T_w_cam[i]
        d = np.linalg.inv(sfm_rel) @ T_scan_cam[lab]
        anchor[lab].update({"sfm_correction_m": float(np.linalg.norm(T_scan_cam[lab][:3, 3] - sfm_rel[:3, 3])),
                            "sfm_correction_deg": _angle_deg(d[:3, :3])})
    return T_scan_cam


def _check_anchor(anchor: dict[str, dict], cfg: SfmConfig) -> None:
    """Each pair's stereo points of shared features lie within ``max_anchor_rms_m`` of the others'."""
    for lab, a in anchor.items():
        if a["residual_rms_m"] > cfg.max_anchor_rms_m:
            raise SfmError(
                f"{lab}: its stereo points of shared SfM features lie {a['residual_rms_m'] * 100:.1f} cm (RMS) from "
                f"the other pairs' (limit {cfg.max_anchor_rms_m * 100:.0f} cm): its pose cannot be trusted. Check "
                "its images and calibration, or drop it"
            )


def _depth_map(points_cam: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Nearest-surface depth [m] per left-image pixel from a pair's camera-frame points (NaN: none)."""
    W, H = size
    z = points_cam[:, 2]
    ok = z > 0
    u = np.rint(K[0, 0] * points_cam[ok, 0] / z[ok] + K[0, 2]).astype(np.int64)
    v = np.rint(K[1, 1] * points_cam[ok, 1] / z[ok] + K[1, 2]).astype(np.int64)
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    depth = np.full((H, W), np.inf)
    np.minimum.at(depth, (v[inside], u[inside]), z[ok][inside])
    depth[~np.isfinite(depth)] = np.nan
    return depth


def _patch_depth(depth: np.ndarray, xy: np.ndarray, cfg: SfmConfig) -> np.ndarray:
    """Stereo depth at sub-pixel positions ``xy`` (N, 2): the median of the surrounding
    ``depth_patch_px`` square; NaN where too little of it has depth or where it spans a depth step
    (feature points like edges, where stereo matching is worst)."""
    H, W = depth.shape
    h = cfg.depth_patch_px // 2
    dv, du = np.mgrid[-h:h + 1, -h:h + 1]
    u = np.rint(xy[:, 0]).astype(np.int64)[:, None] + du.ravel()
    v = np.rint(xy[:, 1]).astype(np.int64)[:, None] + dv.ravel()
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    patch = np.where(inside, depth[np.clip(v, 0, H - 1), np.clip(u, 0, W - 1)], np.nan)
    valid = np.isfinite(patch).mean(axis=1)
    out = np.full(len(xy), np.nan)
    good = valid >= 0.6
    if good.any():
        lo, med, hi = np.nanpercentile(patch[good], [10, 50, 90], axis=1)
        out[np.flatnonzero(good)] = np.where(hi - lo < cfg.depth_step_m, med, np.nan)
    return out


def _track_observations(rec, names: list[str], pairs: Sequence[ScanPair],
                        clouds: Sequence[tuple[np.ndarray, np.ndarray, float]], cfg: SfmConfig):
    """Left-image observations of SfM tracks seen by two or more pairs, with the stereo point of
    each (the pair's own metric depth at that pixel, camera frame). Returns (track index,
    pair index, Y (3,)) arrays."""
    import cv2

    index = {}
    images = dict(rec.images)  # pycolmap returns copies: fetch once
    for img in images.values():
        side, stem = img.name.split("/")[0], img.name.split("/")[-1][:-4]
        if side == "left" and stem in names:
            index[img.image_id] = names.index(stem)
    depths = [_depth_map(pts, p.calibration.K_left, p.calibration.image_size) for p, (pts, _, _) in zip(pairs, clouds)]
    points2d = {i: [p2.xy for p2 in images[i].points2D] for i in index}
    tracks, who, xy = [], [], []
    for k, (pid, pt) in enumerate(dict(rec.points3D).items()):
        obs = [(index[e.image_id], e.image_id, e.point2D_idx) for e in pt.track.elements if e.image_id in index]
        if len({o[0] for o in obs}) < 2:
            continue
        for pair_i, image_id, idx in obs:
            tracks.append(k)
            who.append(pair_i)
            xy.append(np.asarray(points2d[image_id][idx], dtype=np.float64) - 0.5)  # OpenCV pixels
    tracks, who = np.array(tracks, dtype=np.int64), np.array(who, dtype=np.int64)
    xy = np.array(xy, dtype=np.float64).reshape(-1, 2)
    Y = np.full((len(who), 3), np.nan)
    for i, p in enumerate(pairs):
        sel = np.flatnonzero(who == i)
        if sel.size == 0:
            continue
        c = p.calibration
        W, H = c.image_size
        z = _patch_depth(depths[i], xy[sel], cfg)
        rays = cv2.undistortPoints(xy[sel].reshape(-1, 1, 2), c.K_left, c.D_left).reshape(-1, 2)
        Y[sel] = np.column_stack([rays * z[:, None], z])
    keep = np.isfinite(Y).all(axis=1)
    tracks, who, Y = tracks[keep], who[keep], Y[keep]
    # tracks still seen by two or more pairs
    pairs_per_track = np.bincount(np.unique(np.column_stack([tracks, who]), axis=0)[:, 0],
                                  minlength=int(tracks.max()) + 1 if len(tracks) else 0)
    keep = pairs_per_track[tracks] >= 2 if len(tracks) else np.zeros(0, dtype=bool)
    _, tracks = np.unique(tracks[keep], return_inverse=True)
    return tracks.astype(np.int64), who[keep], Y[keep]


def _pair_scales(rec, names: list[str], pairs: Sequence[ScanPair],
                 clouds: Sequence[tuple[np.ndarray, np.ndarray, float]]) -> list[float]:
    """Per pair: median of (stereo depth / SfM depth) over the SfM points its left image sees."""
    out = []
    xyz = {k: np.asarray(v.xyz, dtype=np.float64) for k, v in dict(rec.points3D).items()}  # copies: once
    for stem, p, (pts, _, _) in zip(names, pairs, clouds):
        c = p.calibration
        depth = _depth_map(pts, c.K_left, c.image_size)
        img = rec.find_image_with_name(_image_name(stem, "left"))
        m = np.asarray(img.cam_from_world().matrix(), dtype=np.float64)
        ratios = []
        W, H = c.image_size
        for p2 in img.points2D:
            if not p2.has_point3D():
                continue
            z_sfm = float((m[:, :3] @ xyz[p2.point3D_id] + m[:, 3])[2])
            u, v = (int(round(x - 0.5)) for x in p2.xy)
            if 0 <= u < W and 0 <= v < H and z_sfm > 0 and np.isfinite(depth[v, u]):
                ratios.append(depth[v, u] / z_sfm)
        out.append(float(np.median(ratios)) if len(ratios) >= 10 else math.nan)
    return out


def _check_linked(tracks: np.ndarray, who: np.ndarray, labels: list[str], pairs: Sequence[ScanPair],
                  cfg: SfmConfig) -> None:
    """Every pair must be tied to the first through pairs sharing at least ``min_link_tracks``
    depth-checked SfM points: a group of pairs tied only among themselves is placed by SfM alone,
    unchecked (on a ground texture that repeats, SfM can join such groups metres apart)."""
    n = len(labels)
    sets = [set(tracks[who == i].tolist()) for i in range(n)]
    linked = {0}
    frontier = [0]
    while frontier:
        i = frontier.pop()
        for j in range(n):
            if j not in linked and len(sets[i] & sets[j]) >= cfg.min_link_tracks:
                linked.add(j)
                frontier.append(j)
    if len(linked) < n:
        loose = [str(pairs[j].folder) for j in range(n) if j not in linked]
        raise SfmRegistrationError(
            f"pairs {', '.join(loose)} share fewer than {cfg.min_link_tracks} depth-checked SfM points with "
            f"{labels[0]} and the pairs tied to it: SfM's placement of them cannot be checked against their stereo "
            "depth. Take pairs that overlap their neighbours by about a third, or give the pairs their poses"
        )


def _stereo_anchor(T_w_cam: list[np.ndarray], tracks: np.ndarray, who: np.ndarray, Y: np.ndarray,
                   cfg: SfmConfig, labels: list[str]) -> tuple[list[np.ndarray], dict]:
    """Poses that bring every pair's stereo points of a shared SfM track together: robust least
    squares (scipy, soft-L1) over the poses of all pairs but the first, on the differences
    ``T_a Y_a - T_b Y_b`` of every two observations of a track, started at the SfM poses; then
    observations beyond 3 robust sigmas (within the configured bounds) are dropped and it is
    solved again. Returns the poses and a per-pair report (correspondences, residual RMS)."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    n = len(T_w_cam)
    order = np.argsort(tracks, kind="stable")
    tr, wh = tracks[order], who[order]
    starts = np.flatnonzero(np.r_[True, tr[1:] != tr[:-1]])
    ends_ = np.r_[starts[1:], len(tr)]
    ia, ib = [], []
    for s0, s1 in zip(starts, ends_):
        for a in range(s0, s1):
            for b in range(a + 1, s1):
                if wh[a] != wh[b]:
                    ia.append(order[a])
                    ib.append(order[b])
    ia, ib = np.array(ia, dtype=np.int64), np.array(ib, dtype=np.int64)
    pa, pb = who[ia], who[ib]
    x0 = np.concatenate([np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])
                         for T in T_w_cam[1:]])
    T0 = T_w_cam[0]

    def poses(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R = np.empty((n, 3, 3))
        t = np.empty((n, 3))
        R[0], t[0] = T0[:3, :3], T0[:3, 3]
        if n > 1:
            xx = x.reshape(n - 1, 6)
            R[1:] = Rotation.from_rotvec(xx[:, :3]).as_matrix()
            t[1:] = xx[:, 3:]
        return R, t

    def diffs(x: np.ndarray, keep: np.ndarray) -> np.ndarray:
        R, t = poses(x)
        A = np.einsum("nij,nj->ni", R[pa[keep]], Y[ia[keep]]) + t[pa[keep]]
        B = np.einsum("nij,nj->ni", R[pb[keep]], Y[ib[keep]]) + t[pb[keep]]
        return A - B

    keep = np.ones(len(ia), dtype=bool)
    x = x0
    for _ in range(2):
        sol = least_squares(lambda v: diffs(v, keep).ravel(), x, loss="soft_l1", f_scale=cfg.anchor_min_threshold_m,
                            max_nfev=cfg.anchor_max_evaluations)
        x = sol.x
        r = np.linalg.norm(diffs(x, np.ones(len(ia), dtype=bool)), axis=1)
        sigma = 1.4826 * float(np.median(r[keep])) if keep.any() else 0.0
        thr = float(np.clip(3 * sigma, cfg.anchor_min_threshold_m, cfg.anchor_max_threshold_m))
        keep = r < thr
    R, t = poses(x)
    out = []
    for i in range(n):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[i], t[i]
        out.append(T)
    report = {}
    for i in range(n):
        sel = keep & ((pa == i) | (pb == i))
        report[labels[i]] = {"correspondences": int(sel.sum()),
                             "residual_rms_m": float(np.sqrt(np.mean(r[sel] ** 2))) if sel.any() else math.nan}
    return out, report
