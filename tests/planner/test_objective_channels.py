"""The planner's objectives read the network's channels by name: U for graspability, B for
balance (f3), W for the width. Every channel holds a different value here, so reading the wrong
one changes the chosen grasp or what the plan reports."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from planner.inference import Objective, Planner, plan
from planner.model import OUTPUT_NAMES, UNetConfig, build_unet
from planner_helpers import observation

TINY = UNetConfig.tiny()
C, S, W, U, B = (OUTPUT_NAMES.index(k) for k in ("C", "S", "W", "U", "B"))
BALANCED, UNBALANCED = (10, 10), (20, 22)  # two equally graspable pixels
PIXELS = {BALANCED: {"W": 0.5, "B": 1.0}, UNBALANCED: {"W": 1.0, "B": 0.3}}  # W and B swapped roles


def _net(x):
    out = np.zeros((len(x), 5, 32, 32), np.float32)
    out[:, C], out[:, S], out[:, W], out[:, U], out[:, B] = -1.0, 0.0, 0.7, -10.0, 0.0
    for (r, c), v in PIXELS.items():
        out[:, U, r, c] = math.log(0.8 / 0.2)
        out[:, W, r, c] = v["W"]
        out[:, B, r, c] = v["B"]
    return out


def _planner():
    torch.manual_seed(0)
    p = Planner(build_unet(TINY), TINY, precision="fp32", quality_smoothing_px=0.0, angle_smoothing_px=0.0)
    p.predict = _net
    return p


def test_f3_scores_balance_from_the_b_channel():
    obj = Objective("f3")
    best = plan(observation(2), _planner(), obj).best
    assert best.pixel == BALANCED, "f3 chose the unbalanced grasp: is it reading B?"
    assert best.balance == pytest.approx(PIXELS[BALANCED]["B"])
    assert best.graspability == pytest.approx(0.8, abs=1e-6)
    tau = len(best.targets)
    assert best.quality == pytest.approx(0.8 * tau ** obj.mu, rel=1e-5)  # exp(0) at b = b_opt
    assert best.grasp.width_m == pytest.approx(PIXELS[BALANCED]["W"])


def test_every_grasp_reports_its_own_b_and_w():
    p = plan(observation(2), _planner(), Objective("f1"))
    for g in p.grasps:
        v = PIXELS[g.pixel]
        assert g.balance == pytest.approx(v["B"]) and g.grasp.width_m == pytest.approx(v["W"])
