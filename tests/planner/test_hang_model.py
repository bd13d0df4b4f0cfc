"""planner.balance: the tilt a gripped load hangs with, from its mask and mass."""

import math

import numpy as np
import pytest

from planner.balance import HangModel, tilt_deg


def test_the_tilt_follows_the_moments_about_the_pivot():
    """tan(beta) = d / (h_load + M_grapple / m_load): 0.5 m off a 100 kg load with h 0.95 m and 110 kg m
    tilts atan(0.5 / 2.05); a heavier load tilts more for the same offset; a centred one not at all."""
    m = HangModel(load_drop_m=0.95, grapple_moment_kg_m=110.0)
    assert m.lever_m(100.0) == pytest.approx(2.05)
    assert tilt_deg(m.cos_beta(0.5, 100.0)) == pytest.approx(math.degrees(math.atan(0.5 / 2.05)))
    assert tilt_deg(m.cos_beta(0.5, 400.0)) > tilt_deg(m.cos_beta(0.5, 100.0)) + 3
    assert m.cos_beta(0.0, 100.0) == pytest.approx(1.0)


def test_maps_are_level_at_the_mask_centroid_and_tilt_away_from_it():
    masks = np.zeros((2, 16, 16), bool)
    masks[0, 4:6, 2:12] = True  # a bar, centroid (4.5, 6.5)
    out = HangModel().cos_beta_maps(masks, 0.1, [150.0, 150.0])
    assert out.shape == (2, 16, 16) and out.dtype == np.float32
    assert np.unravel_index(np.argmax(out[0]), out[0].shape) in {(4, 6), (4, 7), (5, 6), (5, 7)}
    assert out[0, 4, 0] < out[0, 4, 3] < out[0, 4, 6]
    assert np.all(out[1] == 1.0)  # an empty mask: nothing to tilt


def test_bad_parameters_and_inputs_are_refused():
    with pytest.raises(ValueError, match="load_drop_m"):
        HangModel(load_drop_m=0.0)
    with pytest.raises(ValueError, match="grapple_moment_kg_m"):
        HangModel(grapple_moment_kg_m=-1.0)
    with pytest.raises(ValueError, match="mass"):
        HangModel().lever_m(0.0)
    with pytest.raises(ValueError, match="load masses"):
        HangModel().cos_beta_maps(np.zeros((2, 4, 4), bool), 0.1, [1.0])


def test_f3_tolerance_defaults_to_the_one_chosen_for_its_balance_source():
    from planner.inference import HANG_SIGMA_B, SIGMA_B, f3_sigma_b

    assert (f3_sigma_b("hang"), f3_sigma_b("network"), f3_sigma_b("hang", 0.2)) == (HANG_SIGMA_B, SIGMA_B, 0.2)
    for bad in ((("hang", 0.0)), ("network", -1.0), ("guess", None)):
        with pytest.raises(ValueError, match="sigma_b|balance"):
            f3_sigma_b(*bad)


def test_the_plan_picture_says_which_balance_f3_scores():
    from planner.inference import Objective
    from planner.pictures import score_formula

    assert score_formula(Objective("f3")).endswith("0.25²)   (objective f3)")
    hang = score_formula(Objective("f3", balance="hang", sigma_b=0.05))
    assert "/ 0.05²)" in hang and hang.endswith("(objective f3, B from the hang model)")
    assert score_formula(Objective("f1", balance="hang")) == "Q = U   (objective f1)"
