"""experiments.f3_frontier: the span under the claws, f3's choice among tried grasps, the oracle."""

import json

import numpy as np
import pytest

from experiments.f3_frontier import f3_choice, frontier, main, oracle, span_table, target_span_m


def test_the_span_counts_only_the_target_pixels_under_the_claws():
    crop = np.zeros((9, 20), dtype=bool)
    crop[4, 3:6] = True  # on the grasp line: columns 3-5
    crop[5, 12] = True  # one row off, still under a 0.3 m plate at 0.1 m pixels
    crop[0, 19] = True  # 0.4 m off the line: not under the plates
    assert target_span_m(crop, 0.1, 0.3) == pytest.approx(1.0)  # columns 3..12
    assert target_span_m(crop, 0.1, 0.1) == pytest.approx(0.3)  # the line's row alone
    assert target_span_m(np.zeros((9, 20), dtype=bool), 0.1, 0.3) == 0.0


def _rec(seed, tau, u, p, success, outcome="success", b=1.0):
    return {"seed": seed, "tau": tau, "u": u, "p": p, "b": b, "success": success,
            "outcome": outcome if success else "not_closed"}


# pile 1: U ranks the wide failing bundle first, p the two-log success; pile 2: one success only
RECORDS = [_rec(1, 5, 0.99, 0.2, False), _rec(1, 2, 0.97, 0.9, True), _rec(2, 3, 0.9, 0.8, True),
           _rec(2, 4, 0.95, 0.1, False)]


def test_f3_chooses_by_the_score_given_and_counts_logs_per_success():
    by_u = f3_choice(RECORDS, np.array([r["u"] for r in RECORDS]))
    by_p = f3_choice(RECORDS, np.array([r["p"] for r in RECORDS]))
    assert (by_u["successes"], by_u["piles"]) == (0, 2)
    assert (by_p["successes"], by_p["logs_per_success"]) == (2, 2.5)


def test_the_oracle_takes_the_successful_grasp_with_most_targets():
    recs = RECORDS + [_rec(1, 4, 0.5, 0.5, True)]
    assert oracle(recs) == {"piles": 2, "successes": 2, "logs_per_success": 3.5}


def test_the_frontier_spans_the_blend_from_u_alone_to_p_alone():
    rows = {(f["u_weight"], f["offset"]): f for f in frontier(RECORDS)}
    assert rows[(1.0, 0.0)]["successes"] == 0 and rows[(0.0, 0.0)]["successes"] == 2


def test_the_span_table_bins_grasps_by_span():
    t = span_table(RECORDS, [0.5, 0.7, 0.7, 1.5])
    assert [row["grasps"] for row in t] == [1, 2, 1]
    assert t[-1]["not_closed"] == 1.0


def test_a_file_without_the_rankers_p_is_a_one_line_error(tmp_path, capsys):
    f = tmp_path / "r.json"
    f.write_text(json.dumps([{"seed": 1, "u": 0.9}]))
    with pytest.raises(SystemExit):
        main([str(f), "--records", str(tmp_path)])
    assert "rescore --out" in capsys.readouterr().err
