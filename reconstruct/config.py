"""How a scan is reconstructed: :class:`ReconstructConfig` (every stage's settings, with units) and
the pile frame's direction and patch size it implies."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from reconstruct.errors import RegistrationError
from reconstruct.fitting.coverage import CoverageConfig
from reconstruct.fitting.fit import FitConfig
from reconstruct.fitting.joint_config import ESTIMATORS, JointConfig
from reconstruct.fitting.fuse import FuseConfig
from reconstruct.registration import ScanPose
from reconstruct.scan.coarse_pose import CoarseConfig
from reconstruct.scan.sfm import SfmConfig
from reconstruct.scan.stereo import StereoConfig


PAIR_POSES = ("auto", "calibration", "sfm")
GEOREGISTER = ("auto", "scan-pose", "gnss")
RENDER_PX_MULTIPLE = 16  # re-render sides are a multiple of this (a depth-4 U-Net pools 4 times) [px]
MAX_EXTENT_M = 100.0  # largest pile patch [m]




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
    coarse: CoarseConfig = field(default_factory=CoarseConfig)
    allow_float: bool = False  # accept RTK float end points
    max_endpoint_distance_m: float = 1.0  # an end point this far from every scan point is outside the scanned
    #                                       area: an error unless its log is seen (coverage) [m]
    coverage: CoverageConfig = field(default_factory=CoverageConfig)  # ends outside the scan on logs it sees
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
    estimator: str = "rules22"  # ESTIMATORS: "rules22" (fitting revision 22, the default until the joint one
    #                             matches it on the held-out set) or "joint" (reconstruct.fitting.joint_*)
    joint: JointConfig = field(default_factory=JointConfig)  # the joint estimator's parameters
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
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {self.estimator!r}")
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
