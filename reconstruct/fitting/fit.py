"""Model fitting: a scan point cloud plus GNSS log end points become a :class:`PileSpec`.

Everything here works in ONE frame, the *pile frame* of the pile being built (metres, z up, origin
at the centre of the terrain patch; see :mod:`synth.scene.pile`). :mod:`reconstruct.pipeline` moves the
scan and the endpoints into that frame first.

Logs
----
The two RTK points of a log give its axis and length (:func:`fit_pile` is given where to look for each
log: with :mod:`reconstruct.pipeline` the scan's own axis of the log, its ends placed afterwards from
the scan and the survey by their accuracies, :mod:`reconstruct.fitting.fuse`). What the points are is a parameter
(``FitConfig.endpoint_ref``):

* ``"end_centre"`` (default): the rover pole stood on the centre of each end face — the points
  lie ON the axis (this is what :func:`reconstruct.survey.gnss.simulate_survey` measures);
* ``"top_surface"``: the points were taken on top of the log at each end — the axis lies one
  radius below them (perpendicular to the axis, in the vertical plane through it).

RTK noise (1.5 cm horizontal, 2.5 cm vertical, 1 sigma) is larger than the diameter accuracy
wanted (1 cm), so the GNSS axis is only the *start* of the fit:

1. the scan points around the GNSS axis are cut into ``chunk_length_m`` chunks; each chunk's
   visible cross-section profile gets the upper half-circle that explains it best (an exhaustive
   search with a visibility test: nothing can be seen *below* a log's top inside its
   footprint), with its centre within ``axis_tolerance_m`` of the GNSS axis; a line through the
   chunk centres is the initial axis — robust to neighbouring logs, ground and obstacles;
2. a cylinder (or a truncated cone, ``fit_taper``) is fitted to the inliers in 3-D by robust
   least squares (scipy ``least_squares``, soft-L1 loss): axis position and direction, radius
   and radius slope, with a weak prior tying the axis to the GNSS points, on the points within
   ``max_angle_deg`` of the top (selected by angle, which does not bias the radius); this is
   done twice: the second time every point belongs only to the log whose first-pass surface
   it lies on;
3. the log's ends are the GNSS points projected onto the fitted axis (``axis_source="fit"``)
   or the GNSS axis itself (``axis_source="gnss"``). The distance between each GNSS point and
   the fitted axis is reported as that point's residual.

A log seen only in part (its fits stray from its GNSS axis, or lie inside a neighbour) gets a
circle through its visible top arc whose centre stays within two ``gnss_sigma_m`` of the survey's
axis (a shift and a tilt), its radius at most the room its neighbours leave plus one sigma
(``LogFit.fit == "partial"``). A log with no scan points on it but scan points standing over it
lies hidden under others: it is placed on its survey axis, as thick as the gap between the
ground and the logs over it (or the pile's typical diameter within the room left), and reported
as ``"hidden"``. A log with no points and nothing over it is an error (:class:`LogNotSeenError`).

Logs are indexed by the natural order of their ids (``log2`` before ``log10``), whatever the
order of the survey rows.

Terrain, obstacles
------------------
Points not explained by a log (farther than ``log_clearance_m`` from every fitted log surface)
are ground or obstacles. The ground is the grey-scale *opening* of the per-cell lowest points
(window ``ground_window_m``, wider than the obstacles) followed by the median of the points near
that surface, on the :class:`TerrainSpec` grid; holes are filled (OpenCV ``inpaint``, Telea);
the unseen ground under a log is lowered to the log's underside where needed (between the grid
samples too: the twin's terrain is linear over each cell). Points more than
``obstacle_min_height_m`` above the ground are clustered with open3d's DBSCAN; each cluster then
takes in the lower points (``obstacle_flank_height_m`` and up) connected to it, so a half-buried
rock is sized by its footprint and not only by the cap above the threshold. Cluster points over
a log's footprint higher than its underside are the log's (stereo smear at a stack of log ends)
and are dropped, and a stump is no taller than the lowest log underside over it. A cluster with a
flat, circular top at least its radius high, covering the cluster, is a stump (:class:`StumpSpec`, no roots: they are
not visible), any other a rock (:class:`RockSpec`, the convex hull of its points extended down
into the ground).

The assembled pile is loaded into the twin (:func:`synth.scene.generate.validate_pile`-style check).
Where logs interpenetrate, each is first turned about its own axis (the twin's log collides as a
pentagonal prism inside the round surface the scan sees, so its roll is not known); a log fitted to its
scan points may then be made thinner with its top kept, as far as its radius is uncertain (the scan sees its
top, and of two stacked logs an overlap is the upper one's radius error; ``max_thinning_m``, off by
default: measured, it thinned logs already too thin); what is left is moved out
along the contact normal by the penetration depth (lifted when stacked, pushed apart when side by
side). Every turn, thinning and move is reported.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Callable, Collection, Mapping, Sequence

import numpy as np

from reconstruct.errors import FitError, LogNotSeenError, SeparationError
from reconstruct.fitting.clearance import ClearanceConfig, clear_pile
from synth.scene.pile import LogSpec, PileSpec, RockSpec, StumpSpec, TerrainSpec

ENDPOINT_REFS = ("end_centre", "top_surface")
AXIS_SOURCES = ("fit", "gnss")

#: Revision of the fitting: raised whenever a change here makes different piles from the same
#: scan, so that kept reconstructions (``experiments.real_test``) are made again. 2: the terrain under a
#: log is held under its round underside between the grid samples too (:func:`_clamp_under_logs`).
#: 3: obstacle points over a log's footprint above its underside are the log's; a refit that
#: strays keeps the first fit; logs hidden under others are placed from their survey. 4: a log
#: seen only in part gets a circle through its top arc (axis within two sigma of the survey's)
#: instead of the lower quartile of distances from the survey's axis (diameters 7.5 cm too small).
#: 5: logs are fitted around the scan's own axes (:mod:`reconstruct.fitting.fuse`), their ends placed from the
#: scan where it sees them and from the survey where it does not, by their accuracies. 6: a seen end is the
#: middle of the last bin on the log's top, not that bin's outer edge (+9 mm outward on twin scans); the
#: registration walks a log's end over the points on no other log, as the ends' placement does. 7: a
#: cross-section circle pays for the part of its footprint it does not explain (a log with a neighbour
#: against its side was fitted up to 2-3.5 cm too thick); two logs side by side that interpenetrate are
#: each pushed half the way apart (only the upper one was moved). 8: a log's ends are walked over the
#: points farther than ``FitConfig.end_walk_band_m`` (3 cm, was the fit's 1.5 cm band) from every other
#: log (a neighbour's top at the height of a covered end's extension made it run on past its fixed point);
#: a log found in the scan alone that has no points of its own once the others took theirs is left out
#: (``fit_pile(optional=...)``); a matching that calls more survey points wrong is no ambiguity; on a log
#: seen only in part an RTK fixed point places a covered or open end, and the log is thinned to the room
#: around its placed ends. 9: the points near another log (within ``end_walk_band_m``, not within
#: ``inlier_band_m``) do not show a log's top but still show where the scan sees below it (at 8, logs the
#: survey missed lost their 'seen' end where they touched a neighbour: 1.9 -> 10.8 cm, 2.3 -> 15.5 cm).
#: 10: a 3-D fit whose radius ends on the edge of ``radius_window_m`` about the chunk profiles' takes the
#: profiles' radius and fits only the axis when that explains the top points about as well
#: (``radius_profile_max_rms_rise``; a 20 cm log came out 18 or 19 cm, by which 2.5 mm grid step the
#: profiles took; ``LogFit.radius_source``); the ground plane of a coarse registration is found by a
#: seeded RANSAC of our own (open3d's gave another plane from run to run).
#: 11: the pile check first turns a log about its axis (the twin's log is a pentagonal prism, which the
#: scan cannot see the roll of: a true pile rebuilt from its end points was lifted up to 4.7 cm), and
#: only then moves what is left (``separate_logs``; thinning a scan-fitted log with its top kept,
#: ``max_thinning_m``, is there but off); the ends are reported where the checked pile has them, their
#: survey points tested again there and their sigma grown by the check's move
#: (:func:`reconstruct.fitting.fuse.after_pile_check`: a log pushed off its fixed points is a weak,
#: contradicted estimate, never a silent one — twin scan 1100133 at 4042e48 came back 40 cm off unwarned);
#: an end the scan shows nothing of is placed across the axis by its survey point too, and a point
#: beyond noise from the extrapolated axis places it (that 40 cm end had been left on a partial fit's
#: axis, 9 deg off, unchecked); a ridge on the line of a log's two fixed points, not above it, is that
#: log, not an ambiguity with "hidden" (1100133 stopped so under all three surveys); a log found in the
#: scan alone whose surface points lie mostly on other logs (``max_borrowed_share``) is left out.
#: 12: a match that calls one of two survey points wrong needs the other within reach of the scan log
#: (a crossing scrap took a log of two fixed points, 1100084); a seen end of a tip in the air (ground seen
#: ``overhang_gap_m`` under its underside) only bounds the end from inside for a precise point beyond it
#: within ``end_search_m``, or any point past what the scan covers (stereo loses a thin tip the cameras see
#: under: 1100085, all three surveys 15 cm short; 1100032 and 1100089 75 cm, their points past the scan's).
#: 13: a tip is in the air where the ground is seen ``overhang_gap_m`` = 5 cm (was 10) under its underside:
#: 1100051's log 5 lies 8-12 cm over the ground, its top seen 6-28 cm short of its fixed points.
#: 14: a log the pile check refuses has its uncertain ends moved within their sigma first, and a
#: contradicted end tried at its survey point (:mod:`reconstruct.fitting.clearance`): float ends under
#: other logs (1100119, 1100129) and a scan walk over a stump past a fixed point (1100166, 1100179) failed;
#: a log found in the scan alone whose ends cannot be placed is left out (1100119, every end fixed); of two
#: scan logs a surveyed log fits about as well, the one that leaves fewer ridges unsurveyed is its log
#: (:func:`reconstruct.fitting.fuse.match_survey`; 1100182, 1100193 and four degraded surveys stopped); a
#: surveyed log whose refit on the points the others leave it fits no cylinder keeps its first fit (1100198).
#: 15: a precise survey point on a log's axis line past all the scan covers places the end beyond a
#: seen one (:func:`reconstruct.fitting.fuse.fuse_end`; 1100189: a log 97 cm short under every survey).
#: 16: a ridge running on well past a fixed end is as costly as a wrong point but calls none wrong, so a
#: scrap beside that end is no better match (1100166 degraded); a log seen only in part is no thicker
#: than the thickest log the scan shows whole (1100069 degraded: 23 cm too thick).
#: 17: a run on the log's top at most 4 cm long past 20 cm with none is a neighbour's flank, not its end
#: (:func:`reconstruct.fitting.fuse.scan_end_interval`; 1100052: a log 31 cm too long under every survey).
#: 18: of two logs side by side the scan shows as one ridge, the one with a float point takes it and the
#: one with both points RTK fixed is the hidden one (:func:`reconstruct.fitting.fuse.match_survey`; real-test
#: scans 700074, 700114 stopped as ambiguous).
#: 19: a fixed point well across a scan-fitted axis is contradicted (reported; the pile check may then try the
#: end at it) (:func:`reconstruct.fitting.fuse._off_the_fitted_axis`; real-test scan 700085).
#: 20: a scan log seen over less than half the distance between a log's two precise survey points is a
#: piece: the points set the log's prior axis (:func:`reconstruct.fitting.fuse.prior_axis`; real-test scan
#: 700414: a 35 cm piece tilted a log 9 deg, 41 cm off its fixed point); past the end of a log running down
#: outward, level ground is not its top (:func:`reconstruct.fitting.fuse.scan_end_interval`; 700414: an end
#: placed 59 cm past its fixed point, on the ground the extended top dived into).
#: 21: such a piece's log is placed seen in part, on those points' axis (``fit_pile(in_part=...)``), not fitted
#: as seen whole on the piece; the first bin where the walk sees below a log's top is the first of two in a
#: row (one bin seen through between logs over it does not end it: twin scan 1100028 fixed, an end 72 cm
#: short, its fixed point called wrong) (:func:`reconstruct.fitting.fuse.scan_end_interval`).
#: 22: revisions 20-21 on the 200-scan bench changed 47 of its first 156 conditions, some for the worse (a
#: fixed-survey log 0.7 -> 4.8 cm seen in part on a piece in line with its points; a degraded end 3.9 -> 7.8 cm
#: where a single bin below was the end): a piece is the log seen in part only when one of the points lies
#: more than ``piece_off_m`` (10 cm) off the piece's line, and a bin below is skipped only alone inside a
#: stretch over the log (:func:`reconstruct.fitting.fuse._first_below`).
FIT_REVISION = 22
# a cross-section circle loses this much score per footprint bin it does not explain (the profile
# there lies above it or off it): where a neighbour lies against a log, or the stereo fills the
# valley between them, that side shows no edge, and without this a wider circle, centred toward
# the neighbour, explained as many bins as the true one [-]
PROFILE_UNSEEN_WEIGHT = 0.5
# a 3-D fit's radius this close to its window's edge is on it (the bound is active) [m]
RADIUS_EDGE_M = 1e-4
# a contact between two logs whose normal is at least this horizontal (squared horizontal part of the
# unit normal; 0.5: within 45 deg of horizontal) is side by side: both are pushed apart [-]
SIDE_CONTACT_MIN_H2 = 0.5
# a log is thinned to clear a contact only where that takes at least this much depth per unit of radius
# (1 + the contact normal's part along its up-across direction: 2 lying on the other, 1 beside it, 0
# under it, where its top, kept, is what meets the other) [-]
MIN_THINNING_GAIN = 0.5
# a log is turned about its axis to clear its contacts at most this many times (the turns of two logs
# in contact could otherwise undo each other) [-]
MAX_ROLLS_PER_LOG = 2


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
                     "terrain_log_pad_m", "loss_scale_m",
                     "gnss_sigma_m", "log_clearance_m", "ground_window_m", "ground_band_m",
                     "obstacle_min_height_m", "dbscan_eps_m", "obstacle_min_size_m", "obstacle_voxel_m",
                     "obstacle_merge_gap_m", "obstacle_sliver_m", "obstacle_flank_height_m",
                     "obstacle_flank_log_gap_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
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


# -- helpers ---------------------------------------------------------------------------------
def natural_key(log_id: str) -> tuple:
    """Sort key putting ``log2`` before ``log10``."""
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(log_id)))


def _frame(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``u``: e1 horizontal, e2 'up-ish'."""
    e1 = np.cross((0.0, 0.0, 1.0), u)
    if np.linalg.norm(e1) < 1e-6:  # vertical axis
        e1 = np.cross((1.0, 0.0, 0.0), u)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return e1, e2


