import numpy as np
import pytest

from experiments.subset_outcomes import by_size, fit_logistic, rescoring_check


def _records(n_piles=60, seed=0):
    """Piles where single logs have the highest U but always fail and pairs always succeed."""
    rng = np.random.default_rng(seed)
    out = []
    for s in range(n_piles):
        for rank, (tau, u) in enumerate([(1, 0.99), (2, float(rng.uniform(0.9, 0.98))), (3, 0.5)]):
            ok = tau == 2
            out.append({"seed": s, "tau": tau, "u": u, "rank_f1": rank, "success": bool(ok)})
    return out


def test_by_size_counts_the_f1_choices():
    t = by_size(_records())
    assert t[1]["f1_choices"] == 60 and t[1]["f1_choice_success"] == 0.0 and t[2]["f1_choices"] == 0
    assert t[2]["success"] == 1.0 and t[3]["success"] == 0.0


def test_rescoring_check_finds_a_map_that_chooses_better_when_there_is_one():
    r = rescoring_check(_records(), repeats=3)
    assert r["f1 raw U"]["success"] == 0.0 and r["f1 raw U"]["logs_per_success"] != r["f1 raw U"]["logs_per_success"]
    assert r["f1 fitted"]["success"] == 1.0 and r["f1 fitted"]["logs_per_success"] == 2.0


def test_fit_logistic_recovers_a_slope():
    rng = np.random.default_rng(1)
    x = np.column_stack([rng.normal(size=4000), np.ones(4000)])
    y = (rng.random(4000) < 1 / (1 + np.exp(-(2.0 * x[:, 0] - 0.5)))).astype(float)
    assert fit_logistic(x, y, l2=1e-3) == pytest.approx([2.0, -0.5], abs=0.15)


def test_perturbations_move_the_grasp_the_way_they_say():
    import math

    from experiments.subset_outcomes import perturbed
    from synth.geometry.grasp import Grasp

    g = Grasp(1.0, 2.0, 0.0, 0.8)
    assert perturbed(g, "width_m", -0.1).width_m == pytest.approx(0.7)
    assert perturbed(g, "width_m", -5).width_m == pytest.approx(0.30)  # never below the grapple's minimum
    s = perturbed(g, "shift_m", 0.1)  # along the closing axis (pile +x at phi = 0)
    assert (s.x_m, s.y_m, s.width_m) == pytest.approx((1.1, 2.0, 0.8))
    assert perturbed(g, "angle_deg", 10).phi_rad == pytest.approx(math.radians(10))
    with pytest.raises(ValueError, match="unknown perturbation"):
        perturbed(g, "height_m", 0.1)


def test_sweep_summary_counts_rescues_of_the_failures_only():
    from experiments.subset_outcomes import sweep_summary

    recs = [{"seed": 1, "kind": "width_m", "delta": 0.0, "success": False},
            {"seed": 1, "kind": "width_m", "delta": -0.05, "success": True},
            {"seed": 2, "kind": "width_m", "delta": 0.0, "success": True},
            {"seed": 2, "kind": "width_m", "delta": -0.05, "success": True}]
    s = sweep_summary(recs)
    assert (s["piles"], s["failures"], s["rescued_by_any"]) == (2, 1, 1)
    assert s["rows"]["width_m -0.05"] == {"success": 1.0, "rescued": 1}
