"""What the fitting of a pile (:mod:`reconstruct.fitting.fit`) is configured with, and what it reports:
:class:`FitConfig` (units in the field names and comments), :class:`LogFit` per log, :class:`PileFit`."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from reconstruct.fitting.clearance import ClearanceConfig
from synth.scene.pile import PileSpec

ENDPOINT_REFS = ("end_centre", "top_surface")
AXIS_SOURCES = ("fit", "gnss")

#: Revision of the fitting: raised whenever a change here makes different piles from the same scan, so
#: that kept reconstructions (``experiments.real_test``) are made again. What each revision changed and
#: why: docs/reconstruction.md, "Fitting revisions 1-22" (23: the obstacle stage, "One obstacle per body").
FIT_REVISION = 23


@dataclass(frozen=True)
class FitConfig:
    """How logs, terrain and obstacles are fitted to a scan (units in the names/comments)."""

    endpoint_ref: str = "end_centre"  # what the GNSS points are: "end_centre" or "top_surface"
    axis_source: str = "fit"  # final axis: "fit" (scan, GNSS for the ends) or "gnss"
    max_radius_m: float = 0.40  # largest log radius considered [m]
    min_radius_m: float = 0.015  # smallest log radius considered [m]
    axis_tolerance_m: float = 0.10  # how far the true axis may lie from the GNSS axis [m]
    end_margin_m: float = 0.08  # points this close to a GNSS end are not used [m]
    profile_tolerance_m: float = 0.01  # profile bins this close to a half-circle fit it [m]
    profile_bin_m: float = 0.01  # lateral bin of the cross-section profile; search step x2 [m]
    chunk_length_m: float = 0.5  # cross-section profiles are taken over this axial length [m]
    chunk_min_points: int = 20  # a chunk with fewer scan points gives no profile [-]
    chunk_min_circle_bins: int = 3  # a chunk's circle explains at least this many profile bins [-]
    chunk_line_band_m: float = 0.02  # chunk centres this close to the line through them agree with it
    #                                  (at least 2 profile_tolerance_m) [m]
    chunk_line_min_span_m: float = 0.2  # a line through chunk centres spans at least this along the log [m]
    min_survey_length_m: float = 0.1  # a log's two survey points at least this far apart [m]
    max_fit_evaluations: int = 60  # least-squares function evaluations per cylinder fit [-]
    top_surface_vertical_prior_weight: float = 0.1  # with top-surface points, the vertical tie to the survey
    #                                                 counts this much (the radius is not known a priori) [-]
    coverage_bin_m: float = 0.1  # a log's coverage: the share of bins this long holding fitted points [m]
    inlier_band_m: float = 0.015  # points within this of the surface are used by the 3-D fit [m]
    end_walk_band_m: float = 0.03  # where a log's end is looked for, points this close to another fitted
    #                                log's surface do not show this log's top (its fit error plus stereo
    #                                noise: at the fit's own band, half a neighbour's top stayed in the walk
    #                                and a log covered at its end ran on over it); they still show where the
    #                                scan sees below its top (points within inlier_band_m are left out) [m]
    max_borrowed_share: float = 0.5  # a log found in the scan alone with more of its surface points than this
    #                                  within end_walk_band_m of other logs is their tops, not a log [-]
    max_angle_deg: float = 60.0  # ... and at most this far round from the top (not the flanks,
    #                              where neighbours, ground and occluders meet the log) [deg]
    loss_scale_m: float = 0.01  # soft-L1 scale of the 3-D fit [m]
    gnss_sigma_m: float = 0.03  # prior sigma tying the fitted axis to the GNSS points [m]
    widen_search: bool = False  # search farther around imprecise (RTK float) ends; experimental
    fit_taper: bool = False  # fit a linear radius change along the log (weakly determined from
    #                           above: the taper trades off against the axis pitch; off by default)
    taper_min_m: float = 0.02  # smaller butt-top diameter differences give a cylinder [m]
    taper_min_coverage: float = 0.7  # a taper needs scan points over this share of the length [-]
    taper_section_m: float = 0.25  # a taper is judged from the radii of sections this long [m]
    taper_section_min_points: int = 20  # ... each of at least this many points [-]
    taper_min_significance: float = 3.0  # ... changing linearly by this many standard errors [-]
    max_taper_per_m: float = 0.2  # largest radius change along a fitted taper [m/m]
    widened_tolerance_max_m: float = 0.4  # widen_search: the axis tolerance at most [m]
    widened_chunk_length_m: float = 0.25  # ... its chunks at most this long [m]
    widened_reach_max_m: float = 0.5  # ... looking at most this far past an imprecise end [m]
    scan_end_percentile: float = 0.5  # widen_search: the scan's end of a log is this percentile of its
    #                                   fitted points along the axis (and 100 less it) [%]
    min_points: int = 60  # fewer inlier points than this: the log is not in the scan [-]
    max_points_per_log: int = 6000  # random subsample for the 3-D fit [-]
    log_clearance_m: float = 0.04  # points this close to a fitted log surface are log [m]
    terrain_log_pad_m: float = 0.10  # ... also this far past its ends, for the terrain [m]
    footprint_margin_m: float = 0.03  # ground points are this far outside log footprints [m]
    terrain_resolution: int = 64  # heightfield samples per side [-]
    ground_window_m: float = 1.0  # opening window; wider than any obstacle [m]
    ground_band_m: float = 0.06  # points within this above the opened surface are ground [m]
    obstacle_min_height_m: float = 0.08  # obstacle points lie this far above the ground [m]
    obstacle_flank_height_m: float = 0.03  # a found obstacle takes in the points connected to it
    #                                        at least this far above the ground (its flanks) [m]
    obstacle_flank_log_gap_m: float = 0.12  # ... but none this close to a log's footprint (stereo
    #                                         smears log edges down to the ground there) [m]
    dbscan_eps_m: float = 0.06  # open3d DBSCAN neighbourhood [m]
    dbscan_min_points: int = 10  # open3d DBSCAN core size [-]
    obstacle_min_points: int = 30  # smaller clusters (voxels) are noise [-]; 30 voxels of 2 cm
    #                                 = 0.012 m^2 of surface, a 6 cm disc
    obstacle_min_size_m: float = 0.12  # smaller clusters (horizontal extent) are noise [m]
    obstacle_voxel_m: float = 0.02  # obstacle points are voxel-downsampled to this first [m]
    obstacle_sliver_m: float = 0.08  # a cluster this close to a log's footprint and long along
    #                                  it is unexplained log surface, not an obstacle [m]
    obstacle_merge_gap_m: float = 0.45  # clusters this close with a log footprint between them
    #                                     are one obstacle (a log lying across it hides a band) [m]
    obstacle_join_gap_m: float = 0.06  # clusters whose top-view footprints touch or overlap within this
    #                                    are one body [m]: the cameras look down, so a part of a body cut off
    #                                    in height only (a stump's rim below its top, across the side wall
    #                                    stereo does not see) is 3-D apart but not apart across the ground;
    #                                    the DBSCAN neighbourhood (dbscan_eps_m), taken in top view
    obstacle_max_size_m: float = 2.0  # ... unless the joined body would be wider than this [m]: no stump
    #                                   (radius <= 0.35 m, roots <= 0.6 m) or rock (<= 1.3 m) of the twin is
    obstacle_log_tolerance_m: float = 0.06  # obstacle points within this of a fitted log's surface (radially,
    #                                         up to radius + this from its axis) are the log's, not obstacle
    #                                         evidence [m]: stereo smears a log's flanks by up to ~5 cm, and a
    #                                         log fitted 1-2 cm thin leaves its top that far above the fit
    obstacle_log_end_reach_m: float = 0.15  # ... also this far along its axis past each placed end [m]: an end
    #                                         placed short leaves the rest of the log there (every-end-fixed
    #                                         worst end p95 ~4 cm, blind ends ~10 cm)
    obstacle_min_top_m: float = 0.08  # an obstacle's top (TOP_PERCENTILE of its heights) stands at least
    #                                   this high above the fitted ground [m]. At the points' own threshold
    #                                   (obstacle_min_height_m), i.e. no further cut: 0.12 m removed the
    #                                   scan-edge scraps of one held-out scan but missed 7-9 low true rocks
    #                                   (and 0.10 m 5-6) on the held-out every-end-fixed scans
    #                                   (docs/reconstruction.md, "One obstacle per body")
    stump_flat_fraction: float = 0.3  # share of points in the top 4 cm for a stump [-]
    stump_max_circle_rms: float = 0.25  # circle-fit RMS of the top over its radius, stump [-]
    stump_min_aspect: float = 1.0  # a stump's height is at least this times its radius [-]
    stump_min_cover: float = 0.6  # a stump's top radius is at least this share of the cluster's
    #                               half extent (a rounded rock's top band is a small disc) [-]
    rock_max_vertices: int = 48  # convex hull vertices kept per rock [-]
    validate: bool = True  # load the pile into the twin and separate interpenetrating logs
    penetration_tolerance_m: float = 0.01  # allowed interpenetration [m]
    max_move_m: float = 0.08  # larger needed separating moves are an error, not noise [m]
    clearance: ClearanceConfig = field(default_factory=ClearanceConfig)  # a log the check refuses: its
    #                                  uncertain ends moved within their sigma first (reconstruct.fitting.clearance)
    roll_steps: int = 12  # rolls tried over the twin log prism's 72 deg period where a log interpenetrates
    #                       another body, before it is thinned or moved (the scan sees a round log: its
    #                       roll is unknown); 0: never turned [-]
    max_thinning_m: float = 0.0  # a log fitted to its scan points may be made this much thinner (radius),
    #                              its seen top kept, where it interpenetrates another body, before anything is
    #                              moved (the top the scan sees fixes the radius only to ~1.5 cm: thinning by
    #                              5 mm changes its top points' RMS residual by < 1 mm). Off (0): at 0.015 it
    #                              also thinned logs already too thin and let two wrong piles through [m]
    radius_window_m: float = 0.01  # the 3-D fit keeps the radius within this of the chunk profiles'
    #                                (robust, they see the flanks and the ground) [m]: from above, the top
    #                                strip alone hardly fixes the curvature, and one noisy scan let
    #                                the fit slide to 0.031 m for a 0.07 m log
    radius_profile_max_rms_rise: float = 0.10  # a 3-D fit ending on that window's edge takes the profiles'
    #                                radius when it explains the top points within this share of the fit's RMS
    #                                (twin stereo: 1.03, the top arc cannot tell; an exact top view: 1.32) [-]
    suspect_shift_m: float = 0.08  # a first fit whose axis lies this far from a GNSS point (~3 sigma
    #                                of RTK noise) took another surface, most likely (a log lying
    #                                under another): the refit gets only points no other log
    #                                explains, and a refit still astray the survey's axis [m]
    partial_loss_scale_m: float = 0.005  # soft-L1 scale of the circle through a partly seen log's top arc [m]
    seed: int = 0  # subsampling seed [-]

    def __post_init__(self) -> None:
        if not 0 <= self.radius_profile_max_rms_rise <= 1.0:
            raise ValueError(f"radius_profile_max_rms_rise must be in [0, 1], got {self.radius_profile_max_rms_rise}")
        if not 0 < self.radius_window_m <= 1.0:
            raise ValueError(f"radius_window_m must be in (0, 1] m, got {self.radius_window_m}")
        if self.endpoint_ref not in ENDPOINT_REFS:
            raise ValueError(f"endpoint_ref must be one of {ENDPOINT_REFS}, got {self.endpoint_ref!r}")
        if self.axis_source not in AXIS_SOURCES:
            raise ValueError(f"axis_source must be one of {AXIS_SOURCES}, got {self.axis_source!r}")
        if not 0 < self.min_radius_m < self.max_radius_m <= 1.0:
            raise ValueError("need 0 < min_radius_m < max_radius_m <= 1 m")
        for name in ("axis_tolerance_m", "profile_tolerance_m", "inlier_band_m", "end_walk_band_m",
                     "chunk_line_band_m", "chunk_line_min_span_m", "min_survey_length_m", "coverage_bin_m",
                     "taper_section_m", "taper_min_significance", "max_taper_per_m", "widened_tolerance_max_m",
                     "widened_chunk_length_m", "widened_reach_max_m", "top_surface_vertical_prior_weight",
                     "terrain_log_pad_m", "loss_scale_m", "partial_loss_scale_m",
                     "gnss_sigma_m", "log_clearance_m", "ground_window_m", "ground_band_m",
                     "obstacle_min_height_m", "dbscan_eps_m", "obstacle_min_size_m", "obstacle_voxel_m",
                     "obstacle_merge_gap_m", "obstacle_sliver_m", "obstacle_flank_height_m",
                     "obstacle_flank_log_gap_m", "obstacle_max_size_m", "obstacle_min_top_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.obstacle_join_gap_m < 0 or self.obstacle_log_tolerance_m < 0 or self.obstacle_log_end_reach_m < 0:
            raise ValueError("obstacle_join_gap_m, obstacle_log_tolerance_m and obstacle_log_end_reach_m must be >= 0")
        if self.obstacle_min_top_m < self.obstacle_min_height_m:
            raise ValueError(f"obstacle_min_top_m ({self.obstacle_min_top_m} m) must not be below "
                             f"obstacle_min_height_m ({self.obstacle_min_height_m} m)")
        if self.obstacle_flank_height_m > self.obstacle_min_height_m:
            raise ValueError(f"obstacle_flank_height_m ({self.obstacle_flank_height_m} m) must not exceed "
                             f"obstacle_min_height_m ({self.obstacle_min_height_m} m)")
        if self.end_margin_m < 0 or self.taper_min_m < 0 or self.max_move_m < 0 or self.max_thinning_m < 0:
            raise ValueError("end_margin_m, taper_min_m, max_move_m and max_thinning_m must be >= 0")
        if not 0.002 <= self.profile_bin_m <= 0.05:
            raise ValueError(f"profile_bin_m must be in [0.002, 0.05] m, got {self.profile_bin_m}")
        if self.roll_steps < 0:
            raise ValueError(f"roll_steps must be >= 0, got {self.roll_steps}")
        if not 0 < self.max_borrowed_share <= 1:
            raise ValueError(f"max_borrowed_share must be in (0, 1], got {self.max_borrowed_share}")
        if self.min_points < 10 or self.max_points_per_log < 100:
            raise ValueError("min_points >= 10, max_points_per_log >= 100 needed")
        if min(self.chunk_min_points, self.chunk_min_circle_bins, self.taper_section_min_points,
               self.max_fit_evaluations) < 1:
            raise ValueError("chunk_min_points, chunk_min_circle_bins, taper_section_min_points and "
                             "max_fit_evaluations must be >= 1")
        if not 0 <= self.scan_end_percentile < 50:
            raise ValueError(f"scan_end_percentile must be in [0, 50) %, got {self.scan_end_percentile}")
        if not 8 <= self.terrain_resolution <= 512:
            raise ValueError(f"terrain_resolution must be in [8, 512], got {self.terrain_resolution}")


@dataclass
class LogFit:
    """One fitted log and how well the scan supports it."""

    log_id: str
    index: int  # position in PileSpec.logs
    butt_m: tuple[float, float, float]  # pile frame [m]
    top_m: tuple[float, float, float]  # pile frame [m]
    length_m: float
    diameter_m: float  # butt diameter [m]
    top_diameter_m: float | None  # None: cylinder
    n_points: int  # inliers used by the 3-D fit [-]
    rms_m: float  # RMS of the inliers' distance to the fitted surface [m]
    coverage: float  # share of the length with scan points (10 cm bins) [-]
    gnss_residual_a_m: float  # distance of GNSS point a from the fitted axis [m]
    gnss_residual_b_m: float  # ... of point b [m]
    axis_shift_m: float  # largest move of the axis end from the GNSS point (perpendicular) [m]
    swapped: bool  # True when end "b" turned out to be the butt (the thicker end)
    moved_m: float = 0.0  # how far it was moved to separate it from other bodies [m]
    thinned_m: float = 0.0  # how much its radius was reduced, its seen top kept, to clear other bodies [m]
    end_source: tuple[str, str] = ("gnss", "gnss")  # butt, top: "gnss" point or "scan" extent; with the
    #                                                 survey fused (fit_pile's place_ends): scan, fixed, float, inferred
    ends: list[dict] | None = None  # ends a, b as placed (reconstruct.fitting.fuse.EndEstimate.to_dict), when fused
    radius_source: str = "fit"  # see CylinderFit.radius_source ("fit" also for partial and hidden logs)
    fit: str = "scan"  # "scan": fitted to its points; "partial": seen only in part, a circle through its
    #                    visible top near the survey's axis; "hidden": no points on it (under other logs),
    #                    the survey's axis, as thick as the gap between the ground and the logs over it

    @property
    def mean_diameter_m(self) -> float:
        return 0.5 * (self.diameter_m + (self.diameter_m if self.top_diameter_m is None else self.top_diameter_m))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["mean_diameter_m"] = self.mean_diameter_m
        return d


@dataclass
class PileFit:
    """The fitted pile and its report."""

    pile: PileSpec
    logs: list[LogFit]
    terrain_coverage: float  # share of terrain cells with ground points [-]
    n_ground_points: int
    n_obstacle_points: int
    obstacles: list[dict] = field(default_factory=list)  # kind, position, size, n_points
    moves: list[str] = field(default_factory=list)  # what the validation moved
    end_moves: list[str] = field(default_factory=list)  # ends the validation moved within their uncertainty
    timings_s: dict = field(default_factory=dict)
    dropped: dict = field(default_factory=dict)  # optional logs left out: {log id: why}
