"""The scan plan sized from the survey (reconstruct.scan.plan): the grid covers every surveyed end plus
its margin and sigmas, a compact pile keeps the 2x2 grid, bad input is a one-line error."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruct.errors import ScanPlanError
from reconstruct.scan.plan import ScanPlan, ScanPlanConfig, plan_scan, survey_yaw

CFG = ScanPlanConfig()


def two_by_two(centre=(0.0, 0.0), yaw=0.0) -> ScanPlan:
    return ScanPlan((2, 2), centre, yaw, (CFG.spacing_along_m, CFG.spacing_across_m), CFG.height_m, 0.0)


def test_footprint_is_the_twins_stereo_cover():
    """At the ground, one pair sees 2.8 x 1.57 m (hfov 50 deg, 16:9, 3 m) less the matcher's disparity band
    on the left (~122 px, ~0.27 m: a 2x2 twin cloud reaches 1.15 m left of a pair, 1.40 m right) and the
    8 px border."""
    lo_a, hi_a, lo_c, hi_c = CFG.footprint_slopes()
    assert 3 * lo_a == pytest.approx(-1.14, abs=0.02) and 3 * hi_a == pytest.approx(1.39, abs=0.01)
    assert 3 * hi_c == pytest.approx(0.77, abs=0.01) and lo_c == -hi_c


def test_a_compact_pile_keeps_2x2():
    """Ends well inside the 2x2 footprint (a 2.5 x 1.2 m pile of fixed points): the plan is 2x2 (never
    smaller: min_grid), centred on the ends, and covers each with at least the margin."""
    ends = np.array([[-1.25, -0.3, 0.1], [1.25, -0.3, 0.1], [-1.25, 0.3, 0.2], [1.25, 0.3, 0.2],
                     [-1.0, 0.0, 0.4], [1.0, 0.0, 0.4]])
    plan = plan_scan(ends, 0.015, 0.0)
    assert plan.grid == (2, 2) and plan.n_pairs == 4
    assert plan.slack_m(ends, CFG).min() >= CFG.margin_m + CFG.n_sigma * 0.015 - 1e-9


def test_an_end_just_outside_2x2_gets_a_bigger_grid():
    """An end 5 cm past the 2x2 grid's footprint across (plus the margin): the plan grows across only,
    and then covers it with the margin; the same end 5 cm inside keeps 2x2."""
    lo_a, hi_a, lo_c, hi_c = CFG.footprint_slopes()
    edge = CFG.spacing_across_m / 2 + CFG.height_m * hi_c  # the 2x2 grid's footprint edge across, at the ground
    sig = 0.015
    grow = CFG.margin_m + CFG.n_sigma * sig
    core = np.array([[-1.0, -0.5, 0.0], [1.0, -0.5, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    for offset, grid in ((-0.05, (2, 2)), (0.05, (2, 3))):
        # a symmetric pile: both across sides reach the same distance
        ends = np.vstack([core, [[0.0, edge - grow + offset, 0.0], [0.0, -(edge - grow + offset), 0.0]]])
        plan = plan_scan(ends, sig, 0.0)
        assert plan.grid == grid, offset
        assert plan.slack_m(ends, CFG).min() >= grow - 1e-9
    # the old 2x2 grid leaves the far end short of the margin
    assert two_by_two().slack_m(ends, CFG).min() < grow


def test_the_plan_covers_a_spread_turned_pile_with_sigmas():
    """A loose pile turned 30 deg, its ends spread over 5 x 4 m, some of them float points (25 cm): every
    end lies inside the planned footprint by its margin plus 2 sigma, and one pair fewer on either axis
    would leave one out."""
    rng = np.random.default_rng(3)
    yaw = math.radians(30)
    R = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    local = rng.uniform([-2.5, -2.0], [2.5, 2.0], size=(12, 2))
    ends = np.column_stack([local @ R.T + [10.0, -4.0], rng.uniform(0, 0.6, 12)])
    sig = np.where(np.arange(12) < 3, 0.25, 0.015)
    plan = plan_scan(ends, sig, yaw)
    assert plan.grid[0] > 2 and plan.grid[1] > 2
    assert (plan.slack_m(ends, CFG) >= CFG.margin_m + CFG.n_sigma * sig - 1e-9).all()
    for k in (0, 1):
        smaller = list(plan.grid)
        smaller[k] -= 1
        best = max(  # the smaller grid, at the best centre along that axis
            (ScanPlan(tuple(smaller), tuple(np.asarray(plan.centre_xy) + plan.axes()[k] * t), yaw, plan.spacing_m,
                      plan.height_m, 0.0).slack_m(ends, CFG) - (CFG.margin_m + CFG.n_sigma * sig)).min()
            for t in np.linspace(-1.0, 1.0, 81))
        assert best < 0, k


def test_a_high_end_needs_more_than_the_same_end_on_the_ground():
    """The footprint shrinks with height: an end 1 m up at the footprint's ground edge is outside."""
    lo_a, hi_a, _, _ = CFG.footprint_slopes()
    x = CFG.spacing_along_m / 2 + CFG.height_m * hi_a - 0.01
    assert two_by_two().slack_m(np.array([[x, 0.0, 0.0]]), CFG)[0] > 0
    assert two_by_two().slack_m(np.array([[x, 0.0, 1.0]]), CFG)[0] < 0


def test_survey_yaw_follows_the_logs_either_way_round():
    a = [np.array([0.0, 0.0]), np.array([1.0, 1.0])]
    pairs = [(a[0], a[1]), (np.array([3.0, 3.0]), np.array([2.0, 2.0])), (None, np.array([5.0, 0.0]))]
    assert survey_yaw(pairs) == pytest.approx(math.radians(45))
    assert survey_yaw([(None, np.zeros(2))]) == 0.0


@pytest.mark.parametrize("kw, word", [({"margin_m": -0.1}, "margin_m"), ({"n_sigma": -1.0}, "n_sigma"),
                                      ({"spacing_along_m": 3.0}, "gaps"), ({"min_grid": (0, 2)}, "min_grid"),
                                      ({"margin_m": float("nan")}, "margin_m"), ({"height_m": 0.0}, "height_m")])
def test_bad_config_is_a_value_error(kw, word):
    with pytest.raises(ValueError, match=word) as exc:
        ScanPlanConfig(**kw)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("points, sig, word", [(np.zeros((0, 3)), 0.01, "N >= 1"), (np.zeros((2, 2)), 0.01, "(N, 3)"),
                                               ([[0.0, float("nan"), 0.0]], 0.01, "finite"),
                                               ([[0.0, 0.0, 0.0]], -0.1, "sigmas >= 0"),
                                               ([[0.0, 0.0, 2.0]], 0.01, "scan from higher"),
                                               ([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0]], 0.01, "far off")])
def test_bad_survey_is_a_one_line_scan_plan_error(points, sig, word):
    with pytest.raises(ScanPlanError, match=word) as exc:
        plan_scan(np.asarray(points, dtype=float), sig, 0.0)
    assert "\n" not in str(exc.value)
