"""Outcome labels: every stored trial, success or failure, becomes a label of its grasp centre."""

import gzip
import json
import math

import numpy as np
import pytest

from synth.data.shards import Sample, ShardWriter, iter_samples, load_shard
from synth.data.datastore import chunk_path, materialize
from synth.data.outcomes import (OutcomeLabelConfig, merge_centres, outcome_targets, trial_array,
                                 trial_success)
from synth.geometry.frames import OrthoGrid

GRID = OrthoGrid(64, 5.0)
CFG = OutcomeLabelConfig(tried_weight=1.0, untried_weight=0.05, capped_untried_weight=0.0)


def _px(x, y):
    r, c = GRID.pile_to_pixel(x, y)
    return int(round(float(r))), int(round(float(c)))


def _row(x, y, o, w=0.6, phi=0.3, **kw):
    return {"g": [x, y, phi, w], "o": o, "b": 0.9 if o == "success" else None, "h": [], **kw}


def test_trial_success_reads_fraction_repeats_or_outcome():
    assert trial_success({"o": "success"}) == 1.0
    assert trial_success({"o": "collision"}) == 0.0
    rows = [[0.1, 0.2, 0.3, 0.6, o] for o in ("success", "dropped", "success", "success")]
    assert trial_success({"o": "success", "r": rows}) == 0.75  # robust labels: the repeats' share
    assert trial_success({"o": "success", "r": rows[1:2]}) == 0.0  # an exact success that fails when moved
    assert trial_success({"o": "success", "r": []}) == 1.0  # no repeats ran: the exact outcome
    assert trial_success({"o": "success", "r": rows[1:2], "p": 0.4}) == 0.4  # the fraction comes first
    with pytest.raises(ValueError, match="no outcome"):
        trial_success({"g": [0, 0, 0, 0.5]})
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        trial_success({"p": 1.5})


def test_failed_centre_is_a_negative_and_successful_one_a_positive():
    trials = trial_array([_row(-1.0, 0.5, "collision"), _row(1.0, -0.5, "success")])
    t = outcome_targets(GRID, trials, capped=False, config=CFG)
    assert t.shape == (6, 64, 64)
    fail, ok = _px(-1.0, 0.5), _px(1.0, -0.5)
    assert t[3][fail] == 0.0 and t[5][fail] == 1.0  # a failed centre: label 0 at full weight
    assert t[3][ok] == 1.0 and t[5][ok] == 1.0
    assert math.isclose(t[4][ok], 0.9, abs_tol=1e-6) and math.isclose(t[2][ok], 0.6, abs_tol=1e-6)
    far = _px(2.2, 2.2)
    assert t[3][far] == 0.0 and math.isclose(t[5][far], 0.05, abs_tol=1e-6)  # untried: negative, weighted low
    assert int((t[5] == 1.0).sum()) == int((t[3] > 0).sum()) * 2  # two equal regions, one positive


def test_capped_subset_does_not_count_untried_pixels_as_negatives():
    trials = trial_array([_row(0.0, 0.0, "success")])
    open_ = outcome_targets(GRID, trials, capped=False, config=CFG)
    capped = outcome_targets(GRID, trials, capped=True, config=CFG)
    far = _px(2.0, -2.0)
    assert math.isclose(open_[5][far], 0.05, abs_tol=1e-6) and capped[5][far] == 0.0
    assert capped[5][_px(0.0, 0.0)] == 1.0


def test_overlapping_regions_take_the_nearest_trial():
    """A failure 12 cm from a success (their 20 cm regions overlap): a pixel inside the success's
    region but nearer the failure is a negative (a union of successes would mark it positive)."""
    grid = OrthoGrid(128, 5.0)
    x, y = grid.pixel_to_pile(63, 66)  # 9.8 cm from the success (inside its region), 2.2 cm from the failure
    assert abs(float(x)) <= 0.1 and abs(float(x) - 0.12) < abs(float(x)) and abs(float(y)) < 0.1
    rows = [_row(0.0, 0.0, "success", phi=0.0), _row(0.12, 0.0, "collision", phi=0.0)]
    for order in (rows, rows[::-1]):  # whichever was tried first
        t = outcome_targets(grid, trial_array(order), capped=False, config=CFG)
        assert t[3][63, 66] == 0.0 and t[5][63, 66] == 1.0
        assert t[3][63, 65] == 1.0  # 5.9 cm from the success, 6.1 cm from the failure: in both regions


def test_success_fraction_is_the_label():
    trials = trial_array([_row(0.5, 0.5, "success", p=0.7)])
    t = outcome_targets(GRID, trials, capped=False, config=CFG)
    assert math.isclose(t[3][_px(0.5, 0.5)], 0.7, abs_tol=1e-6)