def _circles_from_triples(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Circumcircles of (K, 3, 2) point triples: centres (K, 2) and radii (K,); NaN if collinear."""
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    d = 2 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    a2, b2, c2 = (a * a).sum(1), (b * b).sum(1), (c * c).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (a2 * (b[:, 1] - c[:, 1]) + b2 * (c[:, 1] - a[:, 1]) + c2 * (a[:, 1] - b[:, 1])) / d
        uy = (a2 * (c[:, 0] - b[:, 0]) + b2 * (a[:, 0] - c[:, 0]) + c2 * (b[:, 0] - a[:, 0])) / d
    centre = np.stack([ux, uy], axis=1)
    r = np.linalg.norm(a - centre, axis=1)
    return centre, r


def _profile_circle(sw: np.ndarray, prior_centre: np.ndarray, cfg: FitConfig,
                    ) -> tuple[np.ndarray, float, int]:
    """Best upper half-circle (centre (2,), radius, bins explained) for one axial chunk.

    ``sw``: points in cross-section coordinates (s horizontal across the axis, w up-ish). Seen
    from above, every lateral position ``s`` shows ONE surface along a short straight chunk, so
    the chunk is reduced to its visible profile (the median ``w`` per ``profile_bin_m`` bin). An
    exhaustive search over centre offset and radius then scores each upper half-circle by the
    bins it explains minus three times the bins that lie clearly BELOW it inside its footprint
    (impossible: ground beside a too-wide circle, points inside the log), less
    ``PROFILE_UNSEEN_WEIGHT`` for each other footprint bin (above it: an occluder, or a neighbour
    over its flank; it may be there, but nothing shows it, so of two circles that explain as much the
    one that claims less unseen width wins). Robust to neighbouring logs, the ground and obstacles.
    """
    step = cfg.profile_bin_m
    reach = cfg.max_radius_m + cfg.axis_tolerance_m + abs(float(prior_centre[0]))
    nb = int(np.ceil(2 * reach / step))
    idx = np.floor((sw[:, 0] + reach) / step).astype(np.int64)
    ok = (idx >= 0) & (idx < nb)
    idx, w = idx[ok], sw[ok, 1]
    order = np.lexsort((w, idx))
    idx, w = idx[order], w[order]
    starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
    ends = np.r_[starts[1:], len(idx)]
    counts = ends - starts
    good = counts >= 3
    if good.sum() < 4:
        raise FitError("too few profile bins")
    bins = idx[starts[good]]
    wb = w[(starts[good] + ends[good] - 1) // 2]  # per-bin median (sorted within a bin)
    sb = -reach + (bins + 0.5) * step
    tol = cfg.profile_tolerance_m
    cs = prior_centre[0] + np.arange(-cfg.axis_tolerance_m, cfg.axis_tolerance_m + 1e-9, step / 2)
    rs = np.arange(cfg.min_radius_m, cfg.max_radius_m + 1e-9, step / 2)
    C, R = np.meshgrid(cs, rs, indexing="ij")
    C, R = C.ravel(), R.ravel()
    ds = sb[None, :] - C[:, None]
    fp = np.abs(ds) < R[:, None] - step / 2
    sq = np.sqrt(np.clip(R[:, None] ** 2 - ds ** 2, 0.0, None))
    cw = _row_medians(wb[None, :] - sq, fp)
    valid = np.isfinite(cw) & (np.abs(cw - prior_centre[1]) <= cfg.axis_tolerance_m)
    if not valid.any():
        raise FitError("no half-circle near the axis")
    e = wb[None, :] - (cw[:, None] + sq)
    rad = np.hypot(ds, wb[None, :] - cw[:, None]) - R[:, None]
    upper = wb[None, :] > cw[:, None] - tol  # the visible (upper) half only
    on = fp & upper & ((np.abs(e) < tol) | (np.abs(rad) < tol))
    below = fp & (e < -2 * tol) & ~(upper & (np.abs(rad) < tol))
    unseen = fp & ~on & ~below  # footprint bins the circle does not explain: above it, or off it
    score = np.where(valid, on.sum(axis=1) - 3 * below.sum(axis=1) - PROFILE_UNSEEN_WEIGHT * unseen.sum(axis=1),
                     -10**9)
    best = int(np.argmax(score))
    return np.array([C[best], cw[best]]), float(R[best]), int(on[best].sum())


def _row_medians(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Median of each row's ``values`` where ``mask`` holds (NaN for an empty row): what
    ``np.nanmedian`` gives on the masked-out values set to NaN, without its slow masked-array path."""
    v = np.where(mask, values, np.inf)
    v.sort(axis=1)
    n = mask.sum(axis=1)
    rows = np.arange(len(v))
    lo = v[rows, np.maximum((n - 1) // 2, 0)]
    hi = v[rows, np.maximum(n // 2, 0)]
    out = 0.5 * (lo + hi)
    out[n == 0] = np.nan
    return out


@dataclass(frozen=True)
class CylinderFit:
    """One log fitted to the scan (:func:`fit_log`, :func:`fit_radius_on_axis`), pile frame."""

    centre: np.ndarray  # (3,) a point on the fitted axis [m]
    axis: np.ndarray  # (3,) unit axis direction, end a -> end b [-]
    ends: np.ndarray  # (2, 3) ends a, b: the survey points projected on the fitted axis (or the survey's) [m]
    radius_a_m: float  # radius at end a [m]
    radius_b_m: float  # ... at end b [m]
    n_points: int  # scan points on the fitted surface [-]
    rms_m: float  # their RMS distance from it [m]
    coverage: float  # share of 10 cm bins along the log holding such points [-]
    residual_a_m: float  # survey point a -> its projection on the fitted axis [m]
    residual_b_m: float  # ... point b [m]
    end_source: tuple[str, str] = ("gnss", "gnss")  # what placed each end: "gnss" or "scan"
    taper_significance: float = 0.0  # fitted taper over its standard error [-]
    radius_source: str = "fit"  # "fit": the 3-D fit's; "profiles": the cross-section profiles' (the fit
    #                             ended on the edge of FitConfig.radius_window_m about them)
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # indices into the points

    def with_ends(self, ends: np.ndarray) -> "CylinderFit":
        return replace(self, ends=np.asarray(ends, dtype=np.float64))


@dataclass(frozen=True)
class _SearchRegion:
    """Where :func:`fit_log` looks for a log: the survey's axis a -> b, its frame, the scan points near it."""

    a: np.ndarray  # (3,) end a [m]
    b: np.ndarray  # (3,) end b [m]
    length_m: float  # |b - a| [m]
    u0: np.ndarray  # unit survey axis [-]
    e1: np.ndarray  # cross-section frame: horizontal-ish [-]
    e2: np.ndarray  # ... up-ish [-]
    t: np.ndarray  # every point's place along the axis from a [m]
    cand: np.ndarray  # indices of the points near the axis
    sw: np.ndarray  # (len(cand), 2) their cross-section coordinates [m]
    cfg: FitConfig  # the config in use (widened around imprecise ends)
    cfg_r: FitConfig  # ... with the cross-section search tolerance for the endpoint reference
    tol0_m: float  # the configured axis tolerance [m]
    sig_a_m: float  # survey accuracy of end a [m]
    sig_b_m: float  # ... end b [m]
    ext_a_m: float  # how far the search looks past end a (imprecise end) [m]
    ext_b_m: float  # ... past end b [m]
    prior: np.ndarray  # (2,) prior circle centre in the cross-section [m]


@dataclass(frozen=True)
class _Cylinder:
    """The least-squares cylinder of :func:`fit_log` (parameters about the axis midpoint)."""

    x: np.ndarray  # [shift e1, shift e2, tilt e1, tilt e2, radius, radius slope]
    sel: np.ndarray  # indices of the points on its surface
    centre: np.ndarray  # (3,) [m]
    u: np.ndarray  # (3,) unit axis [-]
    res: np.ndarray  # the selected points' distances from its surface [m]
    radius_source: str = "fit"  # "fit", or "profiles" where the fit ended on the radius window's edge


def _search_region(points: np.ndarray, end_a: Any, end_b: Any, cfg: FitConfig, log_id: str,
                   sigma_a_m: float | None, sigma_b_m: float | None) -> tuple[np.ndarray, _SearchRegion]:
    """The points (as float64) and where to look for the log among them."""
    a, b = np.asarray(end_a, dtype=np.float64), np.asarray(end_b, dtype=np.float64)
    L = float(np.linalg.norm(b - a))
    if L < cfg.min_survey_length_m:
        raise FitError(f"log {log_id!r}: its two GNSS points are only {L * 100:.1f} cm apart; "
                       "check that they are the two ends of one log")
    u0 = (b - a) / L
    e1, e2 = _frame(u0)
    P = np.asarray(points, dtype=np.float64)
    rel = P - a
    t = rel @ u0
    q = rel - np.outer(t, u0)
    sig_a = cfg.gnss_sigma_m if sigma_a_m is None or not np.isfinite(sigma_a_m) else max(float(sigma_a_m), 1e-3)
    sig_b = cfg.gnss_sigma_m if sigma_b_m is None or not np.isfinite(sigma_b_m) else max(float(sigma_b_m), 1e-3)
    tol0 = cfg.axis_tolerance_m
    if cfg.widen_search and max(sig_a, sig_b) * 3 > tol0:  # imprecise ends: search wider, shorter chunks
        cfg = replace(cfg, axis_tolerance_m=min(cfg.widened_tolerance_max_m, 3 * max(sig_a, sig_b)),
                      chunk_length_m=min(cfg.chunk_length_m, cfg.widened_chunk_length_m))
    # look past an imprecise end (its position along the axis then comes from the scan)
    ext_a = min(3 * sig_a, cfg.widened_reach_max_m) if cfg.widen_search and sig_a > 2 * cfg.gnss_sigma_m else 0.0
    ext_b = min(3 * sig_b, cfg.widened_reach_max_m) if cfg.widen_search and sig_b > 2 * cfg.gnss_sigma_m else 0.0
    near = (t > cfg.end_margin_m - ext_a) & (t < L - cfg.end_margin_m + ext_b)
    near &= np.einsum("ij,ij->i", q, q) < (cfg.max_radius_m + cfg.axis_tolerance_m) ** 2
    cand = np.flatnonzero(near)
    if cand.size < cfg.min_points:
        raise FitError(
            f"log {log_id!r}: only {cand.size} scan points within "
            f"{cfg.max_radius_m + cfg.axis_tolerance_m:.2f} m of the axis between its GNSS points "
            f"a={np.round(a, 2).tolist()} and b={np.round(b, 2).tolist()} (pile frame, m); the log "
            "is outside the scanned area, or its endpoints are wrong (wrong log id, swapped points)"
        )
    sw = np.stack([q[cand] @ e1, q[cand] @ e2], axis=1)
    # prior circle centre in the cross-section: on the axis, or one radius below (top_surface)
    prior = np.zeros(2)
    if cfg.endpoint_ref == "top_surface":
        prior = np.array([0.0, -0.5 * (cfg.min_radius_m + cfg.max_radius_m)])
        tol = cfg.axis_tolerance_m + 0.5 * (cfg.max_radius_m - cfg.min_radius_m)
        cfg_r = replace(cfg, axis_tolerance_m=tol)
    else:
        cfg_r = cfg
    return P, _SearchRegion(a, b, L, u0, e1, e2, t, cand, sw, cfg, cfg_r, tol0, sig_a, sig_b, ext_a, ext_b, prior)


def _chunk_circles(s: _SearchRegion, log_id: str) -> np.ndarray:
    """Half-circle profiles in axial chunks (the survey's axis direction is off by up to a few cm over
    the length, which would smear one cross-section of the whole log): rows of (place along the axis
    about its middle [m], centre e1 [m], centre e2 [m], radius [m], weight [1/m^2])."""
    cfg, cfg_r, L = s.cfg, s.cfg_r, s.length_m
    tc = s.t[s.cand]
    n_chunks = max(1, int((L - 2 * cfg.end_margin_m) // cfg.chunk_length_m))
    edges = np.linspace(cfg.end_margin_m, L - cfg.end_margin_m, n_chunks + 1)
    chunk = []
    for k in range(n_chunks):
        m = (tc >= edges[k]) & (tc < edges[k + 1])
        if m.sum() < cfg.chunk_min_points:
            continue
        # the search around the GNSS axis is as wide as the axis is uncertain THERE: tight near a
        # precise end, wide near an imprecise one
        f = 0.5 * (edges[k] + edges[k + 1]) / L
        tol_k = float(np.clip(3 * (s.sig_a_m + (s.sig_b_m - s.sig_a_m) * f), s.tol0_m, cfg.axis_tolerance_m))
        try:
            c2, rk, n_on = _profile_circle(s.sw[m], s.prior, replace(cfg_r, axis_tolerance_m=tol_k + (
                cfg_r.axis_tolerance_m - cfg.axis_tolerance_m)))
        except FitError:
            continue
        if n_on >= cfg.chunk_min_circle_bins:
            chunk.append((0.5 * (edges[k] + edges[k + 1]) - L / 2, c2[0], c2[1], rk, n_on / tol_k ** 2))
    if not chunk:
        raise FitError(f"log {log_id!r}: no cylinder of radius {cfg.min_radius_m}-{cfg.max_radius_m} m "
                       "near its GNSS axis fits the scan; the log is hidden, outside the scanned area, "
                       "or its endpoints are wrong")
    return np.asarray(chunk, dtype=np.float64)


def _initial_axis(ch: np.ndarray, s: _SearchRegion) -> np.ndarray:
    """A line through the chunk centres (robust where an end is imprecise): the cylinder's start
    parameters [shift e1, shift e2, tilt e1, tilt e2, radius, radius slope]."""
    cfg = s.cfg
    band = max(cfg.chunk_line_band_m, 2 * cfg.profile_tolerance_m)
    keep = np.ones(len(ch), bool)
    if len(ch) >= 3 and max(s.sig_a_m, s.sig_b_m) > 2 * cfg.gnss_sigma_m:
        # an imprecise (RTK float) end: the line through two chunk centres that most chunks
        # (weighted) agree with, so chunks that latched onto a neighbour or the ground near the
        # imprecise end do not bend the axis
        best_score = -1.0
        for i in range(len(ch)):
            for j in range(i + 1, len(ch)):
                dt_ = ch[j, 0] - ch[i, 0]
                if abs(dt_) < cfg.chunk_line_min_span_m:
                    continue
                slope = (ch[j, 1:3] - ch[i, 1:3]) / dt_
                pred = ch[i, 1:3][None, :] + np.outer(ch[:, 0] - ch[i, 0], slope)
                ok = np.linalg.norm(ch[:, 1:3] - pred, axis=1) < band
                score = float(ch[ok, 4].sum())
                if score > best_score:
                    best_score, keep = score, ok
    coef = np.zeros((2, 2))  # [s0, s1], [w0, w1]
    for _ in range(3):
        if keep.sum() >= 2 and np.ptp(ch[keep, 0]) > cfg.chunk_line_min_span_m:
            A = np.column_stack([np.ones(keep.sum()), ch[keep, 0]])
            wts = np.sqrt(ch[keep, 4])
            for j, col in enumerate((1, 2)):
                coef[j], *_ = np.linalg.lstsq(A * wts[:, None], ch[keep, col] * wts, rcond=None)
        else:
            coef[:, 0] = np.median(ch[keep, 1:3], axis=0)
            coef[:, 1] = 0.0
        pred = coef[:, 0][None, :] + np.outer(ch[:, 0], coef[:, 1])
        dev = np.linalg.norm(ch[:, 1:3] - pred, axis=1)
        new_keep = dev < band
        if new_keep.sum() == 0 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    r0 = float(np.median(ch[keep, 3])) if keep.any() else float(np.median(ch[:, 3]))
    return np.array([coef[0, 0], coef[1, 0], coef[0, 1], coef[1, 1], r0, 0.0])


class _CylinderModel:
    """The cylinder of :func:`_fit_cylinder` about the survey axis' midpoint: parameters
    [shift e1, shift e2, tilt e1, tilt e2, radius, radius slope], the points on its visible top, and
    its residuals (distances from the surface, then the weak ties of its ends to the survey)."""

    def __init__(self, P: np.ndarray, s: _SearchRegion):
        self.s, self.cfg, self.L = s, s.cfg, s.length_m
        self.mid = s.a + s.u0 * (s.length_m / 2)
        self.prior_mid = np.array([s.prior[0], s.prior[1]])
        self.P, self.Pc = P, P[s.cand]
        cfg = s.cfg
        self.w_a, self.w_b = cfg.loss_scale_m / s.sig_a_m, cfg.loss_scale_m / s.sig_b_m
        self.vertical = cfg.top_surface_vertical_prior_weight if cfg.endpoint_ref == "top_surface" else 1.0

    def axis(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = self.s
        u = s.u0 + x[2] * s.e1 + x[3] * s.e2
        return x[0] * s.e1 + x[1] * s.e2, u / np.linalg.norm(u)

    def select(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Candidates on the visible top of cylinder ``x``, away from its flanks."""
        cfg = self.cfg
        c, u = self.axis(x)
        f1, f2 = _frame(u)
        d = self.Pc - (self.mid + c)
        tt = d @ u
        perp = d - np.outer(tt, u)
        rad = np.linalg.norm(perp, axis=1)
        # select by the angle from the top (tangential: unlike a cut on the lateral offset it
        # does not correlate with the radial noise, so it does not bias the radius)
        ang = np.arctan2(np.abs(perp @ f1), perp @ f2)
        ok = (np.abs(rad - (x[4] + x[5] * tt)) < cfg.inlier_band_m) & (ang < math.radians(cfg.max_angle_deg))
        out = self.s.cand[ok]
        if out.size > cfg.max_points_per_log:
            out = rng.choice(out, cfg.max_points_per_log, replace=False)
        return out

    def residuals(self, x: np.ndarray, Pm: np.ndarray) -> np.ndarray:
        c, u = self.axis(x)
        d = Pm - c
        tt = d @ u
        rad = np.linalg.norm(d - np.outer(tt, u), axis=1)
        # weak prior: the GNSS axis (ends at +-L/2) within each end's sigma; tilt priors at the ends
        h, pm, wa, wb = self.L / 2, self.prior_mid, self.w_a, self.w_b
        end_off = np.array([wb * (x[0] - pm[0] + x[2] * h), wb * (x[1] - pm[1] + x[3] * h),
                            wa * (x[0] - pm[0] - x[2] * h), wa * (x[1] - pm[1] - x[3] * h)])
        end_off[[1, 3]] *= self.vertical
        return np.concatenate([rad - (x[4] + x[5] * tt), end_off])

    def jacobian(self, x: np.ndarray, Pm: np.ndarray) -> np.ndarray:
        """d residuals / d x, analytically (the residuals are distances from a cylinder's surface)."""
        s = self.s
        v = s.u0 + x[2] * s.e1 + x[3] * s.e2
        nv = float(np.linalg.norm(v))
        u = v / nv
        d = Pm - (x[0] * s.e1 + x[1] * s.e2)
        tt = d @ u
        perp = d - np.outer(tt, u)
        rad = np.maximum(np.linalg.norm(perp, axis=1), 1e-12)
        p1, p2 = perp @ s.e1, perp @ s.e2
        J = np.zeros((len(Pm) + 4, 6))
        J[:-4, 0] = -p1 / rad + x[5] * float(u @ s.e1)
        J[:-4, 1] = -p2 / rad + x[5] * float(u @ s.e2)
        J[:-4, 2] = -(tt / rad + x[5]) * p1 / nv
        J[:-4, 3] = -(tt / rad + x[5]) * p2 / nv
        J[:-4, 4] = -1.0
        J[:-4, 5] = -tt
        h, wa, wb = self.L / 2, self.w_a, self.w_b
        J[-4, [0, 2]] = wb, wb * h
        J[-3, [1, 3]] = wb, wb * h
        J[-2, [0, 2]] = wa, -wa * h
        J[-1, [1, 3]] = wa, -wa * h
        J[[-3, -1]] *= self.vertical
        return J

    def solve(self, x0: np.ndarray, sel: np.ndarray, r_lo: float, r_hi: float,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Fit with the radius in [r_lo, r_hi], re-select the band around the fitted surface, refit."""
        from scipy.optimize import least_squares

        cfg = self.cfg
        slope = cfg.max_taper_per_m if cfg.fit_taper else 1e-9
        bounds = ([-np.inf] * 4 + [r_lo, -slope], [np.inf] * 4 + [r_hi, slope])
        x = x0
        for _ in range(2):
            x = least_squares(self.residuals, x0, jac=self.jacobian, args=(self.P[sel] - self.mid,), loss="soft_l1",
                              f_scale=cfg.loss_scale_m, tr_solver="lsmr", bounds=bounds, x_scale=[0.01] * 6,
                              max_nfev=cfg.max_fit_evaluations).x
            new_sel = self.select(x, rng)
            if new_sel.size < cfg.min_points:
                break
            sel, x0 = new_sel, x
        return x, sel


def _fit_cylinder(P: np.ndarray, s: _SearchRegion, x_init: np.ndarray, rng: np.random.Generator,
                  log_id: str) -> _Cylinder:
    """The cylinder (soft-L1 least squares, analytic Jacobian) through the points on its visible top,
    weakly tied to the survey's axis by each end's accuracy; the top band re-selected and refitted once.

    The radius stays within ``radius_window_m`` of the chunk profiles' (they see the flanks and the
    ground; the top arc alone hardly fixes the curvature). A fit that ends ON that window's edge
    disagrees with the profiles by more than the window, and the radius it gives is the edge, set by
    the profiles' 2.5 mm grid, not by the scan (a 20 cm log came out 18 or 19 cm by which grid step
    the profiles took). When the profiles' radius explains the top points about as well
    (``radius_profile_max_rms_rise``: the top arc cannot tell the two apart, as on stereo scans), the
    radius is the profiles' and only the axis is fitted; otherwise the top arc rules it out, and the
    edge stands."""
    cfg = s.cfg
    m = _CylinderModel(P, s)
    sel = m.select(x_init, rng)
    if sel.size < cfg.min_points:
        raise LogNotSeenError(f"log {log_id!r}: only {sel.size} scan points lie on a cylinder around its "
                              "GNSS axis; the log is hidden or outside the scanned area")
    r_prof = float(np.clip(x_init[4], cfg.min_radius_m + 1e-6, cfg.max_radius_m - 1e-6))
    r_lo = max(cfg.min_radius_m, r_prof - cfg.radius_window_m)
    r_hi = min(cfg.max_radius_m, r_prof + cfg.radius_window_m)
    x, sel_x = m.solve(np.r_[x_init[:4], r_prof, x_init[5]], sel, r_lo, r_hi, rng)
    on_edge = (x[4] - r_lo < RADIUS_EDGE_M and r_lo > cfg.min_radius_m) or \
        (r_hi - x[4] < RADIUS_EDGE_M and r_hi < cfg.max_radius_m)
    radius_source = "fit"
    if on_edge:
        xp, sel_p = m.solve(np.r_[x[:4], r_prof, 0.0], sel, r_prof - 1e-7, r_prof + 1e-7, rng)
        both = np.union1d(sel_x, sel_p)
        rms_fit, rms_prof = (float(np.sqrt(np.mean(m.residuals(v, P[both] - m.mid)[:-4] ** 2))) for v in (x, xp))
        if rms_prof <= rms_fit * (1.0 + cfg.radius_profile_max_rms_rise):
            x, sel_x, radius_source = xp, sel_p, "profiles"
    c, u = m.axis(x)
    Pm = P[sel_x] - m.mid
    return _Cylinder(x, sel_x, m.mid + c, u, m.residuals(x, Pm)[: len(sel_x)], radius_source)


def _end_radii(cyl: _Cylinder, tt_sel: np.ndarray, ta: float, tb: float, coverage: float, L: float,
               cfg: FitConfig) -> tuple[float, float, float]:
    """Radius at ends a and b, and the taper's significance: a taper is kept only when the radii of
    ``taper_section_m`` sections along the log (mean surface residual + fitted radius) change linearly
    by more than ``taper_min_significance`` standard errors of their own scatter (stereo errors are
    correlated over a section, so the scatter between sections, not between points, measures it)."""
    x = cyl.x
    if not cfg.fit_taper:
        return float(x[4]), float(x[4]), 0.0
    r_a = float(x[4] + x[5] * ta)
    r_b = float(x[4] + x[5] * tb)
    sec = np.floor((tt_sel + L / 2) / cfg.taper_section_m).astype(np.int64)
    ts, rs = [], []
    for k in np.unique(sec):
        m = sec == k
        if m.sum() >= cfg.taper_section_min_points:
            ts.append(float(np.mean(tt_sel[m])))
            rs.append(float(np.mean(x[4] + x[5] * tt_sel[m] + cyl.res[m])))
    taper_sig = 0.0
    if len(ts) >= 4:
        A = np.column_stack([np.ones(len(ts)), ts])
        coef_r, *_ = np.linalg.lstsq(A, np.asarray(rs), rcond=None)
        resid = np.asarray(rs) - A @ coef_r
        dof = max(len(ts) - 2, 1)
        s2 = float(resid @ resid) / dof
        try:
            se = math.sqrt(max(s2 * np.linalg.inv(A.T @ A)[1, 1], 1e-12))
        except np.linalg.LinAlgError:
            se = math.inf
        taper_sig = abs(coef_r[1]) / se
    if taper_sig < cfg.taper_min_significance or coverage < cfg.taper_min_coverage:
        r_a = r_b = float(x[4] + x[5] * np.mean(tt_sel))
    return r_a, r_b, taper_sig


def fit_log(points: np.ndarray, end_a: Any, end_b: Any, cfg: FitConfig | None = None,
            log_id: str = "log", rng: np.random.Generator | None = None,
            sigma_a_m: float | None = None, sigma_b_m: float | None = None) -> CylinderFit:
    """Fit one log to scan points (pile frame) around its GNSS axis ``end_a`` → ``end_b``.

    ``sigma_a_m``/``sigma_b_m``: 1-sigma accuracy of each GNSS point (default
    ``cfg.gnss_sigma_m``). An imprecise point (an RTK float fix) widens the search around the
    axis, weakens the prior, and its end is taken from the scan (the extent of the log's points
    along the fitted axis) when the scan shows it better than the point does.

    Steps: :func:`_search_region` (the points near the survey's axis), :func:`_chunk_circles`
    (cross-section circles along it), :func:`_initial_axis` (a line through their centres),
    :func:`_fit_cylinder` (least squares on the visible top), :func:`_end_radii` (taper), then the ends.
    Raises :class:`FitError` naming ``log_id`` when the scan does not cover the log.
    """
    cfg = cfg or FitConfig()
    rng = rng or np.random.default_rng(cfg.seed)
    P, s = _search_region(points, end_a, end_b, cfg, log_id, sigma_a_m, sigma_b_m)
    cfg, a, b, L = s.cfg, s.a, s.b, s.length_m
    ch = _chunk_circles(s, log_id)
    cyl = _fit_cylinder(P, s, _initial_axis(ch, s), rng, log_id)
    centre, u, sel = cyl.centre, cyl.u, cyl.sel
    rms = float(np.sqrt(np.mean(cyl.res ** 2)))
    tt_sel = (P[sel] - centre) @ u
    # coverage in coverage_bin_m bins over the length
    nb = max(1, int(round(L / cfg.coverage_bin_m)))
    hist, _ = np.histogram(tt_sel, bins=nb, range=(-L / 2, L / 2))
    coverage = float(np.mean(hist > 0))
    # radius at the ends (GNSS a at t = -L/2 about the fitted centre)
    ta = float((a - centre) @ u)
    tb = float((b - centre) @ u)
    r_a, r_b, taper_sig = _end_radii(cyl, tt_sel, ta, tb, coverage, L, cfg)
    proj_a, proj_b = centre + ta * u, centre + tb * u
    res_a, res_b = float(np.linalg.norm(a - proj_a)), float(np.linalg.norm(b - proj_b))
    end_source = ["gnss", "gnss"]
    if s.ext_a_m or s.ext_b_m:  # an imprecise end: where the scan shows the log end, if it does
        t_in = (P[sel] - centre) @ u
        lo_q, hi_q = cfg.scan_end_percentile, 100.0 - cfg.scan_end_percentile
        if s.ext_a_m and t_in.size:
            t_lo = float(np.percentile(t_in, lo_q))
            if abs(t_lo - ta) < 3 * s.sig_a_m:
                proj_a, end_source[0] = centre + t_lo * u, "scan"
        if s.ext_b_m and t_in.size:
            t_hi = float(np.percentile(t_in, hi_q))
            if abs(t_hi - tb) < 3 * s.sig_b_m:
                proj_b, end_source[1] = centre + t_hi * u, "scan"
    if cfg.axis_source == "fit":
        ends = np.stack([proj_a, proj_b])
    elif cfg.endpoint_ref == "top_surface":
        r_mean = 0.5 * (r_a + r_b)
        ends = np.stack([a, b]) - r_mean * s.e2
    else:
        ends = np.stack([a, b])
    return CylinderFit(centre=centre, axis=u, ends=ends, radius_a_m=max(r_a, cfg.min_radius_m),
                       radius_b_m=max(r_b, cfg.min_radius_m), n_points=int(sel.size), rms_m=rms, coverage=coverage,
                       residual_a_m=res_a, residual_b_m=res_b, end_source=tuple(end_source),
                       taper_significance=taper_sig, radius_source=cyl.radius_source, inliers=sel)


def _distance_to_logs(P: np.ndarray, logs: Sequence[LogSpec], pad_m: float) -> np.ndarray:
    """Signed distance [m] of points to the nearest log surface (negative inside); logs are
    extended by ``pad_m`` at both ends."""
    best = np.full(len(P), np.inf)
    for log in logs:
        p0, p1 = log.endpoints_m()
        L = log.length_m
        u = (p1 - p0) / L
        rel = P - p0
        t = rel @ u
        inside = (t > -pad_m) & (t < L + pad_m)
        if not inside.any():
            continue
        ri = rel[inside]
        ti = t[inside]
        rad = np.linalg.norm(ri - np.outer(ti, u), axis=1)
        r = log.diameter_m / 2 + (log.top_d_m - log.diameter_m) / 2 * np.clip(ti / L, 0, 1)
        d = rad - r
        best[inside] = np.minimum(best[inside], d)
    return best


def points_on_no_other_log(P: np.ndarray, logs: Sequence[LogSpec], band_m: float) -> list[np.ndarray]:
    """For each of ``logs``, a mask of the points ``P`` that lie on no other log (farther than ``band_m``
    from every other log's surface): what may show where that log ends (a neighbour's top where it
    touches the end is not this log)."""
    on_log = [np.abs(_distance_to_logs(P, [log], pad_m=0.0)) <= band_m for log in logs]
    out = []
    for i in range(len(logs)):
        others = [m for j, m in enumerate(on_log) if j != i]
        out.append(~np.logical_or.reduce(others) if others else np.ones(len(P), bool))
    return out


# -- terrain ---------------------------------------------------------------------------------
def fit_terrain(ground_candidates: np.ndarray, extent_m: float, cfg: FitConfig | None = None,
                colour: tuple[float, float, float] = (0.45, 0.40, 0.30)) -> tuple[TerrainSpec, np.ndarray, float]:
    """A :class:`TerrainSpec` (explicit heights) from points that are ground or obstacles.

    Returns the terrain, a boolean mask of the points accepted as ground, and the share of grid
    cells that had ground points (the rest are filled)."""
    from scipy import ndimage

    cfg = cfg or FitConfig()
    n = cfg.terrain_resolution
    P = np.asarray(ground_candidates, dtype=np.float64)
    step = extent_m / (n - 1)
    half = extent_m / 2
    ix = np.rint((P[:, 0] + half) / step).astype(np.int64)
    iy = np.rint((P[:, 1] + half) / step).astype(np.int64)
    inside = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n)
    if inside.sum() < 10:
        raise FitError("almost no ground points inside the terrain patch; the scan does not see "
                       "the ground around the pile (scan from higher up, or enlarge the scanned area)")
    flat = iy * n + ix
    # per-cell low value: 10th percentile (robust to single low outliers)
    low = np.full(n * n, np.nan)
    order = np.lexsort((P[:, 2], flat))
    order = order[inside[order]]
    f_sorted = flat[order]
    starts = np.flatnonzero(np.r_[True, f_sorted[1:] != f_sorted[:-1]])
    ends = np.r_[starts[1:], len(order)]
    for s, e in zip(starts, ends):
        k = s + int(0.1 * (e - s))
        low[f_sorted[s]] = P[order[k], 2]
    low = low.reshape(n, n)
    have = np.isfinite(low)
    filled = _fill(low, have)
    w = max(3, int(round(cfg.ground_window_m / step)) | 1)
    opened = ndimage.grey_opening(filled, size=(w, w))
    # ground points: within the band above the opened surface (bilinear)
    from synth.scene.pile import height_at

    z_open = height_at(opened, extent_m, P[:, 0], P[:, 1])
    is_ground = inside & (P[:, 2] < z_open + cfg.ground_band_m) & (P[:, 2] > z_open - 3 * cfg.ground_band_m)
    med = np.full(n * n, np.nan)
    g = np.flatnonzero(is_ground)
    if g.size:
        fg = flat[g]
        o = np.lexsort((P[g, 2], fg))
        fs = fg[o]
        st = np.flatnonzero(np.r_[True, fs[1:] != fs[:-1]])
        en = np.r_[st[1:], len(o)]
        for s, e in zip(st, en):
            med[fs[s]] = P[g[o[(s + e - 1) // 2]], 2]
    med = med.reshape(n, n)
    have_g = np.isfinite(med)
    coverage = float(have_g.mean())
    if not have_g.any():
        heights = opened
    else:
        heights = _fill(med, have_g)
        # holes: OpenCV inpainting (Telea) from the cells with ground, smoother than the
        # nearest-cell fill it starts from
        if (~have_g).any():
            import cv2

            # on a 16-bit image spanning the measured heights (OpenCV 5's float32 inpainting
            # returned values far outside the data); quantisation < 0.02 mm per metre of relief
            lo, hi = float(heights.min()), float(heights.max())
            span = max(hi - lo, 1e-6)
            img = np.rint((heights - lo) / span * 65535).astype(np.uint16)
            inp = cv2.inpaint(img, (~have_g).astype(np.uint8), 3, cv2.INPAINT_TELEA)
            heights = np.where(have_g, heights, lo + inp.astype(np.float64) / 65535 * span)
    heights = ndimage.median_filter(heights, size=3, mode="nearest")
    terrain = TerrainSpec(extent_m=extent_m, resolution=n, amplitude_m=0.0,
                          heights_m=tuple(tuple(float(v) for v in row) for row in heights), colour=colour)
    return terrain, is_ground, coverage


def _fill(grid: np.ndarray, have: np.ndarray) -> np.ndarray:
    """Fill cells without data from the nearest cell with data."""
    from scipy import ndimage

    if have.all():
        return grid.copy()
    _, (iy, ix) = ndimage.distance_transform_edt(~have, return_indices=True)
    return grid[iy, ix]


# -- obstacles -------------------------------------------------------------------------------
def find_obstacles(points: np.ndarray, terrain: TerrainSpec, cfg: FitConfig | None = None,
                   logs: Sequence[LogSpec] = (), flank_points: np.ndarray | None = None,
                   ) -> tuple[list[StumpSpec], list[RockSpec], list[dict]]:
    """Stumps and rocks from points above the terrain (already without log points).

    ``logs``: the fitted logs; two clusters with one of them between (a log lying across a rock
    or against a stump hides a band of it) are one obstacle (:func:`_merge_across_logs`).
    ``flank_points``: lower points (``obstacle_flank_height_m`` above the ground or more) that a
    cluster takes in where they connect to it: the flanks of a half-buried rock, so that its size
    is its footprint and not only the cap above ``obstacle_min_height_m``."""
    import open3d as o3d

    cfg = cfg or FitConfig()
    P = np.asarray(points, dtype=np.float64)
    if len(P) == 0:
        return [], [], []
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc = pc.voxel_down_sample(cfg.obstacle_voxel_m)
    Q = np.asarray(pc.points)
    labels = np.asarray(pc.cluster_dbscan(eps=cfg.dbscan_eps_m, min_points=cfg.dbscan_min_points))
    clusters = [Q[labels == lab] for lab in range(int(labels.max()) + 1 if labels.size else 0)]
    clusters = _merge_across_logs(clusters, logs, cfg)
    if flank_points is not None and len(flank_points) and clusters:
        clusters = _grow_into_flanks(clusters, np.asarray(flank_points, dtype=np.float64), cfg)
    if logs:
        clusters = [_clip_log_smear(C, terrain, logs, cfg) for C in clusters]
        # nothing on the ground stands above a log's underside inside its footprint: points
        # there are the log's (stereo smear at stacked log ends, end faces) and go
        clusters = [C[C[:, 2] < _underside_z(logs, C[:, :2])] for C in clusters]
    stumps: list[StumpSpec] = []
    rocks: list[RockSpec] = []
    info: list[dict] = []
    half = terrain.extent_m / 2
    for C in clusters:
        if len(C) < cfg.obstacle_min_points:
            continue
        ext = C[:, :2].max(0) - C[:, :2].min(0)
        if float(ext.max()) < cfg.obstacle_min_size_m:
            continue
        if _log_sliver(C, logs, cfg):
            continue
        ground = terrain.height_at(C[:, 0], C[:, 1])
        h = C[:, 2] - ground
        top = float(np.percentile(h, 95))
        top_pts = C[h > top - 0.04]
        flat_frac = len(top_pts) / len(C)
        cx, cy, r, rms = _circle_fit_xy(top_pts[:, :2])
        # a stump stands up: flat round top as wide as the cluster, height at least its radius;
        # rocks are domes or slabs
        is_stump = (flat_frac >= cfg.stump_flat_fraction and np.isfinite(r) and 0.03 <= r <= 1.0
                    and rms <= cfg.stump_max_circle_rms * r and 0.05 <= top <= 2.0
                    and top >= cfg.stump_min_aspect * r and abs(cx) < half and abs(cy) < half
                    and r >= cfg.stump_min_cover * 0.5 * float(ext.max()))
        if is_stump and logs:
            # a stump is solid over its whole disc: no higher than the lowest log underside over
            # it (its foot as the twin sets it: the lowest ground under its rim and centre)
            rb = min(1.0, r * 1.1)
            foot = float(np.min(terrain.height_at(np.array([cx - rb, cx, cx + rb, cx, cx]),
                                                  np.array([cy, cy - rb, cy, cy + rb, cy]))))
            room = float(_underside_z(logs, np.array([[cx, cy]]), rb)[0]) - 0.003 - foot
            if room < cfg.obstacle_min_height_m:
                continue  # under a log all over: the log's own points
            top = min(top, room)
        if is_stump:
            stumps.append(StumpSpec(position_m=(float(cx), float(cy)), height_m=float(np.clip(top, 0.05, 2.0)),
                                    bottom_radius_m=float(min(1.0, r * 1.1)), top_radius_m=float(r)))
            info.append({"kind": "stump", "position_m": [float(cx), float(cy)], "height_m": top,
                         "radius_m": float(r), "n_points": int(len(C)), "flat_fraction": flat_frac})
        else:
            rock = _rock_from_points(C, terrain, cfg)
            rocks.append(rock)
            info.append({"kind": "rock", "position_m": list(rock.position_m), "size_m": rock.size_m(),
                         "n_points": int(len(C)), "flat_fraction": flat_frac})
    return stumps, rocks, info


def _grow_into_flanks(clusters: list[np.ndarray], flank: np.ndarray, cfg: FitConfig) -> list[np.ndarray]:
    """Each cluster plus the flank points reachable from it in steps of ``dbscan_eps_m`` (region
    growing on the voxel-downsampled flank points; a flank point joins the first cluster that
    reaches it)."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(flank)).voxel_down_sample(cfg.obstacle_voxel_m)
    F = np.asarray(pc.points)
    if not len(F):
        return clusters
    tree = cKDTree(F)
    taken = np.zeros(len(F), dtype=bool)
    out = []
    for C in clusters:
        front = C
        grown = [C]
        while len(front):
            hits = {j for row in tree.query_ball_point(front, cfg.dbscan_eps_m) for j in row}
            new = np.array(sorted(j for j in hits if not taken[j]), dtype=np.int64)
            if not len(new):
                break
            taken[new] = True
            front = F[new]
            grown.append(front)
        out.append(np.vstack(grown))
    return out


def _clip_log_smear(C: np.ndarray, terrain: TerrainSpec, logs: Sequence[LogSpec], cfg: FitConfig) -> np.ndarray:
    """A cluster whose points near a log (within ``obstacle_flank_log_gap_m`` of its top-view
    footprint) stand higher above the ground than any of its points away from logs: those
    heights are capped at the highest far point. Stereo smears a log's edge outwards at
    heights between the log's top and the ground; on an obstacle beside the log the smear
    would become a tall ridge of the obstacle, into which the log then seems to sink. A cluster
    with fewer than ``dbscan_min_points`` points away from logs is left as it is."""
    near = _footprint_distance(C[:, :2], logs) < cfg.obstacle_flank_log_gap_m
    if not near.any() or int((~near).sum()) < cfg.dbscan_min_points:
        return C
    ground = terrain.height_at(C[:, 0], C[:, 1])
    h = C[:, 2] - ground
    cap = float(h[~near].max())
    out = C.copy()
    high = near & (h > cap)
    out[high, 2] = ground[high] + cap
    return out


def _log_sliver(C: np.ndarray, logs: Sequence[LogSpec], cfg: FitConfig) -> bool:
    """True for a cluster that is a strip of log surface the fitted log does not explain (a
    log fitted a little too thin or too low): every point within ``obstacle_sliver_m`` of one
    log's top-view footprint, the strip elongated along that log's axis."""
    for log in logs:
        if float(np.max(_footprint_distance(C[:, :2], [log]))) > cfg.obstacle_sliver_m:
            continue
        xy = C[:, :2] - C[:, :2].mean(0)
        w, v = np.linalg.eigh(xy.T @ xy / len(xy))
        axis = log.axis()[:2]
        axis = axis / max(float(np.linalg.norm(axis)), 1e-9)
        if w[1] > 4 * w[0] and abs(float(v[:, 1] @ axis)) > math.cos(math.radians(20)):
            return True
    return False


def _merge_across_logs(clusters: list[np.ndarray], logs: Sequence[LogSpec], cfg: FitConfig) -> list[np.ndarray]:
    """Join clusters whose nearest points are at most ``obstacle_merge_gap_m`` apart with a log's
    top-view footprint between them (the middle of the gap inside it): the two visible parts of
    one obstacle that a log lies across or against."""
    if len(clusters) < 2 or not logs:
        return clusters
    from scipy.spatial import cKDTree

    parent = list(range(len(clusters)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    trees = [cKDTree(C[:, :2]) for C in clusters]
    axis_samples = np.vstack([a + np.outer(np.linspace(0, 1, max(2, int(log.length_m / 0.05))), b - a)
                              for log in logs for a, b in [log.endpoints_m()]])  # every 5 cm
    for i in range(len(clusters)):
        for j in range(i + 1, len(clusters)):
            d, k = trees[i].query(clusters[j][:, :2], distance_upper_bound=cfg.obstacle_merge_gap_m)
            if not np.isfinite(d).any():
                continue
            m = int(np.argmin(d))
            a, b = clusters[i][k[m], :2], clusters[j][m, :2]
            between = a + np.outer(np.linspace(0.25, 0.75, 5), b - a)
            if not (_footprint_distance(between, logs) < cfg.footprint_margin_m).any():
                continue
            ri, rj = root(i), root(j)
            if ri == rj:
                continue
            union = np.vstack([C for g, C in enumerate(clusters) if root(g) in (ri, rj)])
            if not _hull_holds_a_log(union, axis_samples):
                parent[rj] = ri
    groups: dict[int, list[np.ndarray]] = {}
    for i, C in enumerate(clusters):
        groups.setdefault(root(i), []).append(C)
    return [np.vstack(g) for g in groups.values()]


def _hull_holds_a_log(C: np.ndarray, axis_samples: np.ndarray) -> bool:
    """True when the obstacle that the points ``C`` would make (their convex hull down to the
    ground) contains a point of a log's axis: two clusters on either side of a log that make
    such a hull are two obstacles, not one that the log lies across (a log rests on top)."""
    from scipy.spatial import ConvexHull, Delaunay

    below = C.copy()
    below[:, 2] = C[:, 2].min() - 0.05
    try:
        pts = np.vstack([C, below])
        tri = Delaunay(pts[ConvexHull(pts).vertices])  # the hull's vertices span the same region, fast
    except Exception:  # flat or degenerate: no volume, holds nothing
        return False
    return bool((tri.find_simplex(axis_samples) >= 0).any())


def _circle_fit_xy(xy: np.ndarray) -> tuple[float, float, float, float]:
    """Algebraic (Kasa) circle fit: centre x, y, radius, RMS of radial residuals."""
    if len(xy) < 3:
        return math.nan, math.nan, math.nan, math.nan
    A = np.column_stack([2 * xy[:, 0], 2 * xy[:, 1], np.ones(len(xy))])
    bvec = (xy ** 2).sum(1)
    sol, *_ = np.linalg.lstsq(A, bvec, rcond=None)
    cx, cy = sol[0], sol[1]
    r2 = sol[2] + cx * cx + cy * cy
    if r2 <= 0:
        return math.nan, math.nan, math.nan, math.nan
    r = math.sqrt(r2)
    # the top is a filled disk, not a ring: use the 90th percentile distance as the radius
    d = np.hypot(xy[:, 0] - cx, xy[:, 1] - cy)
    r_disk = float(np.percentile(d, 95))
    # roundness: how far the outline deviates from a circle (outer points only)
    outer = d > 0.6 * r_disk
    rms = float(np.sqrt(np.mean((d[outer] - r_disk) ** 2))) if outer.any() else math.nan
    return float(cx), float(cy), r_disk, rms


def _rock_from_points(C: np.ndarray, terrain: TerrainSpec, cfg: FitConfig) -> RockSpec:
    """A convex rock: hull of the cluster plus its outline pushed 5 cm into the ground."""
    from scipy.spatial import ConvexHull

    ground = terrain.height_at(C[:, 0], C[:, 1])
    below = C.copy()
    below[:, 2] = ground - 0.05
    allp = np.vstack([C, below])
    try:
        hull = ConvexHull(allp)
        V = allp[hull.vertices]
    except Exception as exc:  # scipy raises QhullError for flat sets
        raise FitError(f"cannot build a rock from a flat cluster of {len(C)} points: {exc}") from exc
    if len(V) > cfg.rock_max_vertices:  # farthest-point subsampling of the hull vertices
        keep = [int(np.argmax(V[:, 2]))]
        dmin = np.linalg.norm(V - V[keep[0]], axis=1)
        while len(keep) < cfg.rock_max_vertices:
            k = int(np.argmax(dmin))
            keep.append(k)
            dmin = np.minimum(dmin, np.linalg.norm(V - V[k], axis=1))
        V = V[keep]
    centre = V.mean(0)
    return RockSpec(position_m=tuple(float(v) for v in centre), orientation=(0.0, 0.0, 0.0, 1.0),
                    vertices_m=tuple(tuple(float(c) for c in v - centre) for v in V))


# -- validation ------------------------------------------------------------------------------
def _up_across(log: LogSpec) -> np.ndarray:
    """The unit vector across ``log``'s axis in the vertical plane through it, pointing up: where its
    axis goes when it is thinned with its top kept."""
    u = log.axis()
    w = np.array([0.0, 0.0, 1.0]) - u[2] * u
    n = float(np.linalg.norm(w))
    return w / n if n > 1e-6 else np.array([1.0, 0.0, 0.0])


def thinned_keeping_top(log: LogSpec, by_m: float) -> LogSpec:
    """``log`` with both its diameters ``2 * by_m`` smaller and its axis ``by_m`` higher (across the
    axis, in the vertical plane): the top stays where it was."""
    p0, p1 = log.endpoints_m()
    up = by_m * _up_across(log)
    return LogSpec.from_endpoints(p0 + up, p1 + up, log.diameter_m - 2 * by_m,
                                  None if log.top_diameter_m is None else log.top_diameter_m - 2 * by_m, log.colour)


def _thinning_split(need_m: float, gains: Sequence[float], room: Sequence[float]) -> list[float]:
    """How much to thin each of the logs in one contact (radius, [m]) to take ``need_m`` of its depth:
    log k's thinning by d takes ``gains[k] * d`` (1 + the part of the contact normal, toward k, along
    k's up-across direction: 2 for the upper of two stacked logs, 1 side by side, 0 for the lower);
    the least total thinning (each in proportion to its gain), each at most ``room[k]``; a log with a gain
    under :data:`MIN_THINNING_GAIN` is not thinned."""
    out = [0.0] * len(gains)
    free = [k for k in range(len(gains)) if gains[k] >= MIN_THINNING_GAIN and room[k] > 0]
    left = need_m
    while free and left > 1e-6:
        g2 = sum(gains[k] ** 2 for k in free)
        want = {k: left * gains[k] / g2 for k in free}
        capped = [k for k in free if want[k] >= room[k] - out[k]]
        if not capped:
            for k in free:
                out[k] += want[k]
            break
        for k in capped:  # these take all they can; the rest is shared by the others
            left -= gains[k] * (room[k] - out[k])
            out[k] = room[k]
        free = [k for k in free if k not in capped]
    return out


def _roll_to_clear(world: Any, body: int, log: LogSpec, steps: int) -> tuple[LogSpec, float, float]:
    """``log`` (body ``body`` of ``world``) turned about its own axis to the roll, of ``steps`` over the
    prism's 72 deg period, at which its deepest contact with any body is least (the twin's log is a
    pentagonal prism to the physics and round to the eye: the scan cannot tell its roll). Returns the
    log at that roll (as it was when no roll does better by 1 mm) and its deepest contact before and
    after [m, <= 0]. The body is left at the returned roll."""
    from synth.scene.pile import quat_from_x_axis

    c = world.client

    def deepest() -> float:
        c.performCollisionDetection()
        return min((cp[8] for cp in c.getContactPoints(bodyA=body)), default=0.0)

    before = deepest()
    best, best_q = before, None
    for k in range(steps):
        q = quat_from_x_axis(log.axis(), 2 * math.pi / 5 * k / steps)
        c.resetBasePositionAndOrientation(body, list(log.centre_m), list(q))
        d = deepest()
        if d > best + 1e-3:
            best, best_q = d, q
    c.resetBasePositionAndOrientation(body, list(log.centre_m), list(best_q or log.orientation))
    if best_q is None:
        return log, before, before
    return replace(log, orientation=tuple(float(v) for v in best_q)), before, best


def separate_logs(pile: PileSpec, cfg: FitConfig | None = None, thinnable: Sequence[bool] | None = None,
                  ) -> tuple[PileSpec, list[str], list[float]]:
    """Clear logs that interpenetrate other bodies (fit noise), the worst contact first, until the
    twin accepts the pile. A ``thinnable`` log (one fitted to its scan points: its top is what the scan
    saw, its radius known to ``max_thinning_m`` only) is first made thinner with its top kept, by at
    most ``max_thinning_m`` in all: of two logs stacked with both tops seen, an overlap is the upper
    one's radius error. What thinning cannot take, a move takes: out along the contact normal by the
    remaining depth (two logs side by side, the contact normal within 45 deg of horizontal, are each
    pushed half the way apart, horizontally; of two stacked logs the upper one is lifted).
    Returns the pile, what was done, and how far each log moved [m] (its thinning:
    the pile's diameters). Raises :class:`FitError` when a log would have to move more than ``max_move_m``."""
    from synth.physics.world import World

    cfg = cfg or FitConfig()
    st = _Separation.start(pile.n_logs, cfg, thinnable)
    for _ in range(10 * pile.n_logs + 5):
        with World(pile) as world:
            contact = _worst_contact(world, cfg)
            if contact is None:
                return pile, st.notes, [float(np.linalg.norm(m)) for m in st.moves]
            turned = _roll_contact(world, pile, contact, cfg, st)
        if turned is None:
            turned = _thin_contact(pile, contact, cfg, st)
        pile = turned if turned is not None else _move_contact(pile, contact, cfg, st)
    raise FitError("could not separate the reconstructed logs; check the fits")


@dataclass
class _Separation:
    """What :func:`separate_logs` has done so far, per log: moves [m], thinning room and thinning [m],
    turns about the axis, and the notes for the report."""

    moves: list[np.ndarray]
    thin_room: list[float]
    thinned: list[float]
    rolled: list[int]
    notes: list[str]

    @classmethod
    def start(cls, n_logs: int, cfg: FitConfig, thinnable: Sequence[bool] | None) -> "_Separation":
        room = [cfg.max_thinning_m if thinnable is not None and thinnable[k] else 0.0 for k in range(n_logs)]
        return cls([np.zeros(3) for _ in range(n_logs)], room, [0.0] * n_logs, [0] * n_logs, [])


@dataclass(frozen=True)
class _Contact:
    """The deepest interpenetration of a log: its signed distance [m] (< 0), the log, the other body's
    id, the contact normal (from the other body towards the log), the bodies' names and log indices."""

    dist: float
    log: int
    other: int
    normal: np.ndarray
    names: dict
    log_of: dict

    @property
    def other_log(self) -> int | None:
        return self.log_of.get(self.other)

    @property
    def other_name(self) -> str:
        return self.names.get(self.other, str(self.other))


def _worst_contact(world, cfg: FitConfig) -> _Contact | None:
    """The deepest contact beyond tolerance in ``world``, or None when the twin accepts the pile
    (raises :class:`FitError` when it still finds the pile not physical)."""
    from synth.errors import PileValidationError

    names = {world.terrain_id: "terrain"}
    names.update({b: f"log {i}" for i, b in enumerate(world.log_ids)})
    names.update({b: f"obstacle {j}" for j, b in enumerate(world.obstacle_ids)})
    log_of = {b: i for i, b in enumerate(world.log_ids)}
    world.client.performCollisionDetection()
    worst = None
    for i, b in enumerate(world.log_ids):
        for cp in world.client.getContactPoints(bodyA=b):
            if cp[8] < -cfg.penetration_tolerance_m and (worst is None or cp[8] < worst[0]):
                worst = (cp[8], i, cp[2], np.asarray(cp[7], dtype=float))  # normal B -> A
    if worst is None:
        # pybullet's contact generation is not always the same twice: ask the twin's own
        # check too, and lift a log it still finds interpenetrating
        bad = world.penetrations(cfg.penetration_tolerance_m)
        if not bad:
            try:
                world.check_valid(cfg.penetration_tolerance_m)
            except PileValidationError as exc:
                raise FitError(f"the reconstructed pile is not physical: {exc}") from exc
            return None
        a_name, b_name, depth = bad[0]
        i_bad = int((b_name if b_name.startswith("log ") else a_name).split()[1])
        other_id = next((b for b, n in names.items() if n == (a_name if b_name == f"log {i_bad}" else b_name)), -1)
        worst = (-depth, i_bad, other_id, np.array([0.0, 0.0, 1.0]))
    return _Contact(*worst, names=names, log_of=log_of)


def _roll_contact(world, pile: PileSpec, c: _Contact, cfg: FitConfig, st: _Separation) -> PileSpec | None:
    """First the roll the scan cannot see: each log of the contact turned about its axis (at most
    ``MAX_ROLLS_PER_LOG`` times each); the pile with the turned logs, or None when none turned."""
    ks = [c.log] + ([c.other_log] if c.other_log is not None else [])
    logs = list(pile.logs)
    turned = False
    for k in ks:
        if cfg.roll_steps <= 0 or st.rolled[k] >= MAX_ROLLS_PER_LOG:
            continue
        logs[k], d0, d1 = _roll_to_clear(world, world.log_ids[k], logs[k], cfg.roll_steps)
        if logs[k] is not pile.logs[k]:
            st.rolled[k] += 1
            turned = True
            st.notes.append(f"log {k} turned about its axis (its deepest contact {-d0 * 1000:.1f} -> "
                            f"{-d1 * 1000:.1f} mm)")
    return pile.with_logs(tuple(logs)) if turned else None


def _contact_pair(c: _Contact) -> list[tuple[int, np.ndarray]]:
    """Each log of the contact and the unit way out of it for that log."""
    n = c.normal / max(np.linalg.norm(c.normal), 1e-9)
    return [(c.log, n)] + ([(c.other_log, -n)] if c.other_log is not None else [])


def _thin_contact(pile: PileSpec, c: _Contact, cfg: FitConfig, st: _Separation) -> PileSpec | None:
    """A thinnable log of the contact made thinner with its top kept (the split by what each log's
    thinning gains); the pile, or None when there is no thinning room left (a move takes it)."""
    pair = _contact_pair(c)
    room = [min(st.thin_room[k] - st.thinned[k], pile.logs[k].top_d_m / 2 - cfg.min_radius_m) for k, _ in pair]
    if max(room) <= 1e-4:
        return None
    gains = [1.0 + float(_up_across(pile.logs[k]) @ n_k) for k, n_k in pair]
    split = _thinning_split(-c.dist + 0.002, gains, room)
    if sum(split) <= 1e-4:
        return None
    logs = list(pile.logs)
    for (k, _), d in zip(pair, split):
        if d > 1e-4:
            logs[k] = thinned_keeping_top(logs[k], d)
            st.thinned[k] += d
            against = c.other_name if k == c.log else f"log {c.log}"
            st.notes.append(f"log {k} thinned {d * 1000:.1f} mm, its top kept (log {k} / {against} "
                            f"interpenetrated {-c.dist * 1000:.1f} mm)")
    return pile.with_logs(tuple(logs))  # the twin looks again: what thinning left, a move takes


def _move_contact(pile: PileSpec, c: _Contact, cfg: FitConfig, st: _Separation) -> PileSpec:
    """Out along the contact normal by the depth: side by side each log half the way, horizontally
    (neither pushed into the ground nor lifted off it); stacked, the upper one lifted (never one
    pushed down). Raises :class:`FitError` past ``max_move_m`` in all for a log."""
    i, j, other_name = c.log, c.other_log, c.other_name
    n = _contact_pair(c)[0][1]
    n_h = np.array([n[0], n[1], 0.0])
    if j is not None and np.linalg.norm(n_h) ** 2 >= SIDE_CONTACT_MIN_H2:
        step = n_h * ((-c.dist + 0.002) / (2 * float(n_h @ n_h)))
        steps = [(i, step, f"log {j}"), (j, -step, f"log {i}")]
    else:
        if j is not None and n[2] < 0:  # move whichever log goes UP
            i, n, other_name = j, -n, f"log {c.log}"
        steps = [(i, n * (-c.dist + 0.002), other_name)]
    logs = list(pile.logs)
    for k, step, against in steps:
        st.moves[k] = st.moves[k] + step
        if np.linalg.norm(st.moves[k]) > cfg.max_move_m:
            raise SeparationError(
                f"log {k} would have to move {np.linalg.norm(st.moves[k]) * 100:.1f} cm to clear {against} "
                f"(limit {cfg.max_move_m * 100:.0f} cm); its fit or its GNSS end points are wrong",
                logs=(k,) + tuple(o for o in (c.log, c.other_log) if o is not None and o != k))
        logs[k] = replace(logs[k], centre_m=tuple(float(v) for v in np.asarray(logs[k].centre_m) + step))
        how = "lifted" if step[2] > 0.7 * np.linalg.norm(step) else "moved"
        st.notes.append(f"log {k} {how} {np.linalg.norm(step) * 1000:.1f} mm along "
                        f"({step[0] / np.linalg.norm(step):+.2f}, {step[1] / np.linalg.norm(step):+.2f}, "
                        f"{step[2] / np.linalg.norm(step):+.2f}) (log {k} / {against} interpenetrated "
                        f"{-c.dist * 1000:.1f} mm)")
    return pile.with_logs(tuple(logs))


def fit_radius_on_axis(points: np.ndarray, end_a: Any, end_b: Any, cfg: FitConfig | None = None,
                       log_id: str = "log") -> CylinderFit:
    """Radius of a log whose axis is taken from its GNSS points, from the scan points on its
    visible top (within ``max_angle_deg`` of straight up): for a log lying mostly under another,
    whose free fit would wander onto the upper one. Returns a :class:`CylinderFit` (the ends are
    the GNSS points). Raises :class:`FitError` naming ``log_id`` when too few points show it."""
    cfg = cfg or FitConfig()
    a, b = np.asarray(end_a, dtype=np.float64), np.asarray(end_b, dtype=np.float64)
    L = float(np.linalg.norm(b - a))
    if L < cfg.min_survey_length_m:
        raise FitError(f"log {log_id!r}: its two GNSS points are only {L * 100:.1f} cm apart")
    u = (b - a) / L
    P = np.asarray(points, dtype=np.float64)
    rel = P - a
    t = rel @ u
    q = rel - np.outer(t, u)
    r = np.linalg.norm(q, axis=1)
    e1, e2 = _frame(u)  # e2: up-ish, perpendicular to the axis
    ang = np.arctan2(np.abs(q @ e1), q @ e2)
    on = ((t > cfg.end_margin_m) & (t < L - cfg.end_margin_m) & (r > cfg.min_radius_m)
          & (r < cfg.max_radius_m) & (ang < math.radians(cfg.max_angle_deg)))
    if on.sum() < cfg.min_points:
        raise LogNotSeenError(f"log {log_id!r}: only {int(on.sum())} scan points show its top near its GNSS axis; "
                              "the log is hidden under others or outside the scanned area")
    # the nearest surface seen from above: the lower quartile of the distances (points beyond are
    # whatever lies on or beside it)
    rad = float(np.percentile(r[on], 25))
    # the survey's axis is a few cm off (RTK noise), which spreads the top's distances by as
    # much: a circle through the top arc, its centre within two sigma of the axis (a shift and a
    # tilt), finds the radius unbiased. Points a few cm beyond the nearest surface are on it
    # still; a log lying on this one is a whole diameter farther
    from scipy.optimize import least_squares

    arc = np.flatnonzero(on & (r > rad - 0.03) & (r < rad + 0.06))
    q1, q2, tau = q[arc] @ e1, q[arc] @ e2, t[arc] / L - 0.5
    lim = 2 * cfg.gnss_sigma_m

    def off_circle(x):
        return np.hypot(q1 - x[0] - x[2] * tau, q2 - x[1] - x[3] * tau) - x[4]

    r0 = float(np.clip(rad, cfg.min_radius_m * 1.01, cfg.max_radius_m * 0.99))
    x = least_squares(off_circle, [0.0, 0.0, 0.0, 0.0, r0],
                      bounds=([-lim, -lim, -lim, -lim, cfg.min_radius_m], [lim, lim, lim, lim, cfg.max_radius_m]),
                      loss="soft_l1", f_scale=0.005).x
    a = a + (x[0] - x[2] / 2) * e1 + (x[1] - x[3] / 2) * e2
    b = b + (x[0] + x[2] / 2) * e1 + (x[1] + x[3] / 2) * e2
    rad = float(x[4])
    res = np.abs(off_circle(x))
    sel = arc[res < cfg.inlier_band_m]
    tt = t[sel]
    nb = max(1, int(round(L / cfg.coverage_bin_m)))
    hist, _ = np.histogram(tt, bins=nb, range=(0.0, L))
    rms = float(np.sqrt(np.mean(res[res < cfg.inlier_band_m] ** 2))) if sel.size else math.nan
    return CylinderFit(centre=0.5 * (a + b), axis=(b - a) / np.linalg.norm(b - a), ends=np.stack([a, b]),
                       radius_a_m=rad, radius_b_m=rad, n_points=int(sel.size), rms_m=rms,
                       coverage=float(np.mean(hist > 0)), residual_a_m=0.0, residual_b_m=0.0, inliers=sel)


def log_spec_from_fit(f: CylinderFit, cfg: FitConfig) -> tuple[LogSpec, bool]:
    """A :class:`LogSpec` from :func:`fit_log`'s result (butt = the thicker end) and whether
    end ``b`` became the butt."""
    ra, rb = f.radius_a_m, f.radius_b_m
    ends = f.ends
    taper = cfg.fit_taper and abs(ra - rb) * 2 >= cfg.taper_min_m
    swapped = bool(taper and rb > ra)
    if taper:
        d_butt, d_top = 2 * max(ra, rb), 2 * min(ra, rb)
    else:
        d_butt, d_top = ra + rb, None
    butt, top = (ends[1], ends[0]) if swapped else (ends[0], ends[1])
    d_butt = float(np.clip(d_butt, 0.03, 1.2))
    if d_top is not None:
        d_top = float(np.clip(d_top, 0.02, d_butt))
    return LogSpec.from_endpoints(butt, top, d_butt, d_top), swapped


def _owners(P: np.ndarray, logs: Sequence[LogSpec], band_m: float,
            suspect: Sequence[bool] | None = None) -> np.ndarray:
    """Index of the log whose surface each point lies on (within ``band_m``, nearest wins);
    -1 for points on no log. A ``suspect`` log (its fit strayed from its GNSS axis) gets only the
    points no other log's surface explains: it had most likely taken a neighbour's."""
    best = np.full(len(P), np.inf)
    owner = np.full(len(P), -1, dtype=np.int64)
    sus = list(suspect) if suspect is not None else [False] * len(logs)
    claimed = np.zeros(len(P), dtype=bool)  # within the band of a trusted log
    ds = [np.abs(_distance_to_logs(P, [log], pad_m=0.0)) for log in logs]
    for i, d in enumerate(ds):
        if not sus[i]:
            claimed |= d < band_m
    for i, d in enumerate(ds):
        closer = (d < best) & (d < band_m)
        if sus[i]:
            closer &= ~claimed
        owner[closer] = i
        best = np.where(closer, d, best)
    return owner


def _segment_distance_3d(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> float:
    """Shortest distance between the 3-D segments p1q1 and p2q2 (both of non-zero length) [m]."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    b, c = float(d1 @ d2), float(d1 @ r)
    denom = a * e - b * b
    s = float(np.clip((b * f - c * e) / denom, 0.0, 1.0)) if denom > 1e-12 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, float(np.clip(-c / a, 0.0, 1.0))
    elif t > 1.0:
        t, s = 1.0, float(np.clip((b - c) / a, 0.0, 1.0))
    return float(np.linalg.norm(p1 + d1 * s - (p2 + d2 * t)))


def _interpenetration(a: LogSpec, b: LogSpec) -> float:
    """How deep two logs (as cylinders of their mean radius) interpenetrate [m]; <= 0: apart."""
    return (a.mean_diameter_m + b.mean_diameter_m) / 2 - _segment_distance_3d(*a.endpoints_m(), *b.endpoints_m())


def _axis_shift(log: LogSpec, end_a: Any, end_b: Any) -> float:
    """Largest perpendicular distance of the two GNSS points from the log's axis line [m]."""
    p0, p1 = log.endpoints_m()
    u = (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9)
    out = 0.0
    for e in (end_a, end_b):
        r = np.asarray(e, dtype=float) - p0
        out = max(out, float(np.linalg.norm(r - (r @ u) * u)))
    return out


def _along_across(xy: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seen from above, each point ``xy`` ((N, 2)) against the segment ``p0`` → ``p1`` (their x, y
    are used): where along it (0 at p0, 1 at p1, not clipped) and how far from it [m]."""
    a, d = np.asarray(p0, dtype=float)[:2], np.asarray(p1, dtype=float)[:2] - np.asarray(p0, dtype=float)[:2]
    t = (xy - a) @ d / max(float(d @ d), 1e-12)
    return t, np.linalg.norm(xy - (a + np.outer(np.clip(t, 0.0, 1.0), d)), axis=1)


def _footprint_distance(xy: np.ndarray, logs: Sequence[LogSpec]) -> np.ndarray:
    """Horizontal distance [m] of points outside the nearest log's top-view footprint
    (negative inside)."""
    best = np.full(len(xy), np.inf)
    for log in logs:
        t, dist = _along_across(xy, *log.endpoints_m())
        t = np.clip(t, 0.0, 1.0)
        r = log.diameter_m / 2 + (log.top_d_m - log.diameter_m) / 2 * t
        best = np.minimum(best, dist - r)
    return best


def _survey_log(end_a: Any, end_b: Any, diameter_m: float, cfg: FitConfig) -> LogSpec:
    """A log from its GNSS points alone, of ``diameter_m`` (the axis one radius under
    ``top_surface`` points)."""
    a, b = np.asarray(end_a, dtype=float), np.asarray(end_b, dtype=float)
    if cfg.endpoint_ref == "top_surface":
        a, b = a - [0.0, 0.0, diameter_m / 2], b - [0.0, 0.0, diameter_m / 2]
    return LogSpec.from_endpoints(a, b, diameter_m)


def _sandwiched_log(P: np.ndarray, end_a: Any, end_b: Any, over: Sequence[LogSpec], cfg: FitConfig,
                    ground_radius_m: float = 0.4) -> LogSpec | None:
    """A hidden log lying on the ground under logs ``over``: its radius is half the gap between
    the ground (the low tenth of the scan points within ``ground_radius_m`` of each GNSS end) and
    the lowest underside over its axis; its axis one radius above the ground, under the GNSS
    points. ``None`` when nothing lies over it or the result disagrees with the surveyed heights
    by more than three ``gnss_sigma_m`` (then the survey's heights stand)."""
    a, b = np.asarray(end_a, dtype=float), np.asarray(end_b, dtype=float)
    ground = []
    for e in (a, b):
        near = np.linalg.norm(P[:, :2] - e[:2], axis=1) < ground_radius_m
        if near.sum() < 10:
            return None
        ground.append(float(np.percentile(P[near, 2], 10)))
    t = np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(b[:2] - a[:2]) / 0.05) + 1))
    xy = a[:2] + np.outer(t, b[:2] - a[:2])
    gap = _underside_z(over, xy) - (ground[0] + t * (ground[1] - ground[0]))
    gap = gap[np.isfinite(gap)]
    if not gap.size or float(gap.min()) < 2 * cfg.min_radius_m:
        return None
    r = float(min(gap.min() / 2, cfg.max_radius_m))
    if cfg.endpoint_ref == "top_surface":
        z_a, z_b = a[2] - r, b[2] - r
    else:
        z_a, z_b = a[2], b[2]
    if abs(ground[0] + r - z_a) > 3 * cfg.gnss_sigma_m or abs(ground[1] + r - z_b) > 3 * cfg.gnss_sigma_m:
        return None
    return LogSpec.from_endpoints((a[0], a[1], ground[0] + r), (b[0], b[1], ground[1] + r), 2 * r)


def _covered_by_others(P: np.ndarray, end_a: Any, end_b: Any, cfg: FitConfig, lateral_m: float = 0.10,
                       above_m: float = 0.05, share: float = 0.5) -> bool:
    """Whether scan points stand over the GNSS axis ``end_a`` → ``end_b`` (within ``lateral_m``
    of it seen from above, ``above_m`` or more over it) along at least ``share`` of its length
    (10 cm bins): something lies on the log. Else a log without points on it is not in the scan."""
    a, b = np.asarray(end_a, dtype=float), np.asarray(end_b, dtype=float)
    t, lat = _along_across(P[:, :2], a, b)
    over = (t > 0.0) & (t < 1.0) & (lat < lateral_m) & (P[:, 2] > a[2] + t * (b[2] - a[2]) + above_m)
    nb = max(1, int(round(float(np.linalg.norm(b[:2] - a[:2])) / 0.1)))
    hist, _ = np.histogram(t[over], bins=nb, range=(0.0, 1.0))
    return bool((hist > 0).mean() >= share)


def _clamp_under_logs(terrain: TerrainSpec, logs: Sequence[LogSpec], gap_m: float = 0.003) -> TerrainSpec:
    """Lower the (unseen, interpolated) ground under each log so that the twin's terrain, the
    surface *between* the samples included, stays under the log: the ground cannot be above a
    log lying on it. Returns a new :class:`TerrainSpec`.

    The physics interpolates the heights linearly over triangles of one grid cell, and a chord
    under the log's round underside rises above it (by ~1.4 cm for a 24 cm log across a cell
    diagonal of 11 cm, the case of logs diagonal to the grid). So every sample is held under the
    lowest point of the underside within one cell diagonal of it (less the axis' rise over that
    reach), which bounds each triangle, whose vertices are all that close to its points."""
    h = terrain.height_grid().copy()
    xs, ys = terrain.grid_xy()
    reach = math.sqrt(2.0) * float(xs[1] - xs[0])  # one cell diagonal [m]
    X, Y = np.meshgrid(xs, ys)
    flat = np.minimum(h.ravel(), _underside_z(logs, np.column_stack([X.ravel(), Y.ravel()]), reach) - gap_m)
    h = flat.reshape(h.shape)
    return replace(terrain, heights_m=tuple(tuple(float(v) for v in row) for row in h))


def _underside_z(logs: Sequence[LogSpec], xy: np.ndarray, reach_m: float = 0.0) -> np.ndarray:
    """Lowest height [m] of any of ``logs``' round undersides within ``reach_m`` (horizontally)
    of each point ``xy`` ((N, 2), pile frame), less the axis' rise over that reach; ``+inf`` where
    no log is that close. Nothing lying on the ground can stand above it there."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    out = np.full(len(xy), np.inf)
    for log in logs:
        p0, p1 = log.endpoints_m()
        d = p1 - p0
        t, lat = _along_across(xy, p0, p1)
        t = np.clip(t, 0.0, 1.0)
        r = log.diameter_m / 2 + (log.top_d_m - log.diameter_m) / 2 * t
        near = np.maximum(lat - reach_m, 0.0)  # the underside's lowest point within reach
        inside = near < r
        if not inside.any():
            continue
        slope = abs(float(d[2])) / max(float(np.linalg.norm(d[:2])), 1e-6)  # axis rise per metre of run [-]
        z_axis = p0[2] + t[inside] * d[2] - slope * reach_m
        z = z_axis - np.sqrt(np.clip(r[inside] ** 2 - near[inside] ** 2, 0.0, None))
        out[inside] = np.minimum(out[inside], z)
    return out


# -- the whole pile --------------------------------------------------------------------------
@dataclass
class _PlacedLog:
    """One log of :func:`fit_pile` as placed: its fit, its LogSpec, whether end b is the butt, and how
    (``"scan"``, ``"partial"`` or ``"hidden"``)."""

    fit: CylinderFit
    spec: LogSpec
    swapped: bool
    how: str


@dataclass
class _FirstPass:
    """:func:`fit_pile`'s first pass: each log on its own."""

    specs: list[LogSpec | None]  # per log (None: hidden, until placed)
    fits: dict[int, CylinderFit]  # the logs fitted here (not given as ``first_pass``)
    hidden: dict[int, LogNotSeenError]  # logs with no scan points on them, under others


@dataclass
class _Ground:
    """Terrain and obstacles under the placed logs."""

    terrain: TerrainSpec
    is_ground: np.ndarray
    coverage: float
    stumps: list
    rocks: list
    info: list
    n_above: int


def _check_endpoints(endpoints: Mapping[str, tuple[Any, Any]], ids: Sequence[str], extent_m: float) -> None:
    half = extent_m / 2
    for log_id in ids:
        for end, p in zip("ab", endpoints[log_id]):
            p = np.asarray(p, dtype=float)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise ValueError(f"log {log_id!r} end {end!r}: need a finite 3-D point, got {p!r}")
            if abs(p[0]) > half or abs(p[1]) > half:
                raise FitError(f"log {log_id!r} end {end!r} at ({p[0]:.2f}, {p[1]:.2f}) m lies outside "
                               f"the {extent_m:g} m terrain patch; enlarge extent_m or check the point")


def _first_pass(P: np.ndarray, ids: Sequence[str], endpoints: Mapping[str, tuple[Any, Any]], cfg: FitConfig,
                rng: np.random.Generator, given: Mapping[str, LogSpec] | None,
                sigmas: Mapping[str, tuple[float, float]] | None, say: Callable[[str], None]) -> _FirstPass:
    """Each log on its own around its axis (or as ``given``); a log with no scan points on it is hidden
    when scan points stand over its axis, else the error stands."""
    out = _FirstPass([], {}, {})
    for i, log_id in enumerate(ids):
        if given is not None and log_id in given:
            out.specs.append(given[log_id])
            continue
        say(f"fitting log {log_id}")
        sa, sb = (sigmas or {}).get(log_id, (None, None))
        try:
            out.fits[i] = fit_log(P, *endpoints[log_id], cfg, log_id=log_id, rng=rng, sigma_a_m=sa, sigma_b_m=sb)
            out.specs.append(log_spec_from_fit(out.fits[i], cfg)[0])
        except LogNotSeenError as exc:
            if not _covered_by_others(P, *endpoints[log_id], cfg):
                raise  # nothing over it either: outside the scan, or wrong end points
            out.hidden[i] = exc
            out.specs.append(None)
    if out.hidden and len(out.hidden) == len(ids):
        raise next(iter(out.hidden.values()))
    return out


class _Placement:
    """:func:`fit_pile`'s second pass: every log placed among the ones placed before it. Trusted logs
    first, each refitted on the points it owns; logs seen only in part on their survey axes; hidden ones
    between the ground and the logs over them. ``placed``, ``dropped`` hold the result."""

    def __init__(self, P: np.ndarray, ids: Sequence[str], endpoints: Mapping[str, tuple[Any, Any]],
                 cfg: FitConfig, rng: np.random.Generator, sigmas: Mapping[str, tuple[float, float]] | None,
                 optional: Collection[str], say: Callable[[str], None], in_part: Collection[str] = ()):
        self.P, self.ids, self.endpoints, self.cfg, self.rng = P, ids, endpoints, cfg, rng
        self.sigmas, self.optional, self.say, self.in_part = sigmas or {}, optional, say, set(in_part)
        self.placed: dict[int, _PlacedLog] = {}
        self.dropped: dict[str, str] = {}  # optional logs left out, and why
        self.typical_d = math.nan

    def neighbours(self, i: int) -> list[LogSpec]:
        """The other logs placed so far."""
        return [self.placed[j].spec for j in self.placed if j != i]

    def room_m(self, p0: np.ndarray, p1: np.ndarray, i: int) -> float:
        """The largest radius a log on axis p0 -> p1 has between the others placed so far [m]."""
        return min((_segment_distance_3d(p0, p1, *o.endpoints_m()) - o.mean_diameter_m / 2 for o in self.neighbours(i)),
                   default=math.inf)

    def within_room(self, spec: LogSpec, i: int, slack_m: float = 0.0) -> LogSpec:
        """``spec`` thinned to the room its neighbours leave, plus ``slack_m`` (their surfaces
        and its axis are surveyed to a few cm: a little overlap is for the twin check to lift)."""
        p0, p1 = spec.endpoints_m()
        room = self.room_m(p0, p1, i) + slack_m
        return (LogSpec.from_endpoints(p0, p1, 2 * room) if self.cfg.min_radius_m <= room < spec.mean_diameter_m / 2
                else spec)

    def no_thicker_than_seen(self, spec: LogSpec) -> LogSpec:
        """A log seen only in part, no thicker than the thickest log the scan shows whole: its radius is
        the distance from its survey axis to what the scan shows of its top, and a float end puts that
        axis decimetres off, the radius with it (twin scan 1100069, degraded survey: 23 cm too thick,
        refused by the pile check at 21 cm); then it is the pile's typical log."""
        whole = [p.spec.mean_diameter_m for p in self.placed.values() if p.how == "scan"]
        if not whole or spec.mean_diameter_m <= max(whole):
            return spec
        p0, p1 = spec.endpoints_m()
        return LogSpec.from_endpoints(p0, p1, self.typical_d, colour=spec.colour)

    def place_hidden(self, i: int, why: LogNotSeenError) -> None:
        cfg, P = self.cfg, self.P
        a, b = self.endpoints[self.ids[i]]
        if not _covered_by_others(P, a, b, cfg):
            raise why  # nothing over it either: outside the scan, or wrong end points
        spec = _sandwiched_log(P, a, b, self.neighbours(i), cfg)
        whence = "as thick as the gap between the ground and the logs over it"
        if spec is None:  # not lying between the ground and logs over it: the survey's axis
            spec = self.within_room(_survey_log(a, b, self.typical_d, cfg), i)
            whence = f"the pile's typical {self.typical_d * 100:.1f} cm within the room left; heights surveyed"
        ab = np.array([a, b], dtype=float)
        f = CylinderFit(centre=ab.mean(axis=0), axis=(ab[1] - ab[0]) / np.linalg.norm(ab[1] - ab[0]), ends=ab,
                        radius_a_m=spec.diameter_m / 2, radius_b_m=spec.diameter_m / 2, n_points=0, rms_m=math.nan,
                        coverage=0.0, residual_a_m=0.0, residual_b_m=0.0)
        self.placed[i] = _PlacedLog(f, spec, False, "hidden")
        self.say(f"log {self.ids[i]}: hidden under others ({why}); axis from GNSS, diameter {spec.diameter_m * 100:.1f} cm "
                 f"({whence})")

    def run(self, first: _FirstPass) -> None:
        cfg, P, ids, endpoints = self.cfg, self.P, self.ids, self.endpoints
        hidden = dict(first.hidden)
        specs = list(first.specs)
        # until it is placed (place_hidden), a hidden log is the pile's typical one on its survey axis
        self.typical_d = float(np.median([log.mean_diameter_m for log in specs if log is not None]))
        for i in hidden:
            specs[i] = _survey_log(*endpoints[ids[i]], self.typical_d, cfg)
        # a first fit this far off its GNSS axis (several sigma of RTK noise) took another surface,
        # most likely: a neighbour's (a log lying under another) or the ground beside it. Its refit
        # gets only the points no other log explains
        suspect = [i in hidden or _axis_shift(log, *endpoints[log_id]) > cfg.suspect_shift_m
                   for i, (log, log_id) in enumerate(zip(specs, ids))]
        owner = _owners(P, specs, cfg.inlier_band_m, suspect)
        on_axis: list[int] = []  # logs seen only in part: placed once the others are fitted
        for i in sorted(range(len(ids)), key=lambda k: suspect[k]):  # trusted logs first
            if i in hidden:
                continue
            log_id = ids[i]
            if log_id in self.in_part:  # the scan shows a piece of it: its survey points set its axis
                on_axis.append(i)
                continue
            a, b = endpoints[log_id]
            sa, sb = self.sigmas.get(log_id, (None, None))
            mine = P[(owner == i) | (owner < 0)]
            trusted = [self.placed[j].spec for j in self.placed if not suspect[j]]
            try:
                f = fit_log(mine, a, b, cfg, log_id=log_id, rng=self.rng, sigma_a_m=sa, sigma_b_m=sb)
                spec, swapped = log_spec_from_fit(f, cfg)
                astray = _axis_shift(spec, a, b) > cfg.suspect_shift_m
            except LogNotSeenError:  # its first fit took a neighbour's points: none are left to it
                astray = True
            except FitError as exc:
                if log_id not in self.optional:
                    # the points left to it fit no cylinder (twin scan 1100198: a log under two others
                    # along it): as above, its first fit if it had one, else seen in part
                    astray = True
                else:
                    self.dropped[log_id] = f"no log fits the scan points left to it once the other logs took theirs ({exc})"
                    self.say(f"log {log_id}: left out, {self.dropped[log_id]}")
                    continue
            if astray and not suspect[i] and i in first.fits:
                # the refit on the points left to it strayed where its first fit had not (a log
                # mostly hidden: its few points let the refit tilt): the first fit stands
                f = first.fits[i]
                spec, swapped = log_spec_from_fit(f, cfg)
                astray = False
            if astray or suspect[i] and any(_interpenetration(spec, o) > cfg.penetration_tolerance_m for o in trusted):
                # still astray, or inside a trusted neighbour: the log is seen only in part (under another)
                on_axis.append(i)
                continue
            self.placed[i] = _PlacedLog(f, spec, swapped, "scan")
        for i in on_axis:
            # its axis is the survey's, its radius what the scan shows of its top, at most the room
            # its neighbours leave around that axis
            log_id = ids[i]
            a, b = endpoints[log_id]
            try:
                f = fit_radius_on_axis(P[(owner == i) | (owner < 0)], a, b, cfg, log_id=log_id)
            except LogNotSeenError as exc:
                hidden[i] = exc
                continue
            spec, swapped = log_spec_from_fit(f, cfg)
            spec = self.no_thicker_than_seen(spec)
            self.placed[i] = _PlacedLog(f, self.within_room(spec, i, slack_m=cfg.gnss_sigma_m), swapped, "partial")
            self.say(f"log {log_id}: seen only in part; axis from GNSS, diameter {self.placed[i].spec.diameter_m * 100:.1f} cm")
        for i in sorted(hidden):
            if ids[i] in self.optional:
                self.dropped[ids[i]] = f"no scan points of its own once the other logs took theirs ({hidden[i]})"
                self.say(f"log {ids[i]}: left out, {self.dropped[ids[i]]}")
                continue
            self.place_hidden(i, hidden[i])
        self.drop_borrowed()

    def drop_borrowed(self) -> None:
        """Leave out a log found in the scan alone whose surface points lie mostly on the other logs
        (within ``end_walk_band_m`` of them: more than ``max_borrowed_share``): a line across the tops
        of logs that cross it, not a log (twin scan 1100087: a 24 cm 'log' across five surveyed ones,
        99 % of its points within 3 cm of them, that the pile check then refused at 17 cm; a log the
        survey missed, 1100019 degraded: 9 %)."""
        cfg = self.cfg
        for i in sorted(self.placed):
            log_id = self.ids[i]
            if log_id not in self.optional:
                continue
            spec = self.placed[i].spec
            on = np.abs(_distance_to_logs(self.P, [spec], pad_m=0.0)) <= cfg.inlier_band_m
            others = [self.placed[j].spec for j in self.placed if j != i]
            if not on.any() or not others:
                continue
            near = np.abs(_distance_to_logs(self.P[on], others, pad_m=0.0)) <= cfg.end_walk_band_m
            if float(near.mean()) > cfg.max_borrowed_share:
                self.dropped[log_id] = (f"{100 * near.mean():.0f} % of its scan points lie on other logs (within "
                                        f"{cfg.end_walk_band_m * 100:.0f} cm): the tops of logs crossing its line")
                self.say(f"log {log_id}: left out, {self.dropped[log_id]}")
                del self.placed[i]

    def place_ends(self, keep: Sequence[int],
                   place: Callable[[str, LogSpec, str, np.ndarray, bool, np.ndarray], tuple[LogSpec, Any]],
                   ) -> dict[int, tuple]:
        """Each kept log's ends placed by ``place`` on the points on no other log (within
        ``inlier_band_m``), those within ``end_walk_band_m`` of another log marked as not showing its
        top; a log seen only in part thinned again to the room around its placed ends. Returns what
        placed them, per log."""
        cfg = self.cfg
        specs = [self.placed[i].spec for i in keep]
        mine = dict(zip(keep, points_on_no_other_log(self.P, specs, cfg.inlier_band_m)))
        clear = dict(zip(keep, points_on_no_other_log(self.P, specs, cfg.end_walk_band_m)))
        ends_info: dict[int, tuple] = {}
        for i in keep:
            pl = self.placed[i]
            try:
                spec, info = place(self.ids[i], pl.spec, pl.how, self.P[mine[i]], bool(pl.swapped), clear[i][mine[i]])
            except FitError as exc:
                if self.ids[i] not in self.optional:
                    raise
                # a log found in the scan alone with an end the scan shows nothing of once the other logs
                # took their points: pieces of others, not a log (twin scan 1100119, all ends RTK fixed)
                self.dropped[self.ids[i]] = f"its ends cannot be placed once the other logs took their points ({exc})"
                self.say(f"log {self.ids[i]}: left out, {self.dropped[self.ids[i]]}")
                continue
            if pl.how == "partial":
                # its ends may have moved out (to its survey points): still no thicker than the room left
                spec = self.within_room(spec, i, slack_m=cfg.gnss_sigma_m)
            pl.spec = spec
            ends_info[i] = tuple(e if isinstance(e, dict) else e.to_dict() for e in info)
        return ends_info


def _log_fits(placement: _Placement, keep: Sequence[int], ends_info: Mapping[int, tuple]) -> list[LogFit]:
    """The per-log report of the kept logs, indexed as in the pile."""
    fits: list[LogFit] = []
    for index, i in enumerate(keep):
        log_id = placement.ids[i]
        pl = placement.placed[i]
        f, spec, swapped = pl.fit, pl.spec, pl.swapped
        a, b = placement.endpoints[log_id]
        butt, top = spec.endpoints_m()
        p0, p1 = np.asarray(a, float), np.asarray(b, float)
        ends = f.ends
        lf = LogFit(
            log_id=log_id, index=index, butt_m=tuple(float(v) for v in butt), top_m=tuple(float(v) for v in top),
            length_m=spec.length_m, diameter_m=spec.diameter_m, top_diameter_m=spec.top_diameter_m,
            n_points=f.n_points, rms_m=f.rms_m, coverage=f.coverage,
            gnss_residual_a_m=f.residual_a_m, gnss_residual_b_m=f.residual_b_m,
            axis_shift_m=float(max(np.linalg.norm(ends[0] - p0), np.linalg.norm(ends[1] - p1))),
            swapped=bool(swapped), end_source=tuple(reversed(f.end_source)) if swapped else tuple(f.end_source),
            radius_source=f.radius_source, fit=pl.how,
        )
        if i in ends_info:
            lf.ends = [dict(e) for e in ends_info[i]]
            srcs = tuple(e["source"] for e in ends_info[i])
            lf.end_source = tuple(reversed(srcs)) if swapped else srcs
            # each survey point's distance from the placed log's axis (NaN: no point)
            lf.gnss_residual_a_m, lf.gnss_residual_b_m = (
                float(e.get("gnss_axis_distance_m", math.nan) if e.get("gnss_axis_distance_m") is not None
                      else math.nan) for e in ends_info[i])
        fits.append(lf)
    return fits


def _ground(P: np.ndarray, logs: Sequence[LogSpec], extent_m: float, cfg: FitConfig,
            timings: dict[str, float], say: Callable[[str], None]) -> _Ground:
    """The terrain from the points off the logs (held under their undersides), then the obstacles
    standing on it."""
    import time

    half = extent_m / 2
    t1 = time.perf_counter()
    say("fitting terrain")
    dist = _distance_to_logs(P, logs, pad_m=cfg.terrain_log_pad_m)
    # not log, and not inside a log's top-view footprint (stereo smears log edges down there)
    rest = P[(dist > cfg.log_clearance_m) & (_footprint_distance(P[:, :2], logs) > cfg.footprint_margin_m)]
    terrain, is_ground, coverage = fit_terrain(rest, extent_m, cfg)
    terrain = _clamp_under_logs(terrain, logs)
    timings["terrain_s"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    say("finding obstacles")
    z_ground = terrain.height_at(rest[:, 0], rest[:, 1])
    above = rest[(~is_ground) & (rest[:, 2] > z_ground + cfg.obstacle_min_height_m)
                 & (np.abs(rest[:, 0]) < half) & (np.abs(rest[:, 1]) < half)]
    flank = rest[(rest[:, 2] > z_ground + cfg.obstacle_flank_height_m)
                 & (rest[:, 2] <= z_ground + cfg.obstacle_min_height_m)
                 & (np.abs(rest[:, 0]) < half) & (np.abs(rest[:, 1]) < half)]
    if logs and len(flank):
        flank = flank[_footprint_distance(flank[:, :2], logs) > cfg.obstacle_flank_log_gap_m]
    stumps, rocks, info = find_obstacles(above, terrain, cfg, logs, flank_points=flank)
    timings["obstacles_s"] = time.perf_counter() - t2
    return _Ground(terrain, is_ground, coverage, stumps, rocks, info, int(len(above)))


def _remeasure_hint(logs: Sequence[int], fits: Sequence[LogFit]) -> str:
    """What a pile-check refusal asks of the survey crew: the survey ids of the logs in the contact, and
    their end points that are not RTK fixed (the likeliest to be wrong), or, all fixed, what else to check."""
    named = [fits[k] for k in logs if 0 <= k < len(fits)]
    if not named:
        return ""
    ids = ", ".join(f"{lf.index} is {lf.log_id!r}" for lf in named)
    weak = [f"{lf.log_id!r} end {'ab'[j]} ({e.get('gnss_fix') or 'no point'}, +-{e['sigma_m'] * 100:.0f} cm)"
            for lf in named for j, e in enumerate(lf.ends or []) if e.get("gnss_fix") != "rtk_fixed"]
    if weak:
        return f" (log {ids}). Re-measure with an RTK fixed solution: {'; '.join(weak)}"
    return f" (log {ids}). Their end points are all RTK fixed: check that each point carries its log's id and end"


def fit_pile(points: np.ndarray, endpoints: Mapping[str, tuple[Any, Any]], extent_m: float,
             cfg: FitConfig | None = None, progress: Callable[[str], None] | None = None,
             georef: Any = None, notes: str = "",
             first_pass: Mapping[str, LogSpec] | None = None,
             sigmas: Mapping[str, tuple[float, float]] | None = None,
             place_ends: Callable[[str, LogSpec, str, np.ndarray, bool, np.ndarray], tuple[LogSpec, Any]] | None = None,
             optional: Collection[str] = (),
             in_part: Collection[str] = (),
             ) -> PileFit:
    """Fit a whole pile to scan ``points`` ((N, 3), pile frame) and GNSS ``endpoints``
    (``{log_id: (end_a, end_b)}``, pile frame: where each log is searched for). ``extent_m``: side
    of the terrain patch, centred on the origin. Returns a :class:`PileFit` whose ``pile`` has
    ``source="reconstructed"``.

    ``place_ends``: called once every log is placed, before the terrain, with (log id, its
    LogSpec, how it was placed, the scan points on no other log, whether end b is its butt, which of
    those points may show its top: not within ``end_walk_band_m`` of another log); returns
    the log with its ends moved and what placed them (two dicts, ends a and b, kept in
    ``LogFit.ends``; their ``source`` becomes ``LogFit.end_source``) — how
    :mod:`reconstruct.fitting.fuse` places each end from the scan and the survey by their accuracies.

    ``optional``: ids of logs found in the scan alone (no survey): one that has no scan points of its
    own once the other logs have taken theirs (a ridge made of other logs' pieces) is left out, with
    the reason in ``PileFit.dropped``, instead of failing the pile; it cannot be hidden, it was seen.
    ``in_part``: ids of logs the scan shows only a piece of (the matching's word: a ridge far shorter
    than the log's two precise survey points are apart): seen only in part, on their survey axes.

    Steps: :func:`_first_pass` (each log on its own), :class:`_Placement` (each scan point to the log
    whose surface it lies on, then each log refitted among the others; its ends placed), :func:`_ground`
    (terrain, obstacles), :func:`separate_logs` (the twin's check).
    """
    import time

    cfg = cfg or FitConfig()
    say = progress or (lambda s: None)
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
        raise ValueError(f"points must be a non-empty (N, 3) array, got shape {P.shape}")
    P = P[np.all(np.isfinite(P), axis=1)]
    if not endpoints:
        raise ValueError("no log endpoints given; the survey is empty")
    rng = np.random.default_rng(cfg.seed)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    ids = sorted(endpoints, key=natural_key)
    _check_endpoints(endpoints, ids, extent_m)
    first = _first_pass(P, ids, endpoints, cfg, rng, first_pass, sigmas, say)
    placement = _Placement(P, ids, endpoints, cfg, rng, sigmas, optional, say, in_part)
    placement.run(first)
    keep = [i for i in range(len(ids)) if ids[i] not in placement.dropped]
    ends_info: dict[int, tuple] = {}
    if place_ends is not None:
        before = {i: placement.placed[i].spec for i in keep}
        ends_info = placement.place_ends(keep, place_ends)
        if any(ids[i] in placement.dropped for i in keep):  # place the others again without it
            keep = [i for i in keep if ids[i] not in placement.dropped]
            for i in keep:
                placement.placed[i].spec = before[i]
            ends_info = placement.place_ends(keep, place_ends)
    fits = _log_fits(placement, keep, ends_info)
    logs = [placement.placed[i].spec for i in keep]
    timings["logs_s"] = time.perf_counter() - t0
    ground = _ground(P, logs, extent_m, cfg, timings, say)
    pile = PileSpec(terrain=ground.terrain, logs=tuple(logs), stumps=tuple(ground.stumps), rocks=tuple(ground.rocks),
                    georef=georef, source="reconstructed", notes=notes)
    move_notes: list[str] = []
    end_moves: list[str] = []
    if cfg.validate:
        t3 = time.perf_counter()
        say("checking the pile in the twin")
        before = pile.logs
        thinnable = [placement.placed[i].how == "scan" for i in keep]
        try:
            cleared = clear_pile(pile, [lf.ends or [] for lf in fits],
                                 lambda p: separate_logs(p, cfg, thinnable=thinnable), cfg.clearance)
        except SeparationError as exc:
            raise SeparationError(f"{exc}{_remeasure_hint(exc.logs, fits)}", logs=exc.logs) from exc
        pile, move_notes, end_moves = cleared.pile, cleared.notes, cleared.end_moves
        for (k, j), e in cleared.at_survey.items():
            fits[k].ends[j] = e
        for lf, log, old, dist in zip(fits, pile.logs, before, cleared.moved):
            lf.moved_m = float(dist)
            lf.thinned_m = float(old.diameter_m - log.diameter_m) / 2
            if log != old:
                butt, top = log.endpoints_m()
                lf.butt_m = tuple(float(v) for v in butt)
                lf.top_m = tuple(float(v) for v in top)
                lf.diameter_m, lf.top_diameter_m = log.diameter_m, log.top_diameter_m
        timings["validate_s"] = time.perf_counter() - t3
    return PileFit(pile=pile, logs=fits, terrain_coverage=ground.coverage, n_ground_points=int(ground.is_ground.sum()),
                   n_obstacle_points=ground.n_above, obstacles=ground.info, moves=move_notes, end_moves=end_moves, timings_s=timings,
                   dropped=dict(placement.dropped))


# -- synthetic scans (tests, benchmarks) -----------------------------------------------------
def sample_top_view_points(pile: PileSpec, size_px: int = 500, noise_m: float = 0.0,
                           rng: np.random.Generator | None = None) -> np.ndarray:
    """Points of ``pile`` as seen from straight above (what a downward scanner sees, occlusion
    included): the exact orthographic height map of the twin at ``size_px`` pixels per side,
    one point per pixel, plus Gaussian noise of ``noise_m`` on every coordinate. Pile frame, (N, 3)."""
    from synth.geometry.frames import OrthoGrid
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    with World(pile) as world:
        obs = render_ortho(world, OrthoRenderConfig(size_px=size_px, n_renders=1))
    X, Y = OrthoGrid(size_px, pile.terrain.extent_m).pixel_centres()
    P = np.column_stack([X.ravel(), Y.ravel(), obs.height().ravel().astype(np.float64)])
    if noise_m > 0:
        rng = rng or np.random.default_rng(0)
        P = P + rng.normal(0.0, noise_m, size=P.shape)
    return P
