"""The subset pre-selection never loses a subset that fits one grapple opening.

At 128 px the candidate centres are every second pixel; a subset whose only fitting centres lie
between them is kept by the slack added to the fit radius (step / sqrt 2 + 1/2 pixel). The
reference is the brute force over every pixel of the full-resolution distance maps.

(Random layouts rarely show the loss: it takes a subset whose every fitting centre lies on an odd
row or column. The cases below are built to have exactly that.)
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.subsets import SubsetPolicy, choose_subsets, distance_maps, feasible_subsets
from synth.geometry.frames import OrthoGrid

GRID = OrthoGrid(128, 5.0)  # 3.9 cm pixels: candidate centres on every second pixel


def _fits_somewhere(masks, subset, radius_m):
    d = distance_maps({i: masks[i] for i in subset}, GRID.pixel_m)
    return float(np.max([d[i] for i in subset], axis=0).min()) <= radius_m


@pytest.mark.parametrize("transpose", [False, True], ids=["rows", "columns"])
def test_a_pair_that_fits_only_between_the_candidate_centres_is_kept(transpose):
    """Two parallel logs whose facing sides are 40 px apart: the one line of centres that fits
    is the odd row (column) 65, exactly R (20.0 px) from both; every even row is 21 px from one."""
    R = SubsetPolicy().fit_radius_m
    assert 20 * GRID.pixel_m <= R < 21 * GRID.pixel_m  # the geometry this case is built on
    masks = {i: np.zeros((128, 128), bool) for i in range(2)}
    masks[0][40:46, 30:98] = True  # last row 45
    masks[1][85:91, 30:98] = True  # first row 85
    if transpose:
        masks = {i: m.T.copy() for i, m in masks.items()}
    assert _fits_somewhere(masks, (0, 1), R)
    subs, info = feasible_subsets(masks, GRID.pixel_m)
    assert (0, 1) in subs, f"the pair fits one opening but was dropped ({info})"
    chosen, _ = choose_subsets(masks, GRID.pixel_m, SubsetPolicy(mode="fit"))
    assert (0, 1) in chosen
    # the slack does not keep everything: a pair 20 px further apart is dropped
    masks[1] = np.roll(masks[1], 20, axis=1 if transpose else 0)
    assert (0, 1) not in feasible_subsets(masks, GRID.pixel_m)[0]
