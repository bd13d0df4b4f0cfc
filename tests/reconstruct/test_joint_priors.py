"""Where the joint pipeline fits a matched log (reconstruct.pipeline._Matching.priors): a point the joint
matching did not believe sets no prior axis, except when the scan log it matched is a piece of the log by both
its points - the log is then seen in part on its survey points (``in_part``), and an axis without one of them
would run along the piece (held-out 3,300,102: two RTK fixed points 2.4 m apart, a 30 cm scrap across the
log by one of them, and a prior 0.15 m long that no scan point fitted)."""

from __future__ import annotations

import numpy as np

from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.matching import Match, a_piece_of_a_surveyed_log
from reconstruct.fitting.scan_logs import ScanLog
from reconstruct.fitting.survey_points import SurveyEnd
from reconstruct.pipeline import _Matching

FUSE = FuseConfig()


def _fixed(x: float, y: float) -> SurveyEnd:
    return SurveyEnd(np.array([x, y, 0.1]), 0.01, 0.018, "rtk_fixed")


def _ridge(x0: float, y0: float, x1: float, y1: float) -> ScanLog:
    start, end = np.array([x0, y0, 0.1]), np.array([x1, y1, 0.1])
    return ScanLog(start, end, 0.1, float(np.linalg.norm(end - start)), 5.0)


def _prior(ends, ridge: ScanLog, outliers: set[int]):
    m = _Matching([ridge], {"log3": Match("log3", 0)}, [], {}, outliers={"log3": outliers})
    a, b, _ = m.priors({"log3": ends}, [ridge], FUSE)["log3"]
    return a, b


def test_a_log_seen_in_part_by_a_scrap_across_it_keeps_both_fixed_points_for_its_axis():
    ends = (_fixed(0.8, 0.9), _fixed(-0.9, -0.8))  # 2.4 m apart
    scrap = _ridge(0.88, 0.78, 0.67, 0.99)  # 30 cm across the log by its end a
    assert a_piece_of_a_surveyed_log(ends, scrap, FUSE)
    a, b = _prior(ends, scrap, {1})  # the matching called b an outlier against the scrap's line
    assert np.allclose(a, ends[0].position_m) and np.allclose(b, ends[1].position_m)
    assert float(np.linalg.norm(b - a)) > 2.3


def test_a_point_the_matching_did_not_believe_sets_no_prior_on_a_ridge_that_is_the_log():
    ends = (_fixed(0.8, 0.9), _fixed(-0.9, -0.8))
    ridge = _ridge(0.85, 0.95, -0.5, -0.45)  # 1.9 m along the log: not a piece of it
    assert not a_piece_of_a_surveyed_log(ends, ridge, FUSE)
    a, b = _prior(ends, ridge, {1})
    assert np.allclose(b, ridge.end_m)  # b's point left out: the ridge's end
    a, b = _prior(ends, ridge, set())
    assert float(np.linalg.norm(b[:2] - ends[1].position_m[:2])) < 0.05  # believed: where it projects
