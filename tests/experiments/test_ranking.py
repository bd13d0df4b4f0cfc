"""experiments.ranking: the within-pile AUC, the calibration table and the choices from trial records."""

import math

import pytest

from experiments.ranking import calibration, choices, ranking_markdown, ranking_metrics, within_pile_auc


def _r(seed, u, ok, tau=1, b=1.0):
    return {"seed": seed, "u": u, "success": ok, "tau": tau, "b": b}


def test_auc_compares_grasps_within_a_pile_only():
    """Pile 1 ranks perfectly, pile 2 inversely (2 pairs each); pile 3 has no failure. Pooled
    across piles, pile 1's high-U failure would beat pile 2's success — within piles it does not."""
    recs = [_r(1, 0.9, True), _r(1, 0.8, False), _r(1, 0.7, False),
            _r(2, 0.3, True), _r(2, 0.4, False), _r(2, 0.5, False),
            _r(3, 0.99, True)]
    a = within_pile_auc(recs)
    assert a == {"auc": 0.5, "pairs": 4, "piles": 2}
    recs[4]["u"] = 0.2  # pile 2 now ranks one of its failures below its success
    assert within_pile_auc(recs)["auc"] == 0.75


def test_auc_counts_ties_half_and_is_undefined_without_mixed_piles():
    assert within_pile_auc([_r(1, 0.5, True), _r(1, 0.5, False)])["auc"] == 0.5
    assert math.isnan(within_pile_auc([_r(1, 0.5, True), _r(2, 0.4, False)])["auc"])


def test_calibration_bins_predicted_against_observed():
    recs = [_r(1, 0.97, True), _r(1, 0.96, False), _r(2, 0.995, True), _r(2, 1.0, True), _r(3, 0.3, False)]
    c = calibration(recs, edges=(0.0, 0.5, 0.99, 1.0))
    assert [b["n"] for b in c["bins"]] == [1, 2, 2]  # 1.0 falls in the last, closed bin
    assert c["bins"][1]["success"] == 0.5 and math.isclose(c["bins"][1]["mean_u"], 0.965)
    assert c["bins"][2]["success"] == 1.0
    gaps = 1 * 0.3 + 2 * abs(0.965 - 0.5) + 2 * abs(0.9975 - 1.0)
    assert math.isclose(c["ece"], gaps / 5)
    assert math.isclose(c["brier"], (0.03 ** 2 + 0.96 ** 2 + 0.005 ** 2 + 0 + 0.3 ** 2) / 5)


def test_choices_follow_f1_f3_and_the_best_tried():
    """f3 prefers the two-log, level grasp over the slightly higher U of the one-log grasp."""
    recs = [_r(1, 0.95, False, tau=1), _r(1, 0.94, True, tau=2, b=0.99),
            _r(2, 0.9, False), _r(2, 0.8, False)]
    c = choices(recs)
    assert c == {"piles": 2, "f1_success": 0.0, "f3_success": 0.5, "best_tried_success": 0.5}


def test_metrics_and_table_need_records():
    with pytest.raises(ValueError, match="no trial records"):
        ranking_metrics([])
    m = ranking_metrics([_r(1, 0.9, True), _r(1, 0.8, False)])
    text = ranking_markdown(m, "test")
    assert "within-pile AUC of U: **1.000**" in text and "| [0.8, 0.9) | 1 | 0.800 | 0.0 % |" in text


def test_paired_choices_count_the_piles_each_scorer_alone_gets_right():
    from experiments.ranking import paired_choices, within_pile_auc

    recs = [_r(1, 0.9, False), _r(1, 0.5, True), _r(2, 0.9, True), _r(2, 0.5, False), _r(3, 0.9, True)]
    for r, p in zip(recs, (0.2, 0.8, 0.1, 0.6, 0.5)):
        r["p"] = p
    # pile 1: U picks the failure, p the success; pile 2: the other way round; pile 3: both succeed
    assert paired_choices(recs)["f1"] == {"wins": 1, "losses": 1}
    recs[3]["success"] = True  # pile 2: p's choice succeeds too
    assert paired_choices(recs)["f1"] == {"wins": 1, "losses": 0}
    assert within_pile_auc(recs, "p")["auc"] == 1.0


def test_rescore_needs_one_scorer_and_a_ranking_folder(tmp_path):
    """rescore refuses two scorers or none, and a folder without the run's collect.json (e.g. its
    records/ sub-folder), before loading any network."""
    from experiments.ranking import rescore

    with pytest.raises(ValueError, match="exactly one scorer"):
        rescore(tmp_path, ranker="r.safetensors", model="m.safetensors")
    with pytest.raises(ValueError, match="exactly one scorer"):
        rescore(tmp_path)
    with pytest.raises(ValueError, match="no collect.json"):
        rescore(tmp_path, model="missing.safetensors")


def test_balance_agreement_compares_predicted_and_measured_tilt_of_successes_only():
    """Predicted beta against the twin's over successful grasps: a monotone prediction ranks 1.0 and its
    error is the mean gap in degrees; failures (no tilt) and records without a prediction are left out."""
    import math

    from experiments.ranking import balance_agreement

    c = lambda deg: math.cos(math.radians(deg))  # noqa: E731
    recs = [{"success": True, "cos_beta": c(t), "b": c(p)} for t, p in ((4, 6), (8, 10), (12, 14), (20, 22))]
    recs += [{"success": False, "cos_beta": None, "b": c(30)}, {"success": True, "cos_beta": c(5), "b": None}]
    a = balance_agreement(recs)
    assert a["n"] == 4 and a["spearman"] == pytest.approx(1.0)
    assert a["mae_deg"] == pytest.approx(2.0, abs=1e-6) and a["true_mean_deg"] == pytest.approx(11.0, abs=1e-6)
    flipped = [dict(r, b=c(30 - math.degrees(math.acos(r["b"])))) for r in recs[:4]]
    assert balance_agreement(flipped)["spearman"] == pytest.approx(-1.0)
    assert math.isnan(balance_agreement(recs[:2])["spearman"])
