"""Obstacles of a reconstructed pile against the truth: one-to-one pairs within the gate, phantoms and misses
(:func:`reconstruct.compare.match_obstacles`, through :func:`reconstruct.compare.compare_piles`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from reconstruct.compare import OBSTACLE_GATE_M, compare_piles, match_obstacles
from synth.scene.pile import StumpSpec


def _stump(x, y, r=0.1):
    return StumpSpec(position_m=(x, y), height_m=0.4, bottom_radius_m=r, top_radius_m=r)


def _obs(x, y, size=0.2, kind="stump"):
    return {"kind": kind, "xy": np.array([x, y], float), "size_m": size}


def test_a_phantom_and_a_missed_obstacle_on_a_hand_made_pair(crossed):
    """Truth: stumps at (2, 2), (-2, 2), (2, -2). Reconstruction: the first 0.2 m off, the second 0.6 m off
    (past the gate: missed), and one where there is none (phantom)."""
    from experiments.survey_conditions import obstacle_entry

    truth = replace(crossed, stumps=(_stump(2.0, 2.0), _stump(-2.0, 2.0), _stump(2.0, -2.0)))
    recon = replace(crossed, stumps=(_stump(2.0, -2.05), _stump(-2.0, 1.4), _stump(1.8, 2.0)))
    entry = obstacle_entry(compare_piles(truth, recon, render=False))
    assert [(m["truth_index"], m["recon_index"]) for m in entry["matched"]] == [(0, 2), (2, 0)]
    assert abs(entry["matched"][0]["distance_m"] - 0.2) < 1e-9
    assert entry["missed_obstacles"] == [1] and entry["phantom_obstacles"] == [1]
    assert (entry["n_truth"], entry["n_recon"], entry["gate_m"]) == (3, 3, OBSTACLE_GATE_M)


def test_the_gate_is_its_value_plus_half_the_true_obstacles_size():
    inside = OBSTACLE_GATE_M + 0.1 - 0.01  # a 0.2 m stump: gate 0.3 + 0.1 m
    outside = OBSTACLE_GATE_M + 0.1 + 0.01
    assert match_obstacles([_obs(0, 0)], [_obs(inside, 0)])[0]["recon_index"] == 0
    assert match_obstacles([_obs(0, 0)], [_obs(outside, 0)])[0]["recon_index"] is None
    big = match_obstacles([_obs(0, 0, size=1.0, kind="rock")], [_obs(0.75, 0)])  # inside 0.3 + 0.5 m
    assert big[0]["recon_index"] == 0 and big[0]["recon_kind"] == "stump"


def test_one_reconstructed_obstacle_serves_one_true_one():
    """Two true stumps 0.2 m apart, one reconstructed between them: one pair, one missed."""
    m = match_obstacles([_obs(0, 0), _obs(0.2, 0)], [_obs(0.1, 0)])
    assert sorted(x["recon_index"] is None for x in m) == [False, True]


def test_the_pairing_with_the_most_pairs_wins_over_the_nearest_first():
    """True A at 0 and B at 0.6 m; reconstructed X at 0.25 m (nearest to A, the only one in B's gate) and Y at
    -0.3 m (in A's gate only). Nearest-first gives A-X and misses B; the assignment gives A-Y and B-X."""
    m = match_obstacles([_obs(0, 0), _obs(0.6, 0)], [_obs(0.25, 0), _obs(-0.3, 0)])
    assert [x["recon_index"] for x in m] == [1, 0]


def test_a_negative_gate_is_refused():
    with pytest.raises(ValueError, match="gate"):
        match_obstacles([_obs(0, 0)], [_obs(0, 0)], gate_m=-0.1)
