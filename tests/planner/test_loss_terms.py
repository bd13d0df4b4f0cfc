"""Every term of the training loss counts, with its weight, and training uses the configured weights.

L = BCE_w(U, U_hat) + lambda_C MMSE(C) + lambda_S MMSE(S) + lambda_W MMSE(W) + lambda_B MMSE(B), with
positive U pixels weighted ``u_pos_weight`` in the BCE. Each term is recomputed here by hand from
the equation (not from planner.loss), so dropping a term or its weight changes the total.
"""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from planner.loss import LossWeights, grasp_loss
CHANNEL = {"c": 0, "s": 1, "w": 2, "b": 4}
WEIGHT = {"c": "lambda_c", "s": "lambda_s", "w": "lambda_w", "b": "lambda_b"}


def _batch():
    """Random targets (U: 30 % grasp pixels), predictions off by a different amount in every channel."""
    g = torch.Generator().manual_seed(0)
    n, h = 2, 16
    tgt = torch.empty(n, 5, h, h)
    tgt[:, 0:2] = torch.rand(n, 2, h, h, generator=g) * 2 - 1
    tgt[:, 2] = 0.3 + 1.25 * torch.rand(n, h, h, generator=g)
    tgt[:, 3] = (torch.rand(n, h, h, generator=g) < 0.3).float()
    tgt[:, 4] = torch.rand(n, h, h, generator=g) * 2 - 1
    pred = tgt.clone()
    for k, ch in enumerate(CHANNEL.values()):
        pred[:, ch] += (0.3 + 0.1 * k) * torch.randn(n, h, h, generator=g)
    pred[:, 3] = torch.randn(n, h, h, generator=g)  # U logits
    return pred, tgt


def _mmse(u, y, y_hat):
    return float(((u * (y - y_hat) ** 2).mean(dim=(-2, -1))).mean())


def _bce(u, logit, pos_weight):
    p = torch.sigmoid(logit.double())
    u = u.double()
    return float(-(pos_weight * u * torch.log(p) + (1 - u) * torch.log(1 - p)).mean())


W = LossWeights(lambda_b=11.0, lambda_s=7.0, lambda_c=5.0, lambda_w=3.0, u_pos_weight=2.5)  # all distinct


def test_total_is_the_weighted_sum_of_hand_computed_terms():
    pred, tgt = _batch()
    u = tgt[:, 3]
    total, parts = grasp_loss(pred, tgt, W)
    want = _bce(u, pred[:, 3], W.u_pos_weight)
    for name, ch in CHANNEL.items():
        term = _mmse(u, tgt[:, ch], pred[:, ch])
        assert term > 1e-2, name  # the batch really has an error in this channel
        assert parts[name] == pytest.approx(term, rel=1e-5), name
        want += getattr(W, WEIGHT[name]) * term
    assert parts["bce"] == pytest.approx(_bce(u, pred[:, 3], W.u_pos_weight), rel=1e-5)
    assert float(total) == pytest.approx(want, rel=1e-5)


@pytest.mark.parametrize("name", sorted(CHANNEL))
def test_each_term_moves_the_total_by_its_weight(name):
    pred, tgt = _batch()
    term = _mmse(tgt[:, 3], tgt[:, CHANNEL[name]], pred[:, CHANNEL[name]])
    with_term, _ = grasp_loss(pred, tgt, W)
    without, _ = grasp_loss(pred, tgt, replace(W, **{WEIGHT[name]: 0.0}))
    assert float(with_term - without) == pytest.approx(getattr(W, WEIGHT[name]) * term, rel=1e-4)


def test_u_pos_weight_weighs_the_positive_pixels_of_the_bce():
    pred, tgt = _batch()
    u = tgt[:, 3]
    heavy, parts = grasp_loss(pred, tgt, W)
    plain, plain_parts = grasp_loss(pred, tgt, replace(W, u_pos_weight=1.0))
    expected = _bce(u, pred[:, 3], W.u_pos_weight) - _bce(u, pred[:, 3], 1.0)
    assert expected > 1e-3
    assert float(heavy - plain) == pytest.approx(expected, rel=1e-4)
    assert parts["bce"] - plain_parts["bce"] == pytest.approx(expected, rel=1e-4)


def test_training_and_validation_use_the_configured_weights(tmp_path, monkeypatch):
    """train() passes TrainConfig.loss to every loss call (training steps and validation)."""
    import planner.train as T
    from planner.data import DataConfig
    from planner.model import UNetConfig
    from planner_helpers import make_dataset

    make_dataset(tmp_path / "data", n_piles=3)
    seen = []
    real = T.grasp_loss

    def spy(pred, target, weights=LossWeights(), b_encoding="cos_beta"):
        seen.append(weights)
        return real(pred, target, weights, b_encoding)

    monkeypatch.setattr(T, "grasp_loss", spy)
    cfg = T.TrainConfig(model=UNetConfig.tiny(), epochs=1, batch_size=4, precision="fp32", loss=W,
                        data=DataConfig(val_fraction=0.5, split_seed=1, shuffle_buffer=4),
                        max_steps_per_epoch=1, max_val_batches=1)
    T.train(tmp_path / "data", tmp_path / "run", cfg)
    assert len(seen) >= 2 and all(w == W for w in seen), seen


def test_the_default_loss_is_the_shipped_models():
    """`loggrasp train` without loss flags trains the shipped model's loss (U positives weighted 25, not
    the paper's plain BCE, which leaves U flat on this data): the shipped model's own training log says so."""
    import json
    from pathlib import Path

    log = json.loads((Path(__file__).parents[2] / "docs/results/learning-curve/share_1/log.json").read_text())
    shipped = log["config"]["loss"]
    assert {k: getattr(LossWeights(), k) for k in shipped} == shipped
