"""planner.balance: the tilt a gripped load hangs with, from its mask and mass."""

import math

import numpy as np
import pytest

from planner.balance import HangModel, principal_axis, tilt_deg


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
    assert np.unravel_index(np.argmax(out[0]), out[0].shape)[1] in {6, 7}  # level across the bar's middle
    assert out[0, 4, 0] < out[0, 4, 3] < out[0, 4, 6]
    assert np.all(out[1] == 1.0)  # an empty mask: nothing to tilt


def test_only_the_offset_along_the_load_tilts_it():
    """The claws gather a load across its logs as they close: a grasp beside the centroid of a bar (across
    it) hangs level, one along it tilts; the first version (radial) tilted both."""
    masks = np.zeros((1, 40, 40), bool)
    for k in range(30):  # a diagonal bar, rows and columns 5..34, three pixels wide
        masks[0, 5 + k, max(k + 4, 0):k + 7] = True
    along = HangModel().cos_beta_maps(masks, 0.1, [300.0])[0]
    radial = HangModel(offset="radial").cos_beta_maps(masks, 0.1, [300.0])[0]
    r0, c0 = np.argwhere(masks[0]).mean(axis=0).round().astype(int)
    across, down = (r0 - 6, c0 + 6), (r0 + 8, c0 + 8)  # 0.85 m across the bar; 1.1 m along it
    assert along[across] > 0.995 and radial[across] < 0.9
    assert along[down] == pytest.approx(radial[down], abs=2e-3) and along[down] < 0.97
    ar, ac = principal_axis(*np.nonzero(masks[0]))
    assert abs(abs(ar) - math.sqrt(0.5)) < 0.02 and abs(abs(ac) - math.sqrt(0.5)) < 0.02


def test_an_evaluation_record_names_the_hang_model_it_was_made_with(tmp_path, monkeypatch):
    """A hang row's fingerprint carries the model's offset and parameters: records made with another
    hang model (the first, radial one) are made again, not reused."""
    import planner.balance as balance
    from planner.evaluate import PlannerSpec, _fingerprint

    ckpt = tmp_path / "m.safetensors"
    ckpt.write_bytes(b"weights")
    spec = PlannerSpec("unet", model=str(ckpt), objective="f3", balance="hang")
    now = _fingerprint(spec)
    assert now.endswith("+hang-along_axis-0.95m-110kgm")
    monkeypatch.setattr(balance, "HangModel", lambda: HangModel(offset="radial"))
    assert _fingerprint(spec) != now


def test_bad_parameters_and_inputs_are_refused():
    with pytest.raises(ValueError, match="load_drop_m"):
        HangModel(load_drop_m=0.0)
    with pytest.raises(ValueError, match="grapple_moment_kg_m"):
        HangModel(grapple_moment_kg_m=-1.0)
    with pytest.raises(ValueError, match="mass"):
        HangModel().lever_m(0.0)
    with pytest.raises(ValueError, match="offset"):
        HangModel(offset="sideways")
    with pytest.raises(ValueError, match="load masses"):
        HangModel().cos_beta_maps(np.zeros((2, 4, 4), bool), 0.1, [1.0])


def test_f3_tolerance_defaults_to_the_one_chosen_for_its_balance_source():
    from planner.inference import HANG_SIGMA_B, SIGMA_B, Objective, f3_sigma_b

    assert (f3_sigma_b("hang"), f3_sigma_b("network"), f3_sigma_b("hang", 0.2)) == (HANG_SIGMA_B, SIGMA_B, 0.2)
    for balance, sigma_b in (("hang", 0.0), ("network", -1.0), ("guess", None)):
        with pytest.raises(ValueError, match="sigma_b|balance"):
            Objective("f3", balance=balance, sigma_b=f3_sigma_b(balance, sigma_b))


def test_the_plan_picture_says_which_balance_f3_scores():
    from planner.inference import Objective
    from planner.pictures import score_formula

    assert score_formula(Objective("f3")).endswith("0.25²)   (objective f3)")
    hang = score_formula(Objective("f3", balance="hang", sigma_b=0.05))
    assert "/ 0.05²)" in hang and hang.endswith("(objective f3, B from the hang model)")
    assert score_formula(Objective("f1", balance="hang")) == "Q = U   (objective f1)"
