"""Stereo scans to point clouds: read a scan folder, rectify, match (OpenCV SGBM), reproject.

A *scan folder* holds one stereo pair, or several pairs in sub-folders (the rig moved; each pair
carries its own left-camera pose). A pair is what :class:`synth.render.stereo.StereoPair` writes (and
what a ZED export converted to it looks like): ``left.png``, ``right.png`` and
``calibration.yaml`` (OpenCV FileStorage: ``K1 D1 K2 D2 R T image_size`` and the left camera's
pose ``T_pile_cam`` in the *scan frame*) and/or the camera's ZED ``SN<serial>.conf`` (or
``zed.conf``), read at the images' resolution and checked against each other
(:mod:`reconstruct.scan.calibration`). Other files (``depth_left.npz``, ``meta.json``) are not read.

Every problem with the input is a :class:`~reconstruct.errors.ScanError` naming the file: a
missing or unreadable image, left and right of different sizes, a calibration whose image size
differs from the images, or a pair where matching finds (almost) no depth.

Pipeline per pair: ``cv2.stereoRectify`` (zero disparity at infinity, ``alpha=0``) →
``cv2.initUndistortRectifyMap``/``remap`` → ``StereoSGBM`` (3-way; disparities as int16 x16) →
``cv2.reprojectImageTo3D`` → points in the left camera frame (undoing the rectifying rotation) →
scan frame (``T_pile_cam``). Pairs are concatenated, then voxel-downsampled and cleaned by
statistical outlier removal (open3d).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from reconstruct.errors import ScanError

PAIR_FILES = ("left.png", "right.png", "calibration.yaml")


@dataclass(frozen=True)
class StereoConfig:
    """Matching and cleaning of stereo scans (units in the names/comments)."""

    z_min_m: float = 1.5  # nearest depth searched [m]
    z_max_m: float = 6.0  # farthest depth searched [m]
    block_size: int = 5  # SGBM block side [px], odd
    uniqueness: int = 5  # SGBM uniqueness ratio [%]
    speckle_window: int = 100  # SGBM speckle filter window [px]
    speckle_range: int = 2  # SGBM speckle range [disparity units]
    disp12_max_diff: int = 1  # left-right consistency [px]
    border_px: int = 8  # image border dropped (rectification edges) [px]
    voxel_m: float = 0.01  # voxel downsampling size [m]; 0 = none
    outlier_neighbours: int = 20  # statistical outlier removal neighbours [-]; 0 = none
    outlier_std_ratio: float = 2.0  # ... standard deviation ratio [-]
    min_valid_fraction: float = 0.3  # fewer matched pixels: unusable (unrelated images still "match" ~25 %) [-]

    def __post_init__(self) -> None:
        if not 0 < self.z_min_m < self.z_max_m:
            raise ValueError(f"need 0 < z_min_m < z_max_m, got {self.z_min_m}, {self.z_max_m}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd and >= 1, got {self.block_size}")
        if self.voxel_m < 0 or self.outlier_neighbours < 0 or self.outlier_std_ratio <= 0:
            raise ValueError("voxel_m and outlier_neighbours must be >= 0, outlier_std_ratio > 0")
        if not 0 <= self.min_valid_fraction < 1:
            raise ValueError("min_valid_fraction must be in [0, 1)")
        if self.border_px < 0:
            raise ValueError("border_px must be >= 0")


@dataclass
class ScanPair:
    """One stereo pair as read from disk (RGB uint8 images, calibration)."""

    folder: Path
    left: np.ndarray
    right: np.ndarray
    calibration: object  # synth.geometry.calibration.StereoCalibration


@dataclass
class ScanCloud:
    """A fused point cloud in the scan frame, with colours and provenance."""

    points: np.ndarray  # (N, 3) float64 [m], scan frame
    colours: np.ndarray  # (N, 3) float32 RGB in [0, 1]
    pairs: list[str] = field(default_factory=list)  # pair folders used
    camera_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (P, 3) [m]
    valid_fractions: list[float] = field(default_factory=list)  # matched share per pair [-]
    timings_s: dict = field(default_factory=dict)


def find_pairs(scan_dir: str | Path) -> list[Path]:
    """The pair folders of a scan: ``scan_dir`` itself if it holds ``left.png``, otherwise its
    sub-folders that do (sorted by name). Raises :class:`ScanError` when there is none."""
    scan_dir = Path(scan_dir)
    if not scan_dir.is_dir():
        raise ScanError(f"scan folder {scan_dir} does not exist or is not a folder; check the path")
    if (scan_dir / "left.png").exists() or (scan_dir / "right.png").exists():
        return [scan_dir]
    pairs = sorted(p for p in scan_dir.iterdir() if p.is_dir() and
                   ((p / "left.png").exists() or (p / "right.png").exists()))
    if not pairs:
        raise ScanError(
            f"{scan_dir} holds no stereo pair: expected left.png, right.png and calibration.yaml in "
            "it or in its sub-folders (one per pair)"
        )
    return pairs


def read_pair(folder: str | Path) -> ScanPair:
    """Read one pair folder and check it (sizes of both images and the calibration)."""
    import cv2

    folder = Path(folder)
    imgs = []
    for name in ("left.png", "right.png"):
        path = folder / name
        if not path.exists():
            raise ScanError(f"{path} is missing; a stereo pair needs left.png and right.png")
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise ScanError(f"{path} cannot be read as an image (corrupt or not a PNG); re-export it")
        imgs.append(np.ascontiguousarray(img[..., ::-1]))
    left, right = imgs
    if left.shape != right.shape:
        raise ScanError(
            f"{folder}: left.png is {left.shape[1]}x{left.shape[0]} px but right.png is "
            f"{right.shape[1]}x{right.shape[0]} px; both images of a pair must have the same size"
        )
    from reconstruct.scan.calibration import read_pair_calibration

    calib, cname = read_pair_calibration(folder, (left.shape[1], left.shape[0]))
    cpath = folder / cname.split(" + ")[0]
    w, h = calib.image_size
    if (w, h) != (left.shape[1], left.shape[0]):
        raise ScanError(
            f"{cpath} is for {w}x{h} px images but {folder}'s images are "
            f"{left.shape[1]}x{left.shape[0]} px; use the calibration of this camera resolution"
        )
    for name, K in (("K1", calib.K_left), ("K2", calib.K_right)):
        if not (K[0, 0] > 0 and K[1, 1] > 0 and 0 <= K[0, 2] <= w and 0 <= K[1, 2] <= h):
            raise ScanError(f"{cpath}: {name} does not fit {w}x{h} px images (focal lengths must be > 0 "
                            "and the principal point inside the image)")
    if not calib.baseline_m > 1e-3:
        raise ScanError(f"{cpath}: the baseline |T| is {calib.baseline_m * 1000:.2f} mm; T must be the "
                        "left-to-right translation in metres")
    return ScanPair(folder=folder, left=left, right=right, calibration=calib)


def pair_points(pair: ScanPair, config: StereoConfig | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Points (scan frame, (N, 3) float64), their colours ((N, 3) float32) and the share of
    pixels matched, for one pair."""
    import cv2

    from synth.render.stereo import rectify_and_match

    cfg = config or StereoConfig()
    calib = pair.calibration
    m = rectify_and_match(pair.left, pair.right, calib, cfg)
    disp, valid, Q, R1, left_r = m.disparity_px, m.valid, m.Q, m.R1, m.left_rectified
    b = cfg.border_px
    if b:
        valid[:b], valid[-b:], valid[:, :b], valid[:, -b:] = False, False, False, False
    frac = float(valid.mean())
    if frac < cfg.min_valid_fraction:
        raise ScanError(
            f"{pair.folder}: stereo matching found depth for only {frac * 100:.1f} % of the pixels; "
            f"the calibration does not fit the images, or the scene is outside "
            f"{cfg.z_min_m}-{cfg.z_max_m} m (set z_min_m/z_max_m)"
        )
    pts = cv2.reprojectImageTo3D(disp, Q)[valid].astype(np.float64)  # rectified left camera
    col = left_r[valid].astype(np.float32) / 255.0
    pts = pts @ R1  # rectified -> original left camera (R1 maps original to rectified)
    z = pts[:, 2]
    keep = np.isfinite(pts).all(axis=1) & (z > cfg.z_min_m * 0.9) & (z < cfg.z_max_m * 1.1)
    pts, col = pts[keep], col[keep]
    T = calib.T_pile_cam
    return pts @ T[:3, :3].T + T[:3, 3], col, frac


