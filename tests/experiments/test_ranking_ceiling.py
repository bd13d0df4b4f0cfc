"""experiments.ranking_ceiling: the repeats' share as a scorer of the exact outcome, within each pile."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.ranking_ceiling import ceiling, rescored_grasps, round_grasps


def _grasps(share, outcome, pile):
    outcome = np.array(outcome)
    return {"share": np.array(share, float), "exact": (outcome == "success").astype(float), "pile": np.array(pile),
            "outcome": outcome}


def test_a_share_that_orders_each_pile_reaches_one_and_its_reverse_zero():
    g = _grasps([1.0, 0.75, 0.0, 0.5, 1.0, 0.25], ["success", "success", "collision", "success", "success",
                                                    "not_closed"], ["a", "a", "a", "b", "b", "b"])
    m = ceiling(g)
    assert m["auc"] == 1.0 and m["pairs"] == 4 and m["piles"] == 2 and m["grasps"] == 6
    assert m["by_failure"]["collision"] == {"auc": 1.0, "pairs": 2, "failures": 1}
    assert m["by_failure"]["not_closed"] == {"auc": 1.0, "pairs": 2, "failures": 1}
    assert ceiling({**g, "share": 1.0 - g["share"]})["auc"] == 0.0


def test_pairs_are_only_within_a_pile_and_ties_count_half():
    g = _grasps([0.5, 0.5, 1.0, 0.0], ["success", "dropped", "dropped", "success"], ["a", "a", "b", "b"])
    m = ceiling(g)  # pile a: a tie (half), pile b: ordered the wrong way (0)
    assert m["auc"] == pytest.approx(0.25) and m["pairs"] == 2
    assert m["by_failure"]["dropped"]["failures"] == 2


def test_round_grasps_reads_a_committed_round_and_refuses_a_data_store():
    g = round_grasps("data/rounds/r0")
    assert len(g["share"]) == 606 and set(np.unique(g["share"])) <= {0.0, 0.25, 0.5, 0.75, 1.0}
    assert g["pile"][0].startswith("r0/pile_") and set(g["exact"]) == {0.0, 1.0}
    assert np.array_equal(g["exact"] == 1.0, g["outcome"] == "success")
    with pytest.raises(ValueError, match="not an on-policy round"):
        round_grasps("data/paper-v4")


def test_rescored_records_are_measured_by_their_score(tmp_path):
    import json

    recs = [{"seed": 1, "outcome": "success", "p": 0.9, "u": 0.2},
            {"seed": 1, "outcome": "not_closed", "p": 0.3, "u": 0.8},
            {"seed": 2, "outcome": "success", "p": 0.6, "u": 0.5},
            {"seed": 2, "outcome": "collision", "p": 0.7, "u": 0.1}]
    f = tmp_path / "rescored.json"
    f.write_text(json.dumps(recs))
    assert ceiling(rescored_grasps(f, "p"))["auc"] == 0.5  # pile 1 right, pile 2 wrong
    m = ceiling(rescored_grasps(f, "u"))
    assert m["by_failure"]["not_closed"]["auc"] == 0.0 and m["by_failure"]["collision"]["auc"] == 1.0
    with pytest.raises(ValueError, match="'b' score"):
        rescored_grasps(f, "b")
