"""Joint revision 16's matching terms: where a ridge's axis runs from its chunks' profile circles
(joint_ridge.ridge_line), the log's unseen run paid by the log laid along its ridge (joint_match.laid_nats), and
the chunks past a point inside a ridge as evidence whether the ridge runs on onto something else
(joint_match.run_on_evidence_nats)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_match import joint_match, laid_nats, point_cost, point_costs, run_on_evidence_nats
from reconstruct.fitting.joint_ridge import ChunkProfile, RidgeEvidence, ridge_line, usable_chunks
from reconstruct.fitting.scan_logs import PROFILE_CENTRE_TOLERANCE_M, ScanLog
from reconstruct.fitting.survey_points import SurveyEnd

CFG, FCFG = JointConfig(), FuseConfig()
RUN_ON = replace(CFG, run_on_chunks=True)  # the chunks' run-on evidence is opt-in
R_M = 0.09  # the ridges' radius [m]


def _ridge(x0: float, x1: float, y: float = 0.0, z: float = 0.09, seen: float | None = None) -> ScanLog:
    return ScanLog(np.array([x0, y, z]), np.array([x1, y, z]), R_M, abs(x1 - x0) if seen is None else seen, 20.0)


def _fixed(x: float, y: float, z: float = 0.09) -> SurveyEnd:
    return SurveyEnd(np.array([x, y, z]), 0.015 / math.sqrt(2), 0.025, "rtk_fixed")


def _float(x: float, y: float, z: float = 0.09) -> SurveyEnd:
    return SurveyEnd(np.array([x, y, z]), 0.20, 0.50, "rtk_float")


def _chunks(ts, lateral, height) -> list[ChunkProfile]:
    return [ChunkProfile(t, s, w, R_M) for t, s, w in zip(ts, lateral, height)]


# a 1.5 m ridge whose whole-run direction is 2.3 deg off its log's: its three chunks' centres 4 cm apart across
# per metre (the log's end a lies 1.17 m before the ridge's start, 9.7 cm across the run's line)
TILT = 0.04
TILTED = _chunks([0.25, 0.75, 1.25], [-0.04, -0.02, 0.0], [0.0, 0.0, 0.0])


def test_a_ridges_chunk_line_corrects_its_direction_and_grows_uncertain_past_its_ends():
    ridge = _ridge(0.0, 1.5, seen=1.1)
    line = ridge_line(TILTED, ridge, CFG, FCFG)
    assert line is not None
    assert line.lateral_m(0.75) == pytest.approx(-0.02, abs=0.002)
    # the prior (the run's own direction within ridge_direction_sigma_m over 1.1 m) shrinks the slope a little
    assert line.lateral_m(-1.17) == pytest.approx(-0.02 - TILT * 1.92, abs=0.015)
    assert line.lateral_m(-1.17) < -0.06
    assert line.lateral_var_m2(-1.17) > 4 * line.lateral_var_m2(0.75)
    assert line.height_m(-1.17) == pytest.approx(0.0, abs=1e-3)
    # two chunks make no line; nor do chunks whose circle lies at the edge of the profile's centre search
    assert ridge_line(TILTED[:2], ridge, CFG, FCFG) is None
    edge = _chunks([0.25, 0.75, 1.25], [-PROFILE_CENTRE_TOLERANCE_M] * 3, [0.0] * 3)
    assert usable_chunks(edge, ridge) == () and ridge_line(edge, ridge, CFG, FCFG) is None


def test_a_ridge_that_is_not_straight_predicts_its_axis_less_surely():
    ridge = _ridge(0.0, 3.35)
    straight = ridge_line(_chunks([0.25, 0.75, 1.25, 1.75, 2.25, 2.75], [0.0] * 6, [0.0] * 6), ridge, CFG, FCFG)
    hump = ridge_line(_chunks([0.25, 0.75, 1.25, 1.75, 2.25, 2.75], [0.0] * 6,
                              [-0.15, -0.05, 0.05, 0.08, -0.05, -0.12]), ridge, CFG, FCFG)
    assert straight.height.scatter_m == pytest.approx(CFG.ridge_line_sigma_floor_m)
    assert hump.height.scatter_m > 0.08
    assert hump.height_var_m2(2.15) > 0.08 ** 2 > 10 * straight.height_var_m2(2.15)
    # a vaguer prediction explains less: a point right on the hump's line costs more than one on the straight's
    on_hump = point_cost(_fixed(0.0, 0.0, 0.09 + hump.height_m(0.0)), ridge, True, CFG, FCFG, line=hump)
    on_straight = point_cost(_fixed(0.0, 0.0, 0.09 + straight.height_m(0.0)), ridge, True, CFG, FCFG, line=straight)
    assert on_hump > on_straight + 0.5


def test_a_fixed_end_past_a_short_tilted_ridge_is_no_outlier_against_its_chunk_line():
    ridge = _ridge(0.0, 1.5, seen=1.1)
    line = ridge_line(TILTED, ridge, CFG, FCFG)
    a = _fixed(-1.17, -0.02 - TILT * 1.92)  # on the log: the chunks' line, 1.17 m before the ridge's start
    alone = point_cost(a, ridge, True, CFG, FCFG, outlier_prob=True)
    along = point_cost(a, ridge, True, CFG, FCFG, outlier_prob=True, line=line)
    assert alone > CFG.outlier_flag_prob > along
    # the line's prediction and its variance both carry it: the variance alone (no correction) is not enough
    no_shift = replace(line, lateral=replace(line.lateral, coef=(0.0, 0.0)))
    assert point_cost(a, ridge, True, CFG, FCFG, outlier_prob=True, line=no_shift) > CFG.outlier_flag_prob
    off = replace(CFG, ridge_chunk_line=False)
    assert point_cost(a, ridge, True, off, FCFG, outlier_prob=True, line=line) == pytest.approx(alone)
    # 6 cm off the line 1.17 m past the ridge's start is a weaker test than the line's mean alone makes it (the
    # line's direction is unsure there)
    far = _fixed(-1.17, line.lateral_m(-1.17) + 0.06)
    sure = replace(line, lateral=replace(line.lateral, cov=((0.0, 0.0), (0.0, 0.0)), scatter_m=0.0))
    assert point_cost(far, ridge, True, CFG, FCFG, line=line) < point_cost(far, ridge, True, CFG, FCFG, line=sure) - 0.3


def test_a_log_laid_on_a_scrap_pays_for_its_unseen_run_though_its_far_point_is_an_outlier():
    scrap = _ridge(0.0, 1.05, seen=0.10)
    ends = (_fixed(0.0, 0.0), _float(0.5, 3.0))  # b 3 m across the scrap: the log is 3 m long
    exact = replace(CFG, laid_length_sigma=False, laid_survey_direction=False)  # the surveyed length as exact and
    #   the log laid along the scrap (revision 16; with the length's sigma: test_joint_laid_sigma; in the points'
    #   direction: test_joint_laid_direction)
    laid = laid_nats(ends, scrap, None, exact)
    # laid from a along the scrap toward b's place on it, its surveyed length: all but 1.05 + 0.10 m past the scrap
    assert laid == pytest.approx(CFG.unseen_nats_per_m * (math.hypot(0.5, 3.0) - 1.05 - CFG.ridge_overrun_m), rel=0.02)
    assert laid_nats(ends, scrap, None, replace(CFG, laid_unseen=False)) == 0.0
    assert laid_nats((ends[0], None), scrap, None, CFG) == 0.0
    # on its own ridge (1.5 m, its fixed end a 0.6 m before it, b 0.9 m after) its points reach both runs and pay
    # for them themselves: the laid log adds nothing
    own = _ridge(0.0, 1.5, y=1.0)
    on_own = (_fixed(-0.6, 1.0), _fixed(2.4, 1.0))
    assert laid_nats(on_own, own, None, exact) == pytest.approx(0.0, abs=1e-6)
    assert point_cost(on_own[0], own, True, CFG, FCFG) > CFG.unseen_nats_per_m * 0.5 - 0.1
    # a point that stops short of where the laid log runs leaves the rest to it: b 1.4 m across the ridge's end,
    # the log laid from a its surveyed length runs 0.32 m past the ridge's other end, which no point reaches
    short = (_fixed(-0.6, 1.0), _float(1.5, 2.4))
    beyond_m = math.hypot(2.1, 1.4) - 0.6 - 1.5 - CFG.ridge_overrun_m
    assert laid_nats(short, own, None, exact) == pytest.approx(CFG.unseen_nats_per_m * beyond_m, rel=0.02)


def test_a_log_takes_its_own_short_ridge_not_a_scrap_its_float_point_calls_wrong():
    # log0: end a RTK fixed 1.8 m before its own 1.2 m ridge, b a float 0.2 m past its other end; a 1.05 m
    # scrap (10 cm of it seen) runs across from a, b 3 m from it: an outlier there, costing a float's little
    own = _ridge(0.0, 1.2)
    scrap = ScanLog(np.array([-1.8, 0.0, 0.09]), np.array([-1.8, 1.05, 0.09]), R_M, 0.10, 20.0)
    survey = {"log0": (_fixed(-1.8, 0.0), _float(1.4, 0.0))}
    cfg = replace(CFG, match_pose_offset=False)
    m = joint_match(survey, [own, scrap], cfg, FCFG)
    assert m.matches["log0"].scan_index == 0 and m.unmatched == [1]
    # each point paying for the run to it, b an outlier on the scrap paid nothing for the log's 2 m past it
    m15 = joint_match(survey, [own, scrap], replace(cfg, laid_unseen=False), FCFG)
    assert m15.matches["log0"].scan_index == 1


def _run_on_ridge() -> tuple[ScanLog, tuple[SurveyEnd, SurveyEnd]]:
    # a 3.35 m ridge whose log (its end b at the ridge's start, a 2.15 m on, 34 cm higher) ends 1.2 m before the
    # ridge does: the ridge runs on onto something lower in line
    ridge = _ridge(0.0, 3.35, z=0.09)
    return ridge, (_fixed(2.15, 0.0, 0.09 + 0.16), _fixed(0.0, 0.0, 0.09 - 0.18))


def test_chunks_past_a_point_off_the_logs_line_say_the_ridge_runs_on_onto_something_else():
    ridge, (a, b) = _run_on_ridge()
    slope = 0.34 / 2.15
    on_log = [ChunkProfile(t, 0.0, -0.18 + slope * t, R_M) for t in (0.25, 0.75, 1.25, 1.75)]
    past_off = [ChunkProfile(t, 0.0, h, R_M) for t, h in ((2.63, -0.08), (3.11, -0.15))]
    past_on = [ChunkProfile(t, 0.0, -0.18 + slope * t, R_M) for t in (2.63, 3.11)]
    off = run_on_evidence_nats(a, b, ridge, False, on_log + past_off, RUN_ON, FCFG)
    on = run_on_evidence_nats(a, b, ridge, False, on_log + past_on, RUN_ON, FCFG)
    assert off == pytest.approx(-2 * math.log(CFG.outlier_prior), rel=0.05)  # each chunk as sure as a wrong point
    assert on < -2.0
    # the chunks on the log's own side of the point say nothing about its running on
    assert run_on_evidence_nats(a, b, ridge, False, on_log, RUN_ON, FCFG) == 0.0
    # end a, 1.2 m inside the ridge: an outlier by the run-on's length alone, not where the ridge leaves its line
    alone = point_cost(a, ridge, False, CFG, FCFG, outlier_prob=True)
    assert alone > CFG.outlier_flag_prob
    assert point_cost(a, ridge, False, CFG, FCFG, outlier_prob=True, run_on_evidence=off) < CFG.outlier_flag_prob
    assert point_cost(a, ridge, False, CFG, FCFG, outlier_prob=True, run_on_evidence=on) > alone
    # never cheaper than a ridge ending at the point
    assert point_cost(a, ridge, False, CFG, FCFG, run_on_evidence=100.0) >= point_cost(
        _fixed(3.35, 0.0, 0.09 + 0.16), ridge, False, CFG, FCFG) - 1e-9
    assert run_on_evidence_nats(a, b, ridge, False, on_log + past_off, CFG, FCFG) == 0.0  # off by default
    # float points (20 cm across, 50 up) draw no line the 30 cm search window can test: the chunks say little
    fa, fb = SurveyEnd(a.position_m, 0.2, 0.5, "rtk_float"), SurveyEnd(b.position_m, 0.2, 0.5, "rtk_float")
    assert abs(run_on_evidence_nats(fa, fb, ridge, False, on_log + past_on, RUN_ON, FCFG)) < 1.0


def test_an_outlying_other_point_draws_no_line_for_the_chunks_to_test():
    # a flat log on the first 2.15 m of a 3.35 m ridge, the ridge past its end a 12-14 cm lower
    ridge = _ridge(0.0, 3.35)
    a, b = _fixed(2.15, 0.0), _fixed(0.0, 0.0)
    chunks = [ChunkProfile(t, 0.0, h, R_M) for t, h in ((2.63, -0.12), (3.11, -0.14))]
    believed = point_costs((a, b), ridge, True, RUN_ON, FCFG, chunks=chunks)
    assert believed[0] < point_costs((a, b), ridge, True, CFG, FCFG, chunks=chunks)[0] - 2.0
    # b 1.2 m under the ridge: an outlier on it, so the line through it says nothing about the ridge past a
    wrong_b = _fixed(0.0, 0.0, 0.09 - 1.2)
    assert point_cost(wrong_b, ridge, True, CFG, FCFG, outlier_prob=True) > 0.99
    assert point_costs((a, wrong_b), ridge, True, RUN_ON, FCFG, chunks=chunks)[0] == pytest.approx(
        point_costs((a, wrong_b), ridge, True, CFG, FCFG, chunks=chunks)[0], abs=0.05)


def test_revision_16s_parameters_are_checked():
    for name in ("ridge_line_min_chunks", "ridge_line_sigma_floor_m", "ridge_direction_sigma_m"):
        with pytest.raises(ValueError, match=name):
            JointConfig(**{name: 0})
