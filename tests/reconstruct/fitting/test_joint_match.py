"""The joint matching's shared scan offset (reconstruct.fitting.joint_pose) and a ridge that runs on past its
log's end (joint_match.run_on_nats): logs between two ridges, a hidden log, a missed log, a merged ridge; a
ridge's radius and the open ground past it (joint_ridge, joint revision 15)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_match import coverage_nats, joint_match, point_cost, run_on_nats
from reconstruct.fitting.joint_pose import pose_offset
from reconstruct.fitting.joint_ridge import (HeightRaster, RidgeEvidence, chunk_radii, not_one_log_nats, open_length_m,
                                             radius_sigma)
from reconstruct.fitting.scan_logs import ScanLog
from reconstruct.fitting.survey_points import SurveyEnd

CFG, FCFG = JointConfig(), FuseConfig()
OFF = replace(CFG, match_pose_offset=False)
SPACING_M = 0.18  # a packed pile's logs side by side (two 9 cm radii)
SHIFT_M = 0.11  # the scan pose's error across them before registration: past half the spacing


def _ridge(y: float, x0: float = 0.0, x1: float = 2.5, z: float = 0.09) -> ScanLog:
    return ScanLog(np.array([x0, y, z]), np.array([x1, y, z]), 0.09, abs(x1 - x0), 20.0)


def _fixed(x: float, y: float, z: float = 0.09) -> SurveyEnd:
    return SurveyEnd(np.array([x, y, z]), 0.015 / math.sqrt(2), 0.025, "rtk_fixed")


def _packed(n: int, shift_m: float) -> tuple[dict, list[ScanLog]]:
    """``n`` logs side by side, each on its own ridge; the survey (every point RTK fixed) off the scan by
    ``shift_m`` across them, as a scan pose that far off puts it."""
    ridges = [_ridge(k * SPACING_M) for k in range(n)]
    survey = {f"log{k}": (_fixed(0.0, k * SPACING_M + shift_m), _fixed(2.5, k * SPACING_M + shift_m))
              for k in range(n)}
    return survey, ridges


def test_logs_whose_points_lie_between_two_ridges_each_take_their_own_when_the_offset_is_shared():
    survey, ridges = _packed(3, SHIFT_M)
    m = joint_match(survey, ridges, CFG, FCFG)
    assert {k: m.matches[k].scan_index for k in survey} == {"log0": 0, "log1": 1, "log2": 2}
    assert m.pose_offset_m[1] == pytest.approx(-SHIFT_M, abs=0.01) and m.unmatched == []
    assert all(not o for o in m.outliers.values())
    # each point scored alone, the logs slip one ridge over: the first ridge is left over, the last log hidden
    alone = joint_match(survey, ridges, OFF, FCFG)
    assert [alone.matches[k].scan_index for k in survey] != [0, 1, 2]


def test_the_offset_is_shared_so_it_cannot_put_a_hidden_log_on_another_logs_ridge():
    # log0 and log1 sit on their ridges; log2's fixed points lie 11 cm beside log1's ridge with no ridge of its
    # own (hidden under others): moving the survey onto it would move the other two off theirs
    ridges = [_ridge(0.0), _ridge(SPACING_M)]
    survey = {"log0": (_fixed(0.0, 0.0), _fixed(2.5, 0.0)),
              "log1": (_fixed(0.0, SPACING_M), _fixed(2.5, SPACING_M)),
              "log2": (_fixed(0.0, SPACING_M + SHIFT_M), _fixed(2.5, SPACING_M + SHIFT_M))}
    m = joint_match(survey, ridges, CFG, FCFG)
    assert {k: m.matches[k].scan_index for k in survey} == {"log0": 0, "log1": 1, "log2": None}
    assert np.linalg.norm(m.pose_offset_m) < 0.02


def test_a_long_ridge_no_surveyed_log_explains_is_left_over_not_taken_by_moving_the_survey():
    # one surveyed log on its ridge and a long ridge 30 cm beside it that the survey missed
    ridges = [_ridge(0.0), _ridge(0.30)]
    survey = {"log0": (_fixed(0.0, 0.0), _fixed(2.5, 0.0))}
    m = joint_match(survey, ridges, CFG, FCFG)
    assert m.matches["log0"].scan_index == 0 and m.unmatched == [1]
    assert np.linalg.norm(m.pose_offset_m) < 0.02


def test_the_offset_is_the_assignments_minimum_pulled_toward_zero_by_its_prior():
    # a Gaussian cost about 6 cm across (sigma 3 cm) and the prior's 4 cm: the posterior mode is the weighted mean
    m_m, s_m, prior_m = np.array([0.0, 0.06, 0.0]), 0.03, FCFG.pose_sigma_m

    def cost_at(d):
        return 0.5 * float((d - m_m) @ (d - m_m)) / s_m ** 2

    d = pose_offset(cost_at, prior_m, CFG)
    assert d == pytest.approx(m_m * prior_m ** 2 / (prior_m ** 2 + s_m ** 2), abs=2e-3)
    assert np.allclose(pose_offset(lambda d: 5.0, prior_m, CFG), 0.0, atol=1e-3)  # nothing to say: the prior's 0


def test_a_log_whose_ridge_runs_on_past_both_its_points_takes_that_ridge():
    # the scan's ridge merges the log with what lies in line: it runs 35 cm past each of its RTK fixed points
    ridges = [_ridge(0.0, -0.45, 2.95), _ridge(0.6)]
    survey = {"log0": (_fixed(0.0, 0.0), _fixed(2.5, 0.0)), "log1": (_fixed(0.0, 0.6), _fixed(2.5, 0.6))}
    m = joint_match(survey, ridges, CFG, FCFG)
    assert m.matches["log0"].scan_index == 0 and m.outliers["log0"] == set()
    gauss_only = joint_match(survey, ridges, replace(CFG, ridge_run_on=False), FCFG)
    assert gauss_only.matches["log0"].scan_index is None  # both points outliers on it: hidden


def test_a_ridge_running_on_costs_a_gaussian_near_the_end_and_a_bounded_rate_past_it():
    s = 0.025
    assert run_on_nats(0.0, s, CFG) == pytest.approx(0.0, abs=0.02)
    assert run_on_nats(0.01, s, CFG) == pytest.approx(0.5 * (0.01 / s) ** 2, abs=0.02)
    far, farther = run_on_nats(0.3, s, CFG), run_on_nats(0.5, s, CFG)
    assert farther - far == pytest.approx(0.2 / CFG.ridge_run_on_mean_m, rel=1e-3)
    assert far < 0.5 * (0.3 / s) ** 2 / 10
    assert run_on_nats(0.3, s, replace(CFG, ridge_run_on=False)) == pytest.approx(0.5 * (0.3 / s) ** 2)
    # a point 30 cm inside a ridge is no outlier of it; 30 cm across it is
    ridge = _ridge(0.0)
    assert point_cost(_fixed(0.3, 0.0), ridge, True, CFG, FCFG, outlier_prob=True) < CFG.outlier_flag_prob
    assert point_cost(_fixed(0.0, 0.3), ridge, True, CFG, FCFG, outlier_prob=True) > CFG.outlier_flag_prob


def test_the_matchings_new_parameters_are_checked():
    with pytest.raises(ValueError, match="ridge_run_on_prior"):
        JointConfig(ridge_run_on_prior=1.0)
    with pytest.raises(ValueError, match="ridge_run_on_mean_m"):
        JointConfig(ridge_run_on_mean_m=0.0)
    with pytest.raises(ValueError, match="match_pose_step_m"):
        JointConfig(match_pose_step_m=-0.02)
    with pytest.raises(ValueError, match="match_pose_reach_sigmas"):
        JointConfig(match_pose_reach_sigmas=0.0)


# -- joint revision 15: the ridge's radius and the open ground past it (joint_ridge) --

def _ground_and_top(x0: float, x1: float, y: float, top_z: float, step: float = 0.01) -> np.ndarray:
    """The scan of open ground (z = 0) over x -1..4, y -0.5..0.5 with a log's top (``top_z``) over ``x0``-``x1``
    along ``y``."""
    xs, ys = np.meshgrid(np.arange(-1.0, 4.0, step), np.arange(-0.5, 0.5, step))
    P = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    on = (P[:, 0] > x0) & (P[:, 0] < x1) & (np.abs(P[:, 1] - y) < 0.06)
    P[on, 2] = top_z
    return P


def test_a_3cm_ridge_beside_a_surveyed_log_whose_fixed_points_lie_off_it_is_left_unexplained():
    # the only ridge has a 3 cm radius (its chunks agree to 5 mm) and runs on 1 m past the log's RTK fixed
    # points, which lie 8 cm either side of it (no shared offset puts both on it): taking it costs their misfit
    # and its radius, less than hiding the log and leaving a 3.5 m ridge over costs without its radius
    ridge = ScanLog(np.array([-1.0, 0.0, 0.09]), np.array([2.5, 0.0, 0.09]), 0.03, 3.5, 20.0)
    survey = {"log0": (_fixed(0.0, 0.08), _fixed(2.5, -0.08))}
    sure = RidgeEvidence((0.005,))
    m = joint_match(survey, [ridge], CFG, FCFG, sure)
    assert m.matches["log0"].scan_index is None and m.unmatched == [0]
    # without its radius the ridge is taken; a 9 cm ridge is taken with it; so is a 3 cm one whose chunks
    # disagree (its radius unsure)
    assert joint_match(survey, [ridge], replace(CFG, ridge_radius_evidence=False), FCFG, sure
                       ).matches["log0"].scan_index == 0
    assert joint_match(survey, [replace(ridge, radius_m=0.09)], CFG, FCFG, sure).matches["log0"].scan_index == 0
    assert joint_match(survey, [ridge], CFG, FCFG, RidgeEvidence((0.05,))).matches["log0"].scan_index == 0


def test_a_ridges_radius_is_evidence_against_one_log_only_outside_the_fields_radii_within_its_sigma():
    assert not_one_log_nats(0.09, 0.005, CFG) == 0.0 and not_one_log_nats(0.19, 0.005, CFG) == 0.0
    thin, thick = not_one_log_nats(0.03, 0.005, CFG), not_one_log_nats(0.25, 0.005, CFG)
    assert thin > 5.0 and thick > 5.0 and thin <= CFG.not_one_log_max_nats
    assert not_one_log_nats(0.03, 0.05, CFG) < 1.0  # an unsure radius says little
    # the radius's sigma: its chunks' RMS about the whole run's radius, floored; the prior with under two chunks
    assert radius_sigma([0.03, 0.03, 0.031], 0.03, CFG) == CFG.ridge_radius_sigma_floor_m
    assert radius_sigma([0.07, 0.08, 0.09], 0.03, CFG) == pytest.approx(math.sqrt((16 + 25 + 36) / 2) * 0.01)
    assert radius_sigma([0.08], 0.08, CFG) == CFG.ridge_radius_sigma_prior_m


def test_a_ridges_chunks_are_fitted_with_the_profile_of_the_whole_run():
    # a 9 cm log's upper half seen from above, its ridge found 3 cm thin: every 0.5 m chunk says 9 cm
    xs, ang = np.meshgrid(np.arange(0.0, 2.0, 0.01), np.linspace(0.05, math.pi - 0.05, 40))
    r = 0.09
    P = np.column_stack([xs.ravel(), r * np.cos(ang.ravel()), r + r * np.sin(ang.ravel())])
    ground = _ground_and_top(0.0, 0.0, 0.0, 0.0)
    ground = ground[(np.abs(ground[:, 1]) > r) & (ground[:, 0] > 0) & (ground[:, 0] < 2)]
    ridge = ScanLog(np.array([0.0, 0.0, 2 * r - 0.03]), np.array([2.0, 0.0, 2 * r - 0.03]), 0.03, 2.0, 20.0)
    radii = chunk_radii(np.vstack([P, ground]), ridge, CFG)
    assert len(radii) == 4 and all(abs(x - r) <= 0.01 for x in radii)
    assert radius_sigma(radii, ridge.radius_m, CFG) > 0.05  # the run's 3 cm is no sure radius


def test_a_log_on_a_short_scrap_is_dearer_than_hidden_where_the_scan_sees_open_ground_along_it():
    # the log's fixed point a lies on a 30 cm scrap; its point b 3 m on, in line, lies on nothing the scan
    # found (an outlier of the scrap): over open ground that is no log; under a log across (seen high) it may be
    scrap = ScanLog(np.array([0.0, 0.0, 0.09]), np.array([0.3, 0.0, 0.09]), 0.09, 0.3, 20.0)
    survey = {"log0": (_fixed(0.0, 0.0), _fixed(3.0, 0.0))}
    open_ground = RidgeEvidence((0.005,), HeightRaster.of(_ground_and_top(0.0, 0.3, 0.0, 0.18), CFG.coverage_cell_m))
    m = joint_match(survey, [scrap], CFG, FCFG, open_ground)
    assert m.matches["log0"].scan_index is None
    assert joint_match(survey, [scrap], replace(CFG, ridge_coverage=False), FCFG, open_ground
                       ).matches["log0"].scan_index == 0
    covered = RidgeEvidence((0.005,), HeightRaster.of(_ground_and_top(0.0, 3.1, 0.0, 0.3), CFG.coverage_cell_m))
    assert joint_match(survey, [scrap], CFG, FCFG, covered).matches["log0"].scan_index == 0
    # the open length is the stretch past the scrap's end (beyond the overrun) to b
    raster = open_ground.raster
    assert open_length_m(scrap, 0.3 + CFG.ridge_overrun_m, 3.0, raster, CFG) == pytest.approx(
        2.6, abs=2 * CFG.coverage_cell_m)
    assert coverage_nats(survey["log0"], scrap, raster, CFG) == pytest.approx(
        CFG.coverage_nats_per_m * open_length_m(scrap, 0.3 + CFG.ridge_overrun_m, 3.0, raster, CFG))
    # b 2.5 m across the scrap: laid from a the log runs 2.1 m on over open ground; laid from b (its place on the
    # scrap's line 15 cm in) back toward a, off the scan's edge at -1 m after 0.9 m of it: the cheaper counts
    across = (_fixed(0.0, 0.0), _fixed(0.15, 2.5))
    from_b = open_length_m(scrap, 0.15 - math.hypot(0.15, 2.5), -CFG.ridge_overrun_m, raster, CFG)
    assert from_b == pytest.approx(0.9, abs=2 * CFG.coverage_cell_m)
    along_scrap = replace(CFG, laid_survey_direction=False)  # laid along the scrap's axis, as revision 17
    assert coverage_nats(across, scrap, raster, along_scrap) == pytest.approx(CFG.coverage_nats_per_m * from_b)


def test_the_ridge_terms_parameters_are_checked():
    with pytest.raises(ValueError, match="log_radius_min_m < log_radius_max_m"):
        JointConfig(log_radius_min_m=0.25)
    with pytest.raises(ValueError, match="log_radius_min_m < log_radius_max_m"):
        JointConfig(other_radius_span_m=0.15)
    for name in ("coverage_nats_per_m", "ridge_chunk_m", "open_drop_m", "coverage_cell_m",
                 "ridge_radius_sigma_floor_m", "not_one_log_max_nats"):
        with pytest.raises(ValueError, match=name):
            JointConfig(**{name: 0.0})
