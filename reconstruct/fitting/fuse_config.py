"""How logs are found in the scan, matched to the survey and their ends placed: :class:`FuseConfig`
(units in the field names and comments), and the words for where an end came from and what the scan
showed of it."""

from __future__ import annotations

from dataclasses import dataclass

END_SOURCES = ("scan", "fixed", "float", "inferred")
END_STATES = ("seen", "occluded", "open", "none")  # what the scan shows of an end


@dataclass(frozen=True)
class FuseConfig:
    """How logs are found in the scan, matched to the survey and their ends placed (units in the
    names/comments)."""

    cell_m: float = 0.01  # top-view raster cell [m]
    ridge_scale_m: float = 0.04  # Gaussian scale of the height curvature [m] (about half a log radius)
    min_curvature_per_m: float = 3.0  # a ridge is curved across by at least this [1/m] (a 16 cm log: ~10)
    max_anisotropy: float = 0.4  # ... and along it by at most this share of that [-]
    band_m: float = 0.06  # ridge pixels this close to a line belong to it [m]
    suppress_m: float = 0.10  # a found log's ridge pixels this close to its axis are taken out [m]
    max_angle_deg: float = 10.0  # a ridge pixel's direction is within this of its line's [deg]
    max_gap_m: float = 0.45  # a ridge broken for this long is still one log (another lies across it) [m]
    max_occluded_gap_m: float = 1.5  # ... and for up to this long where something lies over it all along [m]
    min_segment_m: float = 0.3  # shorter ridge runs are not counted as logs [m]
    min_strength_per_m: float = 6.0  # a line's mean curvature over its ridge pixels, at least [1/m]
    max_logs: int = 40  # lines taken from the scan at most [-]
    min_new_log_m: float = 0.9  # a log the survey missed must show at least this length in the scan [m]
    min_new_log_coverage: float = 0.6  # ... and its fit scan points over this share of it [-]
    pose_sigma_m: float = 0.04  # scan pose uncertainty while matching (added to each point's) [m]
    axis_sigma_m: float = 0.02  # a scan log's axis position from the raster, 1 sigma [m]
    radius_sigma_m: float = 0.03  # its axis height (top less an estimated radius), 1 sigma [m]
    gate_sigma: float = 4.0  # a point this many sigma from a scan log's axis is not on it [-]
    ridge_overrun_m: float = 0.10  # a ridge may run this far past its log's end [m]
    ambiguity_chi2: float = 4.0  # another matching within this summed chi^2 of the best is as good [-]
    one_scan_offset: bool = False  # an alternative matching is as good only if also so with one offset of the
    #                                whole scan for the pose's error (reconstruct.fitting.scan_offset); off: as
    #                                revision 23 (docs/reconstruction.md, "Correct fixed points called ambiguous") [-]
    scrap_keeps_precise_points: bool = False  # a scan log seen under min_new_log_m cannot call a precise
    #                                           point wrong; off: as revision 23 [-]
    end_bin_m: float = 0.02  # bins of the walk along a fitted log [m]
    seen_gap_m: float = 0.08  # an end whose top stops this close to where the scan sees below it is seen (the
    #                           gap is the end face's shadow) [m]
    end_search_m: float = 0.6  # the walk goes at most this far past the prior end [m]
    overhang_gap_m: float = 0.05  # past a seen end the scan sees this far under the log's underside: the tip
    #                               is in the air, and a point beyond it may place the end (_end_along); the
    #                               walk's gap reads the true clearance or less (median 3 cm less), and ends
    #                               resting on the ground read at most 1.6 cm (202 seen ground ends, 16 twin
    #                               scans) [m]
    island_max_m: float = 0.04  # a run on the log this short, past a stretch with none of at least
    island_gap_m: float = 0.20  # this long, is not the log's end (a neighbour's flank at its top's height) [m]
    on_band_m: float = 0.02  # a bin is on the log when points lie this close to its top [m]
    below_min_m: float = 0.03  # a bin is below the log's top when the scan sees this much deeper than it at
    below_radius_share: float = 0.5  # least, and this share of the log's radius at least [m, -]
    below_weight: int = 3  # a bin seen below counts this many bins on the log where the walk cuts the end
    #                        (seeing the ground where the log would be is the stronger evidence) [-]
    min_on_points: int = 2  # ... at least this many [-]
    scan_end_sigma_m: float = 0.015  # axial accuracy of an end the scan sees (stereo smear, bins) [m]
    contradiction_sigma: float = 3.0  # a point farther than this many sigma from the scan's estimate is
    #                                   contradicted: reported, not used [-]
    weak_sigma_m: float = 0.05  # an end less certain than this is a weak estimate (warned about) [m]
    descent_min_deg: float = 3.0  # past the end of a log descending outward at least this steeply [deg], level
    level_shoulder: float = 0.6  # ground (the scan beside the top this many radii over the axis) is no top [-]
    piece_share: float = 0.5  # a scan log seen over less than this share of its two precise survey points'
    #                           distance is a piece: the points set the log's prior axis [-] ...
    piece_off_m: float = 0.10  # ... when one of those points lies farther than this from the piece's line [m]
    inferred_sigma_m: float = 0.30  # uncertainty of an end known only to lie beyond what the scan sees [m]
    extrapolation_sigma_per_m: float = 0.02  # a fitted axis extended past what the scan shows of its log is
    #                                          less sure across by this per metre [m/m]

    def __post_init__(self) -> None:
        for name in ("cell_m", "ridge_scale_m", "min_curvature_per_m", "band_m", "suppress_m", "max_angle_deg",
                     "max_gap_m", "max_occluded_gap_m", "min_segment_m", "pose_sigma_m", "axis_sigma_m",
                     "radius_sigma_m", "gate_sigma", "ridge_overrun_m",
                     "end_bin_m", "seen_gap_m", "end_search_m", "overhang_gap_m", "on_band_m", "scan_end_sigma_m",
                     "island_max_m", "island_gap_m", "below_min_m", "below_radius_share",
                     "contradiction_sigma", "weak_sigma_m", "inferred_sigma_m", "min_new_log_m",
                     "extrapolation_sigma_per_m", "piece_off_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.max_anisotropy < 1:
            raise ValueError(f"max_anisotropy must be in (0, 1), got {self.max_anisotropy}")
        if not 0 <= self.descent_min_deg < 90 or not self.level_shoulder > 0:
            raise ValueError("descent_min_deg must be in [0, 90) and level_shoulder > 0")
        if not 0 <= self.piece_share <= 1:
            raise ValueError(f"piece_share must be in [0, 1], got {self.piece_share}")
        if not 0 <= self.min_new_log_coverage <= 1:
            raise ValueError(f"min_new_log_coverage must be in [0, 1], got {self.min_new_log_coverage}")
        if self.cell_m > 0.05:
            raise ValueError(f"cell_m must be <= 0.05 m (logs are ~10-40 cm thick), got {self.cell_m}")
        if self.below_weight < 1:
            raise ValueError(f"below_weight must be >= 1, got {self.below_weight}")
        if self.max_logs < 1 or self.min_on_points < 1 or self.ambiguity_chi2 < 0 or self.min_strength_per_m < 0:
            raise ValueError("max_logs and min_on_points must be >= 1, ambiguity_chi2 and min_strength_per_m >= 0")