def thin_pair(points: np.ndarray, colours: np.ndarray, cfg: StereoConfig) -> tuple[np.ndarray, np.ndarray]:
    """One pair's points and colours voxel-downsampled to ``cfg.voxel_m`` (open3d; unchanged at 0)."""
    if cfg.voxel_m <= 0:
        return points, colours
    import open3d as o3d

    one = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    one.colors = o3d.utility.Vector3dVector(colours.astype(np.float64))
    one = one.voxel_down_sample(cfg.voxel_m)
    return np.asarray(one.points), np.asarray(one.colors, dtype=np.float32)


def clean_cloud(points: Sequence[np.ndarray], colours: Sequence[np.ndarray], cfg: StereoConfig,
                where: str = "") -> tuple[np.ndarray, np.ndarray]:
    """The pairs' points fused: voxel-downsampled together (when there are several) and cleared of
    statistical outliers (open3d). Raises :class:`ScanError` (``where`` first) when under 100 are left."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(points)))
    pc.colors = o3d.utility.Vector3dVector(np.concatenate(colours).astype(np.float64))
    if cfg.voxel_m > 0 and len(points) > 1:
        pc = pc.voxel_down_sample(cfg.voxel_m)
    if cfg.outlier_neighbours > 0 and len(pc.points) > cfg.outlier_neighbours:
        pc, _ = pc.remove_statistical_outlier(cfg.outlier_neighbours, cfg.outlier_std_ratio)
    P = np.asarray(pc.points, dtype=np.float64)
    C = np.asarray(pc.colors, dtype=np.float32)
    if len(P) < 100:
        raise ScanError(f"{where}only {len(P)} points survive matching and cleaning; the scan is unusable")
    return P, C


def scan_cloud(scan_dir: str | Path, config: StereoConfig | None = None,
               progress: Callable[[str], None] | None = None) -> ScanCloud:
    """Read every pair of a scan folder and fuse their points in the scan frame (open3d voxel
    downsampling and statistical outlier removal). Raises :class:`ScanError`."""
    cfg = config or StereoConfig()
    say = progress or (lambda s: None)
    pairs = find_pairs(scan_dir)
    t0 = time.perf_counter()
    all_p, all_c, fracs, cams = [], [], [], []
    t_read = t_match = 0.0
    for folder in pairs:
        say(f"matching {folder}")
        ta = time.perf_counter()
        pair = read_pair(folder)
        tb = time.perf_counter()
        p, c, frac = pair_points(pair, cfg)
        t_read += tb - ta
        t_match += time.perf_counter() - tb
        p, c = thin_pair(p, c, cfg)  # each pair first: ~1 M points a pair is mostly redundant
        all_p.append(p)
        all_c.append(c)
        fracs.append(frac)
        cams.append(pair.calibration.T_pile_cam[:3, 3].copy())
    t1 = time.perf_counter()
    P, C = clean_cloud(all_p, all_c, cfg, f"{scan_dir}: ")
    return ScanCloud(points=P, colours=C, pairs=[str(p) for p in pairs], camera_positions=np.array(cams),
                     valid_fractions=fracs,
                     timings_s={"read_s": t_read, "match_s": t_match, "clean_s": time.perf_counter() - t1,
                                "total_s": time.perf_counter() - t0})


# -- pairs posed by structure from motion (reconstruct.scan.sfm) -------------------------------
def camera_points(pair: ScanPair, stereo: StereoConfig) -> tuple[np.ndarray, np.ndarray, float]:
    """A pair's stereo points in its own left camera frame."""
    from dataclasses import replace as dc_replace

    calib = dc_replace(pair.calibration, T_pile_cam=np.eye(4))
    return pair_points(ScanPair(pair.folder, pair.left, pair.right, calib), stereo)


