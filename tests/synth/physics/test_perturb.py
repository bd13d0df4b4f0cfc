"""The positioning error: validation, repeatable draws, the spread it names."""

import math

import numpy as np
import pytest

from synth.geometry.grasp import Grasp
from synth.physics.perturb import PositioningError, grasp_rng, perturbed_grasps


@pytest.mark.parametrize("xy, phi", [(0.0, 2.0), (-0.01, 2.0), (0.02, 0.0), (0.02, -1.0), (float("nan"), 2.0),
                                     (0.6, 2.0), (0.02, 50.0)])
def test_nonsense_sigma_is_refused(xy, phi):
    with pytest.raises(ValueError, match="positioning error"):
        PositioningError(xy, phi)


def test_parse_names_the_format():
    assert PositioningError.parse("0.03,2") == PositioningError(0.03, 2.0)
    with pytest.raises(ValueError, match="SIGMA_XY_M,SIGMA_PHI_DEG"):
        PositioningError.parse("3cm")


def test_draws_repeat_per_key_and_differ_across_keys():
    g = Grasp(1.0, 2.0, 0.3, 0.8)
    err = PositioningError(0.02, 2.0)
    a = perturbed_grasps(g, err, 4, grasp_rng(7, "pile", 3))
    b = perturbed_grasps(g, err, 4, grasp_rng(7, "pile", 3))
    c = perturbed_grasps(g, err, 4, grasp_rng(7, "pile", 4))
    assert a == b and a != c


def test_spread_matches_sigma():
    g = Grasp(0.0, 0.0, 0.5, 0.8)
    err = PositioningError(0.03, 3.0)
    gs = perturbed_grasps(g, err, 4000, grasp_rng(1))
    dx = np.array([q.x_m for q in gs])
    dphi = np.array([q.phi_rad - g.phi_rad for q in gs])
    assert abs(dx.std() - 0.03) < 0.002
    assert abs(np.degrees(dphi).std() - 3.0) < 0.2
    assert all(q.width_m == g.width_m for q in gs)
    assert not math.isclose(dx.mean(), 0.03)
