"""Joint revision 18: the log joint_match.laid_nats lays on a ridge runs in the direction the evidence supports
(joint_match.laid_direction, JointConfig.laid_survey_direction): the inverse-variance weighted angle of the ridge's
axis (ridge_direction_sigma_m over its seen length) and the survey points' line (their sigmas across it over their
distance). A short scrap across a log's two fixed points says nothing of which way the log runs; a long ridge says
more than two float points."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_match import laid_direction, laid_nats, unseen_run_nats
from reconstruct.fitting.scan_logs import ScanLog
from reconstruct.fitting.survey_points import SurveyEnd

CFG = JointConfig()
EXACT = replace(CFG, laid_length_sigma=False)  # the surveyed length as exact: the charge is rate x the run
ALONG_RIDGE = replace(EXACT, laid_survey_direction=False)  # revision 17: along the ridge's axis
RATE = CFG.unseen_nats_per_m
R_M = 0.09  # the ridges' radius [m]
FIXED_SIGMA_M = 0.015 / math.sqrt(2)  # an RTK fixed point's sigma per horizontal axis (1.5 cm radial) [m]
FLOAT_SIGMA_M = 0.25 / math.sqrt(2)  # an RTK float point's (25 cm radial) [m]


def _ridge(x0: float, x1: float, seen: float) -> ScanLog:
    return ScanLog(np.array([x0, 0.0, R_M]), np.array([x1, 0.0, R_M]), R_M, seen, 20.0)


def _point(x: float, y: float, sigma_h_m: float) -> SurveyEnd:
    fix = "rtk_fixed" if sigma_h_m < 0.05 else "rtk_float"
    return SurveyEnd(np.array([x, y, R_M]), sigma_h_m, 0.025 if fix == "rtk_fixed" else 0.40, fix)


def _angle(w: np.ndarray) -> float:
    """The direction's angle from the ridges' axis (+x) [rad]."""
    return math.atan2(float(w[1]), float(w[0]))


def test_a_short_scrap_across_a_logs_fixed_points_lays_the_log_along_its_points():
    scrap = _ridge(0.0, 0.5, seen=0.10)
    ends = (_point(0.25, 0.0, FIXED_SIGMA_M), _point(0.40, 2.42, FIXED_SIGMA_M))  # b on the scrap, a 2.42 m across
    survey_angle = math.atan2(2.42, 0.15)
    w = laid_direction(ends, scrap, CFG)
    assert np.linalg.norm(w) == pytest.approx(1.0)
    assert _angle(w) == pytest.approx(survey_angle, abs=0.002)  # 0.2 rad against 0.6 mrad: the points' line
    # laid from b's place on the scrap toward a: only the scrap's width (its radius either side of the axis,
    # across at that angle) is seen, the rest of the 2.42 m log is unseen
    length = math.hypot(0.15, 2.42)
    unseen = length - R_M / math.sin(survey_angle)
    assert laid_nats(ends, scrap, None, EXACT) == pytest.approx(RATE * unseen, rel=0.01)
    # revision 17 laid it along the scrap, the cheaper way from a's place on it (0.40 m in) back toward b's: 0.40 m
    # of it and the overrun on the scrap
    along = length - 0.40 - CFG.ridge_overrun_m
    assert laid_nats(ends, scrap, None, ALONG_RIDGE) == pytest.approx(RATE * along, rel=0.01)
    # the length's sigma still prices the run (two fixed points: 1.5 cm across, about as exact)
    assert laid_nats(ends, scrap, None, CFG) == pytest.approx(
        unseen_run_nats(unseen, math.hypot(*(e.sigma_along(np.array([1.0, 0.0, 0.0])) for e in ends)), RATE),
        rel=0.01)


def test_a_long_ridge_lays_the_log_along_its_own_axis():
    ridge = _ridge(0.0, 2.5, seen=2.5)
    ends = (_point(-0.1, 0.0, FLOAT_SIGMA_M), _point(2.6, 0.15, FLOAT_SIGMA_M))  # two floats, 3.2 deg off
    survey_angle = math.atan2(0.15, 2.7)
    w = laid_direction(ends, ridge, CFG)
    assert 0.0 < _angle(w) < 0.02 * survey_angle  # 8 mrad against 93: the ridge's axis
    assert laid_nats(ends, ridge, None, EXACT) == pytest.approx(laid_nats(ends, ridge, None, ALONG_RIDGE), abs=0.01)
    # points on the ridge's own line: the same laying, on or off, to the bit
    on_line = (_point(-0.1, 0.0, FIXED_SIGMA_M), _point(2.2, 0.0, FIXED_SIGMA_M))
    assert np.array_equal(laid_direction(on_line, ridge, CFG), np.array([1.0, 0.0]))
    assert laid_nats(on_line, ridge, None, EXACT) == laid_nats(on_line, ridge, None, ALONG_RIDGE)


def test_the_direction_blends_monotonely_from_the_points_line_to_the_ridges_axis():
    ends = (_point(0.0, 0.0, FLOAT_SIGMA_M), _point(2.0, 1.0, FIXED_SIGMA_M))
    survey_angle = math.atan2(1.0, 2.0)
    angles = [_angle(laid_direction(ends, _ridge(-0.2, 1.0, seen=s), CFG)) for s in np.linspace(0.0, 3.0, 61)]
    assert angles[0] == pytest.approx(survey_angle, abs=1e-12)  # a ridge seen over nothing says nothing
    assert all(a1 < a0 for a0, a1 in zip(angles, angles[1:]))  # the longer it is seen, the more it counts
    assert all(0.0 < a <= survey_angle + 1e-12 for a in angles)  # between the two, never past either
    # the vaguer the points, the more the ridge counts
    ridge = _ridge(-0.2, 1.0, seen=0.5)
    by_sigma = [_angle(laid_direction((_point(0.0, 0.0, s), _point(2.0, 1.0, s)), ridge, CFG))
                for s in (0.005, 0.02, 0.08, 0.3, 1.0)]
    assert all(a1 < a0 for a0, a1 in zip(by_sigma, by_sigma[1:]))
    # the midpoint of the weights: the survey's sigma in angle equal to the ridge's
    var_ridge = (CFG.ridge_direction_sigma_m / 0.5) ** 2
    sigma_pt = math.sqrt(var_ridge * 5.0 / 2.0)  # two points, sigma across each, over sqrt(5) m
    half = _angle(laid_direction((_point(0.0, 0.0, sigma_pt), _point(2.0, 1.0, sigma_pt)), ridge, CFG))
    assert half == pytest.approx(0.5 * survey_angle, rel=1e-9)


def test_the_direction_is_the_axis_the_ridge_and_the_points_share_whatever_their_order():
    ridge = _ridge(0.0, 0.6, seen=0.3)
    ends = (_point(0.1, 0.0, FIXED_SIGMA_M), _point(2.0, -0.8, FLOAT_SIGMA_M))
    w = laid_direction(ends, ridge, CFG)
    assert np.allclose(laid_direction((ends[1], ends[0]), ridge, CFG), w)
    assert w[0] > 0.0 and _angle(w) < 0.0  # within 90 deg of the ridge's start -> end, turned toward the points
    flipped = ScanLog(ridge.end_m, ridge.start_m, R_M, 0.3, 20.0)
    assert np.allclose(laid_direction(ends, flipped, CFG), -w)
    assert laid_nats(ends, flipped, None, EXACT) == pytest.approx(laid_nats(ends, ridge, None, EXACT), abs=1e-9)


def test_the_switch_lays_the_log_along_the_ridge_as_revision_17_and_is_checked():
    scrap = _ridge(0.0, 0.5, seen=0.10)
    ends = (_point(0.25, 0.0, FIXED_SIGMA_M), _point(0.40, 2.42, FIXED_SIGMA_M))
    off = replace(CFG, laid_survey_direction=False)
    assert np.array_equal(laid_direction(ends, scrap, off), np.array([1.0, 0.0]))
    assert laid_nats(ends, scrap, None, off) < laid_nats(ends, scrap, None, CFG) - 1.0
    for bad in (1, 0, "yes", None):
        with pytest.raises(ValueError, match="laid_survey_direction"):
            JointConfig(laid_survey_direction=bad)


def test_the_turned_log_is_laid_through_the_ridge_not_through_a_points_place_off_it():
    ridge = _ridge(0.0, 0.5, seen=0.3)
    # b 1 m before the ridge's start, a 1 m past its end, 20 cm across: the survey's line runs 4.6 deg off the
    # ridge's axis and over the ridge; each point pays for its own run to the ridge, the laid log for nothing more
    ends = (_point(-1.0, -0.05, FIXED_SIGMA_M), _point(1.5, 0.15, FIXED_SIGMA_M))
    w = laid_direction(ends, ridge, CFG)
    assert _angle(w) == pytest.approx(math.atan2(0.2, 2.5), abs=0.002)
    assert laid_nats(ends, ridge, None, EXACT) < 0.05
    assert laid_nats(ends, ridge, None, ALONG_RIDGE) < 0.05
