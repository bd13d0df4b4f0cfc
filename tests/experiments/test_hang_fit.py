"""experiments.hang_fit: the hang model's two parameters recovered from the tilts they make."""

import math

import numpy as np
import pytest

from experiments.hang_fit import agreement, fit, predict_deg, read_successes
from planner.balance import HangModel


def test_fit_recovers_the_parameters_that_made_the_tilts():
    rng = np.random.default_rng(0)
    s = np.zeros((60, 4))
    s[:, 0], s[:, 1] = rng.uniform(0.0, 0.8, 60), rng.uniform(40, 600, 60)
    truth = HangModel(load_drop_m=1.2, grapple_moment_kg_m=80.0)
    s[:, 2] = predict_deg(truth, s)
    got = fit(s)
    assert got.load_drop_m == pytest.approx(1.2, rel=1e-2) and got.grapple_moment_kg_m == pytest.approx(80.0, rel=2e-2)
    a = agreement(predict_deg(got, s), s[:, 2])
    assert a["n"] == 60 and a["mae_deg"] < 0.05 and a["spearman"] > 0.999
    assert math.isnan(agreement(np.full(60, np.nan), s[:, 2])["mae_deg"])


def test_a_folder_of_neither_kind_is_refused(tmp_path):
    with pytest.raises(ValueError, match="neither collect.json"):
        read_successes(tmp_path)
