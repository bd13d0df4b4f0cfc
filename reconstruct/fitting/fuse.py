"""Survey and scan fused by their uncertainties.

An RTK survey of log ends is as good as its points: an RTK-fixed point is good to 1-2 cm, a float one to
decimetres, and some logs are not surveyed at all. The scan sees most logs and most of their ends to a
centimetre or two. The fusion lets each estimate count by its accuracy, in three steps, each in its own
module:

1. **Logs in the scan** (:func:`find_scan_logs`, :mod:`reconstruct.fitting.scan_logs`): ridges of the
   scan's height raster that line up.
2. **Matching** (:func:`match_survey`, :mod:`reconstruct.fitting.matching`): every surveyed log to at most
   one scan log by the normalised distances of its points, a scan log no surveyed log takes a log the
   survey missed; :class:`AmbiguousSurveyError` when another matching is nearly as good.
3. **Ends** (:func:`scan_end_interval`, :func:`fuse_end`, :func:`place_log_ends`,
   :mod:`reconstruct.fitting.ends`): where the scan shows each end, fused with its survey point.

The configuration is :class:`FuseConfig` (:mod:`reconstruct.fitting.fuse_config`), the survey points
:class:`SurveyEnd` (:mod:`reconstruct.fitting.survey_points`). This module is the fusion's one import
place.
"""

from __future__ import annotations

from reconstruct.fitting.ends import (
    EndEstimate, EndInterval, after_pile_check, fuse_end, place_log_ends, scan_end_interval, seen_end,
)
from reconstruct.fitting.fuse_config import END_SOURCES, END_STATES, FuseConfig
from reconstruct.fitting.matching import (
    PIECE_ANGLE_DEG, PIECE_LATERAL_M, AmbiguousSurveyError, Match, a_piece_of_a_surveyed_log, absorb_pieces,
    match_survey, prior_axis,
)
from reconstruct.fitting.scan_logs import ScanLog, find_scan_logs
from reconstruct.fitting.survey_points import TYPICAL_ACCURACY_M, SurveyEnd, point_accuracy

__all__ = [
    "END_SOURCES", "END_STATES", "PIECE_ANGLE_DEG", "PIECE_LATERAL_M", "TYPICAL_ACCURACY_M", "AmbiguousSurveyError",
    "EndEstimate", "EndInterval", "FuseConfig", "Match", "ScanLog", "SurveyEnd", "a_piece_of_a_surveyed_log",
    "absorb_pieces", "after_pile_check", "find_scan_logs", "fuse_end", "match_survey", "place_log_ends",
    "point_accuracy", "prior_axis", "scan_end_interval", "seen_end",
]
