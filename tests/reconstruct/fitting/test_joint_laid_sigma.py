"""Joint revision 17: the run of a laid log no point of it reaches (joint_match.laid_nats) priced over the surveyed
length's error (joint_match.unseen_run_nats, JointConfig.laid_length_sigma): an RTK fixed length charged as
revision 16 did, a float one less, a run of 0 nothing."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_match import laid_nats, unseen_run_nats
from reconstruct.fitting.scan_logs import ScanLog
from reconstruct.fitting.survey_points import SurveyEnd

CFG = JointConfig(laid_survey_direction=False)  # laid along the ridge's axis, as revision 17 (revision 18's own tests:
#                                                test_joint_laid_direction.py)
EXACT = replace(CFG, laid_length_sigma=False)  # revision 16: the surveyed length as exact
RATE = CFG.unseen_nats_per_m
R_M = 0.09  # the ridges' radius [m]
FIXED_SIGMA_M = 0.015 / math.sqrt(2)  # an RTK fixed point's sigma per horizontal axis (1.5 cm radial) [m]
FLOAT_SIGMA_M = 0.25 / math.sqrt(2)  # an RTK float point's (25 cm radial) [m]


def _ridge(x0: float, x1: float, y: float = 0.0, seen: float | None = None) -> ScanLog:
    return ScanLog(np.array([x0, y, R_M]), np.array([x1, y, R_M]), R_M, abs(x1 - x0) if seen is None else seen, 20.0)


def _point(x: float, y: float, sigma_h_m: float) -> SurveyEnd:
    fix = "rtk_fixed" if sigma_h_m < 0.05 else "rtk_float"
    return SurveyEnd(np.array([x, y, R_M]), sigma_h_m, 0.025 if fix == "rtk_fixed" else 0.40, fix)


def _by_quadrature(unseen_m: float, sigma_m: float) -> float:
    """-log E[exp(-rate max(0, x - e))] relative to x = 0, summed over e on a fine grid (the closed form's check)."""
    e = np.linspace(-10 * sigma_m, 10 * sigma_m, 200_001)
    w = np.exp(-0.5 * (e / sigma_m) ** 2)
    mean = lambda x: float(np.sum(w * np.exp(-RATE * np.maximum(0.0, x - e))) / np.sum(w))  # noqa: E731
    return math.log(mean(0.0)) - math.log(mean(unseen_m))


@pytest.mark.parametrize("unseen_m", [0.05, 0.3, 1.0, 2.5])
@pytest.mark.parametrize("sigma_m", [0.02, 0.25, 0.6])
def test_the_closed_form_is_the_marginal_over_the_lengths_error(unseen_m, sigma_m):
    assert unseen_run_nats(unseen_m, sigma_m, RATE) == pytest.approx(_by_quadrature(unseen_m, sigma_m), abs=2e-3)


def test_a_sure_length_is_charged_as_revision_16_did_a_vague_one_less():
    fixed_sigma = math.hypot(FIXED_SIGMA_M, FIXED_SIGMA_M)  # two RTK fixed points: 1.5 cm
    for x in (0.05, 0.2, 1.0, 2.0):
        assert unseen_run_nats(x, 0.0, RATE) == pytest.approx(RATE * x, rel=1e-12)
        assert unseen_run_nats(x, fixed_sigma, RATE) == pytest.approx(RATE * x, abs=0.05)
        one_float = unseen_run_nats(x, math.hypot(FIXED_SIGMA_M, FLOAT_SIGMA_M), RATE)
        two_float = unseen_run_nats(x, math.hypot(FLOAT_SIGMA_M, FLOAT_SIGMA_M), RATE)
        assert two_float < one_float < RATE * x - 0.05
    # a metre unseen: 5 nats exact, under 4 with two float points (25 cm each), under 1 with a 1 m sigma
    assert unseen_run_nats(1.0, math.hypot(FLOAT_SIGMA_M, FLOAT_SIGMA_M), RATE) < 4.0
    assert unseen_run_nats(1.0, 1.0, RATE) < 1.0


def test_the_charge_falls_with_the_sigma_never_exceeds_the_exact_one_and_is_nothing_for_no_run():
    sigmas = [0.0, 0.005, 0.015, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 5.0]
    for x in (0.01, 0.1, 0.5, 1.0, 3.0):
        charges = [unseen_run_nats(x, s, RATE) for s in sigmas]
        assert all(a > b for a, b in zip(charges, charges[1:]))
        assert all(0.0 < c <= RATE * x + 1e-12 for c in charges)
    for s in sigmas:
        assert unseen_run_nats(0.0, s, RATE) == 0.0
        assert unseen_run_nats(-0.4, s, RATE) == 0.0
        assert unseen_run_nats(1e-4, s, RATE) < RATE * 1e-4 + 1e-12  # continuous at 0: a tiny run, a tiny charge
    assert unseen_run_nats(1.0, 50.0, RATE) < 0.05  # a length known to metres says almost nothing


def test_a_log_laid_on_a_scrap_pays_its_unseen_run_as_its_lengths_sigma_allows():
    scrap = _ridge(0.0, 1.05, seen=0.10)
    # a fixed, b 3 m across the scrap: laid from a along the scrap its surveyed length, 1.9 m of it unseen
    unseen_m = math.hypot(0.5, 3.0) - 1.05 - CFG.ridge_overrun_m
    fixed = (_point(0.0, 0.0, FIXED_SIGMA_M), _point(0.5, 3.0, FIXED_SIGMA_M))
    assert laid_nats(fixed, scrap, None, EXACT) == pytest.approx(RATE * unseen_m, rel=0.02)
    assert laid_nats(fixed, scrap, None, CFG) == pytest.approx(laid_nats(fixed, scrap, None, EXACT), abs=0.05)
    one_float = (fixed[0], _point(0.5, 3.0, FLOAT_SIGMA_M))
    two_float = (_point(0.0, 0.0, FLOAT_SIGMA_M), one_float[1])
    assert laid_nats(one_float, scrap, None, EXACT) == pytest.approx(RATE * unseen_m, rel=0.02)
    expected = unseen_run_nats(unseen_m, math.hypot(FIXED_SIGMA_M, FLOAT_SIGMA_M), RATE)
    assert laid_nats(one_float, scrap, None, CFG) == pytest.approx(expected, rel=0.02)
    assert laid_nats(two_float, scrap, None, CFG) < laid_nats(one_float, scrap, None, CFG) < RATE * unseen_m - 0.3
    # the two points' sigmas combine in quadrature (independent errors): 25 cm for two float points, not 35
    two_float_sigma = math.hypot(FLOAT_SIGMA_M, FLOAT_SIGMA_M)
    assert laid_nats(two_float, scrap, None, CFG) == pytest.approx(unseen_run_nats(unseen_m, two_float_sigma, RATE),
                                                                   rel=0.01)
    # still far dearer than nothing: a vague length does not let a log lie on a scrap for free
    assert laid_nats(two_float, scrap, None, CFG) > 0.7 * RATE * unseen_m


def test_a_float_log_on_its_own_ridge_pays_less_for_the_run_its_points_error_alone_explains():
    own = _ridge(0.0, 1.2)
    # a on the ridge's start, b (a float) 0.8 m across its other end: laid from a the log runs 0.14 m past the
    # ridge's end where no point is - the float point's error across alone makes the surveyed length that long
    ends = (_point(0.0, 0.0, FIXED_SIGMA_M), _point(1.2, 0.8, FLOAT_SIGMA_M))
    unseen_m = math.hypot(1.2, 0.8) - 1.2 - CFG.ridge_overrun_m
    assert laid_nats(ends, own, None, EXACT) == pytest.approx(RATE * unseen_m, rel=0.02)
    assert laid_nats(ends, own, None, CFG) < 0.6 * laid_nats(ends, own, None, EXACT)
    # points that reach the laid log's ends leave no run to price, sure or vague
    reach = (_point(-0.6, 0.0, FLOAT_SIGMA_M), _point(2.4, 0.0, FLOAT_SIGMA_M))
    assert laid_nats(reach, own, None, CFG) == pytest.approx(0.0, abs=1e-6)


def test_the_switch_is_checked():
    with pytest.raises(ValueError, match="laid_length_sigma"):
        JointConfig(laid_length_sigma=1)
    with pytest.raises(ValueError, match="laid_length_sigma"):
        JointConfig(laid_length_sigma="no")
    assert JointConfig().laid_length_sigma is True
