"""The joint estimator's pieces (reconstruct.fitting.joint_*): the assignment, each end's posterior from the
per-bin scan likelihood and a robust survey point, and its configuration. Hand-made evidence: runs in a second."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_ends import (BELOW, ON, OVER, UNSEEN, _Axis, along_sigmas, bin_states,
                                            edge_log_likelihood, end_posterior, outlier_probability)
from reconstruct.fitting.joint_match import joint_match
from reconstruct.fitting.matching import AmbiguousSurveyError
from reconstruct.fitting.scan_logs import ScanLog
from reconstruct.fitting.survey_points import SurveyEnd
from reconstruct.config import ReconstructConfig

CFG, FCFG = JointConfig(), FuseConfig()
CHAIN = JointConfig(contiguity=True)  # the per-bin end model with contiguity
STEP = FCFG.end_bin_m
AXIS = _Axis(np.zeros(3), np.array([1.0, 0.0, 0.0]), 2.0)  # a 2 m log along x, end a at 0, end b at 2 m


def _scan_log(x0, x1, y, z=0.08, r=0.08, seen=None) -> ScanLog:
    return ScanLog(np.array([x0, y, z]), np.array([x1, y, z]), r, abs(x1 - x0) if seen is None else seen, 20.0)


def _end(x, y, z=0.08, fix="rtk_fixed") -> SurveyEnd:
    s = (0.25, 0.40) if fix == "rtk_float" else (0.015, 0.025)
    return SurveyEnd(np.array([x, y, z]), s[0] / math.sqrt(2), s[1], fix)


def _states_b(end_m: float, past: int, inside=ON, lo_m: float = 1.0, n: int = 80) -> np.ndarray:
    """Bins from ``lo_m`` along the axis: ``inside`` up to ``end_m``, then ``past`` (a state or a list by bin)."""
    c = lo_m + STEP * (np.arange(n) + 0.5)
    return np.where(c < end_m, inside, past)


def test_a_seen_end_is_where_the_top_gives_way_to_the_ground():
    post = end_posterior(_states_b(2.0, BELOW), 1.0, 1, AXIS, None, 0.005, CFG, FCFG)
    assert abs(post["t_m"] - (2.0 - CFG.top_smear_m)) < 0.01 and post["sigma_along_m"] < CFG.weak_sigma_m
    assert post["outlier_prob"] is None


def test_a_neighbours_top_in_line_past_a_gap_does_not_pull_the_end_onto_it():
    # the top to 2.0 m, 6 cm of ground, then a neighbour's top in line for 34 cm, then ground again
    c = 1.0 + STEP * (np.arange(80) + 0.5)
    states = np.where(c < 2.0, ON, np.where(c < 2.06, BELOW, np.where(c < 2.4, ON, BELOW)))
    fixed = end_posterior(states, 1.0, 1, AXIS, _end(1.995, 0.0, 0.0), 0.005, CHAIN, FCFG)
    assert fixed["outlier_prob"] < 0.01 and abs(fixed["t_m"] - 1.995) < 0.01  # a correct fixed point stands
    floating = end_posterior(states, 1.0, 1, AXIS, _end(2.0, 0.0, 0.0, fix="rtk_float"), 0.005, CHAIN, FCFG)
    assert abs(floating["t_m"] - (2.0 - CFG.top_smear_m)) < 0.02  # the end at the gap, not the neighbour's far end
    alone = end_posterior(states, 1.0, 1, AXIS, None, 0.005, CHAIN, FCFG)
    assert abs(alone["t_m"] - (2.0 - CFG.top_smear_m)) < 0.02 and alone["sigma_along_m"] > 0.1  # the other, less likely
    independent = end_posterior(states, 1.0, 1, AXIS, _end(2.0, 0.0, 0.0, fix="rtk_float"), 0.005, CFG, FCFG)
    assert independent["t_m"] > 2.3  # without contiguity each bin of the neighbour's top pulls: its far end


def test_a_fixed_point_at_a_seen_end_agrees_and_one_30_cm_past_it_is_an_outlier():
    states = _states_b(2.0, BELOW)
    agree = end_posterior(states, 1.0, 1, AXIS, _end(1.995, 0.0, 0.0), 0.005, CFG, FCFG)
    assert agree["outlier_prob"] < 0.01 and abs(agree["t_m"] - 1.995) < 0.01
    off = end_posterior(states, 1.0, 1, AXIS, _end(2.30, 0.0, 0.0), 0.005, CFG, FCFG)
    assert off["outlier_prob"] > 0.99 and abs(off["t_m"] - (2.0 - CFG.top_smear_m)) < 0.01  # the scan's end
    across = end_posterior(states, 1.0, 1, AXIS, _end(1.995, 0.30, 0.0), 0.005, CFG, FCFG)
    assert across["outlier_prob"] > 0.99  # 30 cm beside the log's end: as wrong


def test_a_fixed_point_past_a_stretch_under_another_log_places_the_end():
    # the top seen to 1.6 m, then another log over it (no below bin): an RTK fixed point at 1.95 m stands
    states = _states_b(1.6, OVER)
    post = end_posterior(states, 1.0, 1, AXIS, _end(1.95, 0.0, 0.0), 0.005, CFG, FCFG)
    assert post["outlier_prob"] < 0.5 and abs(post["t_m"] - 1.95) < 0.02
    # a float point there is far less sure: the end lies between, and its sigma says so
    flt = end_posterior(states, 1.0, 1, AXIS, _end(1.95, 0.0, 0.0, fix="rtk_float"), 0.005, CFG, FCFG)
    assert flt["sigma_along_m"] > 0.08


def test_an_end_nothing_shows_is_as_unsure_as_its_prior():
    post = end_posterior(np.full(80, UNSEEN), 1.0, 1, AXIS, None, 0.005, CFG, FCFG)
    assert post["sigma_along_m"] > 0.15 and post["seen_any"] is False


def test_bins_read_the_top_the_ground_and_a_log_over_it():
    # a 16 cm log (radius 8 cm, axis 8 cm up) along x to 2 m: its top at 16 cm; ground at 0 past it; from
    # 1.0 to 1.2 m another log's surface 10 cm over its top
    x = np.arange(0.0, 2.6, 0.005)
    top = np.c_[x[x < 2.0], np.zeros((x < 2.0).sum()), np.full((x < 2.0).sum(), 0.16)]
    ground = np.c_[x[x >= 2.0], np.zeros((x >= 2.0).sum()), np.zeros((x >= 2.0).sum())]
    pts = np.r_[top, ground]
    pts[(pts[:, 0] > 1.0) & (pts[:, 0] < 1.2), 2] = 0.26
    st = bin_states(pts, np.array([0.0, 0.0, 0.08]), np.array([1.0, 0.0, 0.0]), 0.08, 0.0, 125, FCFG)
    c = STEP * (np.arange(125) + 0.5)
    assert (st[(c < 1.0) & (c > 0.05)] == ON).all() and (st[(c > 1.02) & (c < 1.18)] == OVER).all()
    assert (st[c > 2.02] == BELOW).all()


def test_a_point_pushed_off_its_end_is_flagged_after_the_check():
    p = _end(0.0, 0.0, 0.0)
    assert outlier_probability(p, np.array([0.01, 0.0, 0.0]), 0.015, CFG) < 0.01
    assert outlier_probability(p, np.array([0.20, 0.0, 0.0]), 0.015, CFG) > 0.99


def test_one_assignment_keeps_a_log_with_a_wrong_fixed_point_on_its_ridge():
    scan_logs = [_scan_log(0.0, 2.0, 0.0), _scan_log(0.0, 2.0, 0.6)]
    survey = {"log0": (_end(0.0, 0.0), _end(2.0, 0.6)),  # its end b recorded at the other log's
              "log1": (_end(0.0, 0.6), _end(2.0, 0.6))}
    m = joint_match(survey, scan_logs, CFG, FCFG)
    assert m.matches["log0"].scan_index == 0 and m.matches["log1"].scan_index == 1
    assert m.outliers["log0"] == {1} and m.outliers["log1"] == set() and m.unmatched == []


def test_a_log_of_two_fixed_points_over_no_ridge_is_hidden_and_a_long_ridge_no_one_took_is_missed():
    scan_logs = [_scan_log(0.0, 2.0, 0.0), _scan_log(0.0, 2.0, 1.5)]
    survey = {"log0": (_end(0.0, 0.0), _end(2.0, 0.0)), "log1": (_end(0.0, 0.7), _end(2.0, 0.7))}
    m = joint_match(survey, scan_logs, CFG, FCFG)
    assert m.matches["log1"].scan_index is None and m.unmatched == [1]


def test_a_one_point_log_that_is_the_end_of_no_scan_log_is_left_out_its_point_an_outlier():
    scan_logs = [_scan_log(0.0, 2.0, 0.0)]
    survey = {"log0": (_end(0.0, 0.0), _end(2.0, 0.0)), "log9": (None, _end(1.0, 1.2))}
    m = joint_match(survey, scan_logs, CFG, FCFG)
    assert "log9" in m.dropped and "log9" not in m.matches and m.matches["log0"].scan_index == 0


def test_two_float_logs_that_fit_two_ridges_either_way_are_no_ambiguity_but_a_kept_or_dropped_ridge_is():
    scan_logs = [_scan_log(0.0, 2.0, 0.0), _scan_log(0.0, 2.0, 0.25)]
    survey = {"log0": (_end(0.0, 0.1, fix="rtk_float"), _end(2.0, 0.1, fix="rtk_float")),
              "log1": (_end(0.0, 0.15, fix="rtk_float"), _end(2.0, 0.15, fix="rtk_float"))}
    m = joint_match(survey, scan_logs, CFG, FCFG)  # a swap makes the same pile
    assert {m.matches[k].scan_index for k in survey} == {0, 1}
    one = {"log0": survey["log0"]}  # one float log between two long ridges: the other is a log the survey
    assert joint_match(one, scan_logs, CFG, FCFG).matches["log0"].scan_index in (0, 1)  # missed: the same pile
    short = [_scan_log(0.6, 1.4, 0.0), _scan_log(0.6, 1.4, 0.25)]  # too short to stand as logs of their own:
    between = {"log0": (_end(0.0, 0.125, fix="rtk_float"), _end(2.0, 0.125, fix="rtk_float"))}
    with pytest.raises(AmbiguousSurveyError, match="log0"):  # which one is in the pile, the survey cannot say
        joint_match(between, short, JointConfig(ambiguity_is_error=True), FCFG)
    warned = joint_match(between, short, CFG, FCFG)  # by default: said, and the likelier placed
    assert len(warned.ambiguous) == 1 and "log0" in warned.ambiguous[0] and "re-measure" in warned.ambiguous[0].lower()


def test_contiguity_counts_a_run_where_it_starts():
    # 20 bins of top past 20 bins of top: independent bins count each; a chain counts the run once
    run = np.full(40, ON)
    ll_chain = edge_log_likelihood(run, CHAIN, STEP)
    ll_independent = edge_log_likelihood(run, CFG, STEP)
    assert ll_independent[40] - ll_independent[20] == pytest.approx(20 * math.log(CFG.p_on_inside / CFG.p_on_outside))
    assert 0 < ll_chain[40] - ll_chain[20] < 0.5 * (ll_independent[40] - ll_independent[20])
    # the end where the top gives way to the ground beats an end inside the top's run or inside the ground's
    seen = np.r_[np.full(20, ON), np.full(20, BELOW)]
    ll = edge_log_likelihood(seen, CHAIN, STEP)
    assert int(np.argmax(ll)) == 20


def test_an_ends_along_prior_is_its_posteriors_sigma_where_it_is_gaussian():
    # a hidden end (nothing seen) on a float point: the posterior is the point's Gaussian (and the weak prior)
    post = end_posterior(np.full(120, UNSEEN), 1.0, 1, AXIS, _end(2.1, 0.0, 0.0, fix="rtk_float"), 0.005, CFG, FCFG)
    gauss = (post["sigma_point_m"] ** -2 + CFG.end_prior_sigma_m ** -2) ** -0.5  # the point and the weak prior
    assert post["sigma_along_in_m"] == pytest.approx(gauss, rel=0.05)
    assert post["sigma_along_out_m"] == pytest.approx(gauss, rel=0.05)
    assert gauss > 0.1


def test_an_ends_along_prior_is_tight_where_the_scan_sees_it_and_one_sided_where_a_log_hides_it():
    # the top seen inside costs ~1 nat per 2 cm bin an end moves in (8 nats at ~16 cm: 4 cm a sigma), the
    # ground seen past it ~1.9 nats per bin out
    seen = end_posterior(_states_b(2.0, BELOW), 1.0, 1, AXIS, None, 0.005, CFG, FCFG)
    assert seen["sigma_along_in_m"] < 0.05 and seen["sigma_along_out_m"] < 0.03
    under = end_posterior(_states_b(2.0, OVER), 1.0, 1, AXIS, None, 0.005, CFG, FCFG)  # a log across past it
    assert under["sigma_along_in_m"] < 0.05 and under["sigma_along_out_m"] > 0.1  # free outward only
    fixed = end_posterior(_states_b(2.0, OVER), 1.0, 1, AXIS, _end(2.0, 0.0, 0.0), 0.005, CFG, FCFG)
    assert fixed["sigma_along_in_m"] < 0.02 and fixed["sigma_along_out_m"] < 0.02  # an RTK fixed point holds it


def test_an_ends_along_prior_does_not_reach_across_a_valley_to_a_second_hump():
    edges = np.arange(-0.8, 0.2, 0.005)
    post = np.exp(-0.5 * (edges / 0.02) ** 2) + 0.5 * np.exp(-0.5 * ((edges + 0.5) / 0.02) ** 2)
    post /= post.sum()
    spread = math.sqrt(float(post @ edges ** 2))
    inward, outward = along_sigmas(post, edges, 0.0, 1, CFG)  # end b: inward is toward lower t
    assert spread > 0.2
    assert inward == pytest.approx(0.02, abs=0.003) and outward == pytest.approx(0.02, abs=0.003)
    a_in, a_out = along_sigmas(post[::-1], -edges[::-1], 0.0, 0, CFG)  # the same seen from end a
    assert (a_in, a_out) == pytest.approx((inward, outward), abs=1e-9)


def test_the_estimator_and_its_parameters_are_checked():
    with pytest.raises(ValueError, match="estimator"):
        ReconstructConfig(estimator="rules23")
    with pytest.raises(ValueError, match="outlier_prior"):
        JointConfig(outlier_prior=1.5)
    with pytest.raises(ValueError, match="hidden_cost"):
        JointConfig(hidden_cost=0.0)
    with pytest.raises(ValueError, match="p_on"):
        JointConfig(p_on_inside=0.9, p_below_inside=0.05)
    assert ReconstructConfig().estimator == "rules22"  # revision 22 stays the default