def camera_clouds(pairs: Sequence[ScanPair], stereo: StereoConfig | None = None,
                  progress: Callable[[str], None] | None = None) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Every pair's stereo points, colours and matched share, in its own left camera frame."""
    say = progress or (lambda s: None)
    out = []
    for p in pairs:
        say(f"matching {p.folder}")
        out.append(camera_points(p, stereo or StereoConfig()))
    return out


def fuse_pairs(pairs: Sequence[ScanPair], T_scan_cam: dict[str, np.ndarray], config: StereoConfig | None = None,
               clouds: Sequence[tuple[np.ndarray, np.ndarray, float]] | None = None,
               progress: Callable[[str], None] | None = None) -> ScanCloud:
    """Every pair's points placed by ``T_scan_cam`` (pair folder name -> 4x4) and fused in the
    scan frame: per-pair and joint voxel downsampling, statistical outlier removal (open3d), as
    :func:`reconstruct.scan.stereo.scan_cloud` does with the calibrations' poses. ``clouds``:
    :func:`camera_clouds` of the pairs when already computed."""
    cfg = config or StereoConfig()
    say = progress or (lambda s: None)
    t0 = time.perf_counter()
    all_p, all_c, fracs, cams = [], [], [], []
    clouds = clouds if clouds is not None else camera_clouds(pairs, cfg, progress=say)
    for pair, (p, c, frac) in zip(pairs, clouds):
        T = np.asarray(T_scan_cam[pair.folder.name], dtype=np.float64)
        p = p @ T[:3, :3].T + T[:3, 3]
        p, c = thin_pair(p, c, cfg)
        all_p.append(p)
        all_c.append(c)
        fracs.append(frac)
        cams.append(T[:3, 3].copy())
    t1 = time.perf_counter()
    P, C = clean_cloud(all_p, all_c, cfg)
    return ScanCloud(points=P, colours=C, pairs=[str(p.folder) for p in pairs], camera_positions=np.array(cams),
                     valid_fractions=fracs,
                     timings_s={"match_s": t1 - t0, "clean_s": time.perf_counter() - t1,
                                "total_s": time.perf_counter() - t0})