def test_a_centre_retried_wider_is_worth_its_best_width():
    """Algorithm 1 tries a success again 5-10 cm wider at the same centre: the centre keeps the
    successful width, whichever order the two came in; two successes keep the wider (later) one."""
    narrow_ok_wide_fail = trial_array([_row(0, 0, "success", w=0.5), _row(0, 0, "dropped", w=0.58)])
    m = merge_centres(narrow_ok_wide_fail)
    assert len(m) == 1 and m[0, 4] == 1.0 and math.isclose(m[0, 3], 0.5)
    both_ok = trial_array([_row(0, 0, "success", w=0.5), _row(0, 0, "success", w=0.58), _row(1, 1, "collision")])
    m = merge_centres(both_ok)
    assert len(m) == 2 and math.isclose(m[0, 3], 0.58) and m[1, 4] == 0.0
    t = outcome_targets(GRID, narrow_ok_wide_fail, capped=False, config=CFG)
    assert t[3][_px(0, 0)] == 1.0 and math.isclose(t[2][_px(0, 0)], 0.5, abs_tol=1e-6)


def test_label_weights_are_checked():
    with pytest.raises(ValueError, match="untried_weight"):
        OutcomeLabelConfig(untried_weight=-0.1)
    with pytest.raises(ValueError, match="tried_weight must be > 0"):
        OutcomeLabelConfig(tried_weight=0.0)


def _sample(pid, subset, trials, capped=False):
    z = np.zeros((16, 16), np.float32)
    return Sample(pile_id=pid, render=0, subset=subset, intensity=z, depth=z + 5, target_mask=z > 0,
                  maps=np.zeros((5, 16, 16), np.float32), grasps=np.zeros((0, 5)), negative=True, n_logs=2,
                  n_candidates=len(trials) if trials is not None else None,
                  trials=None if trials is None else trial_array(trials), capped=None if trials is None else capped)


def test_shard_keeps_each_subsets_trials_and_cap(tmp_path):
    w = ShardWriter(tmp_path, "t", 0)
    w.add(_sample("p0", (0,), [_row(0, 0, "collision"), _row(1, 0, "dropped")], capped=True))
    w.add(_sample("p0", (1,), []))
    w.close()
    got = {s.subset: s for s in load_shard(tmp_path / "shard_t_00000.npz")}
    assert got[(0,)].capped is True and got[(1,)].capped is False
    assert got[(0,)].trials.shape == (2, 6) and list(got[(0,)].trials[:, 4]) == [0.0, 0.0]
    assert got[(1,)].trials.shape == (0, 6)


def test_shard_without_trials_reads_as_unrecorded(tmp_path):
    w = ShardWriter(tmp_path, "t", 0)
    w.add(_sample("p0", (0,), None))
    w.close()
    (s,) = load_shard(tmp_path / "shard_t_00000.npz")
    assert s.trials is None and s.capped is None


def test_a_shard_cannot_mix_subsets_with_and_without_trials(tmp_path):
    w = ShardWriter(tmp_path, "t", 0)
    w.add(_sample("p0", (0,), []))
    with pytest.raises(ValueError, match="all carry their trials or none"):
        w.add(_sample("p0", (1,), None))


def test_materialized_store_samples_carry_every_stored_trial(tmp_path):
    """Each materialised sample holds its subset's trials as the chunk stores them (all outcomes,
    in order; an exact success labelled by its robust repeats) and its cap flag — the store's
    failures reach the trainer."""
    from types import SimpleNamespace

    from synth.data.dataset import DatasetJob
    from synth.data.datastore import build_store

    def factory(pile, targets):  # stand-in for run_trial: grasps centred right of the pile's middle succeed
        def simulate(g):  # (robust repeats, moved 2 cm, may cross the line: fractions below 1)
            ok = g.x_m > 0
            return SimpleNamespace(success=ok, cos_beta=0.9, grasped=tuple(targets) if ok else (),
                                   outcome=SimpleNamespace(value="success" if ok else "collision"))
        return simulate

    job = DatasetJob(n_piles=2, n_logs=2, obstacles_fraction=0.0, seed=3, size_px=32, n_renders=2,
                     max_trials_per_subset=3)
    build_store(tmp_path / "s", job, simulate_factory=factory)
    want, n_robust = {}, 0
    for k in (0, 1):
        d = json.loads(gzip.decompress(chunk_path(tmp_path / "s", k).read_bytes()))
        for p in d["piles"]:
            for s in p["subsets"]:
                want[(p["pile_id"], tuple(s["targets"]))] = (
                    [(t["g"], _robust_or_exact(t)) for t in s["trials"]], s["capped"])
                n_robust += sum(1 for t in s["trials"] if t.get("r"))
    n_fail = 0
    for s in iter_samples(materialize(tmp_path / "s", tmp_path / "c")):
        rows, capped = want[(s.pile_id, tuple(s.subset))]
        assert s.capped == capped
        assert [(list(r[:4]), r[4]) for r in s.trials] == [(list(map(float, g)), v) for g, v in rows]
        n_fail += int((s.trials[:, 4] == 0).sum())
    assert n_fail > 0 and n_robust > 0


def _robust_or_exact(t: dict) -> float:
    """What a stored trial should be labelled: its robust repeats' success share, else its outcome."""
    if t.get("r"):
        return sum(r[4] == "success" for r in t["r"]) / len(t["r"])
    return 1.0 if t["o"] == "success" else 0.0
