"""experiments.precision_trials: paired rows against the first precision."""

from experiments.precision_trials import paired_rows, trials_markdown


def _rec(planner, seed, ok, logs=3):
    return {"planner": planner, "seed": seed, "outcome": "success" if ok else "dropped", "grasped": list(range(logs)) if ok else []}


def test_paired_rows_count_piles_won_and_lost_against_the_first_precision():
    recs = []
    for seed, (a, b) in enumerate([(1, 1), (1, 0), (0, 1), (0, 1), (1, 1)]):
        recs += [_rec("bf16/f1", seed, a, 4), _rec("int8/f1", seed, b, 2)]
    rows = paired_rows(recs)
    ref, other = rows
    assert ref["reference"] and ref["successes"] == 3 and ref["logs_per_success"] == 4
    assert not other["reference"] and (other["won"], other["lost"]) == (2, 1) and other["successes"] == 4
    assert other["diff_pp"] == 20.0 and other["lo_pp"] <= 20.0 <= other["hi_pp"]
    table = trials_markdown(rows)
    assert table[2].startswith("| bf16 | f1 | 3/5 (60.0 %) | 4.00 |  |") and "2 / 1 | +20.0 (" in table[3]
