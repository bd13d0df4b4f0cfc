"""A scan plan sized from the survey: the smallest grid of stereo pairs whose footprint covers every
surveyed log end.

A field crew surveys the log ends before it scans, so it knows how far the pile spreads. The plan
takes those end points (with their horizontal sigmas) and the camera model the twin renders (a ZED
2-like rig looking straight down from ``height_m``) and returns the grid of pairs, its centre, its
direction and its spacing, such that every end, grown by ``margin_m`` plus ``n_sigma`` of its own
sigma, lies inside the part of some pair's left image that gets depth.

The footprint of one pair, at a depth ``d`` below the camera, in the rig's frame (``along``: the
baseline and the long image side; ``across``: image up): ``along`` from ``d (u0 - cx) / f`` to
``d (u1 - cx) / f`` and ``across`` +-``d (cy - v0) / f``, where ``u0`` leaves out the left image's
first columns that the matcher cannot give depth (:func:`synth.render.stereo.disparity_range`) and the
border the stereo stage drops, and ``u1``, ``v0`` the border. Pairs are spaced at most the twin's
spacing apart (overlap for fusion and SfM), so the grid's footprint at a depth is one rectangle: a
grid of ``n`` pairs covers ``(n - 1) spacing`` more than one pair, and the smallest ``n`` per axis is
found in closed form. The grid is never smaller than ``min_grid`` (the grid the benches measured).

Frames: points are given in any horizontal frame F (the pile frame in the twin, the site frame in the
field), ``z`` the height above the ground the camera height is measured from; the plan's centre and
pair positions are in F, ``yaw_rad`` the rig's ``along`` direction from F's +x.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reconstruct.errors import ScanPlanError


@dataclass(frozen=True)
class ScanPlanConfig:
    """How a scan is planned from surveyed end points (units in the names)."""

    height_m: float = 3.0  # camera height above the ground (the twin's default) [m]
    hfov_deg: float = 50.0  # horizontal field of view (ZED 2-like, the twin's) [deg]
    width_px: int = 1280  # image width [px]
    height_px: int = 720  # image height [px]
    baseline_m: float = 0.12  # stereo baseline (ZED 2) [m]
    z_min_m: float = 1.5  # nearest depth the matcher searches (StereoConfig.z_min_m) [m]
    z_max_m: float = 6.0  # farthest depth the matcher searches (StereoConfig.z_max_m) [m]
    border_px: int = 8  # image border the stereo stage drops (StereoConfig.border_px) [px]
    # past each end the scan must show: the end's face and about a log's diameter of ground beyond it
    # (the end placement tells an end from a log leaving the scan by where the log is NOT seen) [m]
    margin_m: float = 0.3
    # each end is grown by this many of its horizontal sigmas (an RTK float point is +-25 cm): 2 covers
    # ~95 % of where the end truly is [-]
    n_sigma: float = 2.0
    # the largest spacing between neighbouring pairs (the twin's grid: 50 % overlap along, ~35 % across at
    # the ground, what the stereo fusion and SfM were measured with) [m]
    spacing_along_m: float = 1.4
    spacing_across_m: float = 1.0
    # the smallest grid planned (along, across): the grid every bench measured; fewer pairs were never
    # measured to be enough (a log's far side seen from one pair only) [pairs]
    min_grid: tuple[int, int] = (2, 2)
    max_pairs_per_side: int = 8  # a survey needing more is refused (a point far off: check it) [pairs]

    def __post_init__(self) -> None:
        if not 0.2 <= self.height_m <= 100.0:
            raise ValueError(f"scan plan height_m must be in [0.2, 100] m, got {self.height_m}")
        if not 5.0 <= self.hfov_deg <= 150.0:
            raise ValueError(f"scan plan hfov_deg must be in [5, 150] deg, got {self.hfov_deg}")
        if self.width_px < 16 or self.height_px < 16 or 2 * self.border_px >= min(self.width_px, self.height_px):
            raise ValueError(f"scan plan image {self.width_px}x{self.height_px} px with a {self.border_px} px "
                             "border leaves no image")
        if not (self.baseline_m > 0 and 0 < self.z_min_m < self.z_max_m):
            raise ValueError("scan plan needs baseline_m > 0 and 0 < z_min_m < z_max_m")
        if not (self.margin_m >= 0 and math.isfinite(self.margin_m)):
            raise ValueError(f"scan plan margin_m must be >= 0 m, got {self.margin_m}")
        if not (self.n_sigma >= 0 and math.isfinite(self.n_sigma)):
            raise ValueError(f"scan plan n_sigma must be >= 0, got {self.n_sigma}")
        if not (self.spacing_along_m > 0 and self.spacing_across_m > 0):
            raise ValueError("scan plan spacing_along_m and spacing_across_m must be > 0 m")
        if len(self.min_grid) != 2 or min(self.min_grid) < 1 or max(self.min_grid) > self.max_pairs_per_side:
            raise ValueError(f"scan plan min_grid must be two counts in 1..max_pairs_per_side, got {self.min_grid}")
        lo_a, hi_a, lo_c, hi_c = self.footprint_slopes()
        if lo_a >= hi_a:
            raise ValueError(f"scan plan: the matcher's disparity band leaves no columns of a {self.width_px} px image")
        depth = self.height_m
        if self.spacing_along_m > depth * (hi_a - lo_a) or self.spacing_across_m > depth * (hi_c - lo_c):
            raise ValueError(f"scan plan spacing {self.spacing_along_m} x {self.spacing_across_m} m leaves gaps "
                             f"between pairs at {depth} m (footprint {depth * (hi_a - lo_a):.2f} x "
                             f"{depth * (hi_c - lo_c):.2f} m)")

    def focal_px(self) -> float:
        """The focal length [px] (square pixels, principal point centred: the twin's rig)."""
        return (self.width_px / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    def footprint_slopes(self) -> tuple[float, float, float, float]:
        """(along low, along high, across low, across high) of one pair's footprint per metre of depth,
        from its left camera: ``d * slope`` is the edge at depth ``d`` [m/m]."""
        from synth.render.stereo import disparity_range

        f = self.focal_px()
        d_min, n_disp = disparity_range(f * self.baseline_m, self.z_min_m, self.z_max_m)
        cx, cy = (self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0
        u0 = max(self.border_px, d_min + n_disp)
        u1 = self.width_px - 1 - self.border_px
        v0 = self.border_px
        return (u0 - cx) / f, (u1 - cx) / f, -(cy - v0) / f, (cy - v0) / f


@dataclass(frozen=True)
class ScanPlan:
    """A grid of straight-down stereo pairs: ``grid`` (along, across) pairs ``spacing_m`` apart about
    ``centre_xy`` (frame F), turned ``yaw_rad`` from F's +x, at ``height_m`` above the ground."""

    grid: tuple[int, int]  # pairs (along, across)
    centre_xy: tuple[float, float]  # the grid's centre in frame F [m]
    yaw_rad: float  # the rig's along direction from F's +x [rad]
    spacing_m: tuple[float, float]  # between neighbouring pairs (along, across) [m]
    height_m: float  # camera height above the ground [m]
    margin_m: float  # what each covered end was grown by, besides its sigmas [m]

    @property
    def n_pairs(self) -> int:
        return self.grid[0] * self.grid[1]

    def axes(self) -> np.ndarray:
        """2x2: rows are the along and across unit vectors in frame F."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.array([[c, s], [-s, c]])

    def pair_positions(self) -> np.ndarray:
        """(n_pairs, 2): each pair's left camera in frame F, along first then across (the twin's order)."""
        nx, ny = self.grid
        ax = self.axes()
        out = [np.asarray(self.centre_xy) + ax[0] * (ix - (nx - 1) / 2) * self.spacing_m[0]
               + ax[1] * (iy - (ny - 1) / 2) * self.spacing_m[1] for iy in range(ny) for ix in range(nx)]
        return np.array(out)

    def slack_m(self, points_xyz: np.ndarray, cfg: ScanPlanConfig) -> np.ndarray:
        """Per point: how far inside the grid's footprint (at its depth) it lies, the smaller of its
        four distances to the footprint's edges [m]; negative: outside by that much."""
        p = np.atleast_2d(np.asarray(points_xyz, dtype=float))
        lo_a, hi_a, lo_c, hi_c = cfg.footprint_slopes()
        q = (p[:, :2] - np.asarray(self.centre_xy)) @ self.axes().T
        depth = self.height_m - np.maximum(p[:, 2], 0.0)
        half = (np.array(self.grid) - 1) / 2 * np.asarray(self.spacing_m)
        return np.min(np.stack([q[:, 0] - (-half[0] + depth * lo_a), (half[0] + depth * hi_a) - q[:, 0],
                                q[:, 1] - (-half[1] + depth * lo_c), (half[1] + depth * hi_c) - q[:, 1]]), axis=0)

    def describe(self) -> str:
        """One line, e.g. ``3x2 pairs 1.4 x 1.0 m apart at 3.0 m, centred at (0.12, -0.30) m, along 81 deg``."""
        return (f"{self.grid[0]}x{self.grid[1]} pairs {self.spacing_m[0]:g} x {self.spacing_m[1]:g} m apart at "
                f"{self.height_m:g} m, centred at ({self.centre_xy[0]:.2f}, {self.centre_xy[1]:.2f}) m, along "
                f"{math.degrees(self.yaw_rad):.0f} deg")

    def to_dict(self) -> dict:
        return {"grid": list(self.grid), "centre_xy_m": list(self.centre_xy), "yaw_deg": math.degrees(self.yaw_rad),
                "spacing_m": list(self.spacing_m), "height_m": self.height_m, "margin_m": self.margin_m}


def survey_yaw(log_ends_xy: list[tuple[np.ndarray | None, np.ndarray | None]]) -> float:
    """The logs' mean direction [rad] from F's +x, from each log with both ends surveyed (``(a, b)``
    horizontal points; a None end is not surveyed): the long image side goes along the logs, as the
    twin's rig does. 0 when no log has both ends."""
    dirs = [np.asarray(b, float)[:2] - np.asarray(a, float)[:2] for a, b in log_ends_xy
            if a is not None and b is not None]
    dirs = [d / np.linalg.norm(d) for d in dirs if np.linalg.norm(d) > 1e-9]
    if not dirs:
        return 0.0
    v = np.array(dirs)
    v *= np.sign(v @ v[0])[:, None]
    m = v.mean(axis=0)
    return float(math.atan2(m[1], m[0]))


def plan_scan(points_xyz, sigma_h_m, yaw_rad: float, cfg: ScanPlanConfig | None = None) -> ScanPlan:
    """The smallest grid (along, across) of pairs ``cfg.spacing_*`` apart, turned ``yaw_rad``, whose
    footprint covers every point (frame F, ``z`` above the ground) grown by ``cfg.margin_m`` plus
    ``cfg.n_sigma`` times its horizontal sigma ``sigma_h_m`` (one per point, or one for all); never
    smaller than ``cfg.min_grid``. The grid is centred on what it must cover.

    No points, non-finite values or a point higher than the camera: :class:`ScanPlanError`. A survey
    spreading over more than ``cfg.max_pairs_per_side`` pairs: :class:`ScanPlanError` (a point far off)."""
    cfg = cfg or ScanPlanConfig()
    p = np.asarray(points_xyz, dtype=float)
    if p.ndim != 2 or p.shape[0] == 0 or p.shape[1] != 3:
        raise ScanPlanError(f"a scan plan needs surveyed end points as an (N, 3) array, N >= 1; got shape {p.shape}")
    sig = np.broadcast_to(np.asarray(sigma_h_m, dtype=float), (p.shape[0],))
    if not (np.isfinite(p).all() and np.isfinite(sig).all() and (sig >= 0).all() and math.isfinite(yaw_rad)):
        raise ScanPlanError("a scan plan needs finite end points, sigmas >= 0 and a finite yaw")
    if (p[:, 2] >= cfg.height_m - cfg.z_min_m).any():
        raise ScanPlanError(f"a surveyed end lies {p[:, 2].max():.2f} m above the ground: within {cfg.z_min_m} m of "
                            f"a camera at {cfg.height_m} m, nearer than stereo matching sees; scan from higher")
    probe = ScanPlan((1, 1), (0.0, 0.0), float(yaw_rad), (cfg.spacing_along_m, cfg.spacing_across_m),
                     cfg.height_m, cfg.margin_m)
    q = p[:, :2] @ probe.axes().T
    depth = cfg.height_m - np.maximum(p[:, 2], 0.0)
    grow = cfg.margin_m + cfg.n_sigma * sig
    lo_a, hi_a, lo_c, hi_c = cfg.footprint_slopes()
    grid, centre = [], []
    for k, (lo, hi, spacing) in enumerate(((lo_a, hi_a, cfg.spacing_along_m), (lo_c, hi_c, cfg.spacing_across_m))):
        # the grid's outermost cameras must reach past every grown point less what one pair sees at its depth
        need_hi = float(np.max(q[:, k] + grow - depth * hi))
        need_lo = float(np.min(q[:, k] - grow - depth * lo))
        n = max(cfg.min_grid[k], int(math.ceil(max(need_hi - need_lo, 0.0) / spacing - 1e-9)) + 1)
        if n > cfg.max_pairs_per_side:
            side = ("along", "across")[k]
            raise ScanPlanError(f"the surveyed ends spread {need_hi - need_lo + depth.min() * (hi - lo):.1f} m "
                                f"{side} the logs: {n} pairs, more than max_pairs_per_side "
                                f"{cfg.max_pairs_per_side}; check the survey for a point far off")
        grid.append(n)
        centre.append((need_hi + need_lo) / 2)
    centre_xy = np.array(centre) @ probe.axes()
    return ScanPlan((grid[0], grid[1]), (float(centre_xy[0]), float(centre_xy[1])), float(yaw_rad),
                    (cfg.spacing_along_m, cfg.spacing_across_m), cfg.height_m, cfg.margin_m)


def covering_plan_hint(endpoints: dict) -> str:
    """``: <plan> covers every surveyed end ...``: the scan plan (default camera) that would cover the
    surveyed ends, ``{log_id: (end_a, end_b)}`` in the site frame (each a point, an object with
    ``position_m`` and a per-axis ``sigma_h_m`` such as :class:`reconstruct.fitting.fuse.SurveyEnd`, or None),
    heights taken above the lowest end; empty when no plan covers them (the refusal stands alone). For a
    refusal's message: a point outside the scan names the scan that would see it."""
    pts, sig, pairs = [], [], []
    for ends in endpoints.values():
        pair = []
        for e in ends:
            p = None if e is None else np.asarray(getattr(e, "position_m", e), dtype=float)
            if p is not None:
                pts.append(p)
                sig.append(math.sqrt(2.0) * float(getattr(e, "sigma_h_m", 0.0)))
            pair.append(p)
        pairs.append(tuple(pair))
    if not pts:
        return ""
    xyz = np.array(pts)
    xyz[:, 2] -= xyz[:, 2].min()
    cfg = ScanPlanConfig()
    try:
        plan = plan_scan(xyz, np.array(sig), survey_yaw(pairs), cfg)
    except ScanPlanError:
        return ""
    return (f": {plan.describe().replace('centred at', 'centred at site E, N')} covers every surveyed end with "
            f"{cfg.margin_m:g} m and {cfg.n_sigma:g} sigma to spare (reconstruct.scan.plan; in the twin: "
            "loggrasp synth scan --pairs auto)")
