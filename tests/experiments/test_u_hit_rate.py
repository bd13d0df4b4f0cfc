"""The U hit rate: a predictor that peaks where the labels are scores 1, one that peaks elsewhere 0."""

import numpy as np

from experiments.u_hit_rate import U, hit_rates, validation_samples
from planner.data import is_validation_pile, sample_pile_id
from tests.planner.planner_helpers import make_dataset


def test_peaks_on_the_labels_hit_and_peaks_elsewhere_miss(tmp_path):
    make_dataset(tmp_path, n_piles=12)
    samples = list(validation_samples(tmp_path, every=1))
    assert samples and all(is_validation_pile(sample_pile_id(s)) and not s.negative for s in samples)
    labels = iter([])

    def on_labels(x):
        out = np.zeros((1, 5, *x.shape[2:]), np.float32)
        out[0, U] = np.where(next(labels).maps[U] > 0.5, 5.0, -5.0)
        return out

    def beside_them(x):
        out = on_labels(x)
        return np.where(out > 0, -5.0, np.where(np.arange(out.shape[-1]) == 0, 1.0, -4.0)).astype(np.float32)

    labels = iter(samples)
    assert hit_rates(samples, {"on": on_labels})["on"]["hit_rate"] == 1.0
    labels = iter(samples)
    r = hit_rates(samples, {"off": beside_them})["off"]
    assert r["samples"] == len(samples) and r["hit_rate"] == 0.0
    assert abs(r["u_max_median"] - 1 / (1 + np.exp(-1.0))) < 1e-6


def test_a_model_without_depth_gets_intensity_and_mask_only():
    from types import SimpleNamespace

    from experiments.u_hit_rate import _three_inputs

    seen = []
    fake = SimpleNamespace(config=SimpleNamespace(in_channels=2), predict=lambda x: seen.append(x) or x)
    x = np.stack([np.full((4, 4), v, np.float32) for v in (1.0, 2.0, 3.0)])[None]  # I, D, M_T
    _three_inputs(fake)(x)
    assert seen[0].shape == (1, 2, 4, 4) and seen[0][0, 0, 0, 0] == 1.0 and seen[0][0, 1, 0, 0] == 3.0
