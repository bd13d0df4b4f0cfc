import json
import math

import numpy as np
import pytest
import torch

from planner.calibration import Calibration, calibration_path, fit_calibration, load_calibration, logit
from planner.checkpoint import save_checkpoint
from planner.errors import CheckpointError
from planner.inference import Objective, Planner, load_planner, plan
from planner.model import UNetConfig, build_unet
from synth.common.files import sha256_file
from planner_helpers import observation

TINY = UNetConfig.tiny()


def test_probability_per_subset_size_and_monotone_in_u():
    cal = Calibration("x" * 64, 1.0, (-2.0, 0.0, 1.0))
    u = np.array([0.5, 0.9, 0.99])
    assert cal.probability(u, 1) == pytest.approx(1 / (1 + np.exp(-(logit(u) - 2.0))), rel=1e-5)
    assert np.all(np.diff(cal.probability(u, 2)) > 0)  # the order of U within a subset stays
    assert cal.probability(0.5, 7) == pytest.approx(cal.probability(0.5, 3))  # larger sizes: the last offset
    assert float(cal.probability(0.9, 1)) < float(cal.probability(0.9, 2)) < float(cal.probability(0.9, 3))
    p = cal.probability(np.full((2, 4, 4), 0.9), np.array([1, 2])[:, None, None])  # per-subset broadcast
    assert p.shape == (2, 4, 4) and p[0, 0, 0] < p[1, 0, 0]


@pytest.mark.parametrize("slope, offsets", [(0.0, (0.0,)), (-1.0, (0.0,)), (math.nan, (0.0,)), (1.0, ()),
                                            (1.0, (math.inf,))])
def test_invalid_calibrations_are_refused(slope, offsets):
    with pytest.raises(ValueError):
        Calibration("x", slope, offsets)


def test_fit_recovers_a_known_calibration(tmp_path):
    model = tmp_path / "m.safetensors"
    model.write_bytes(b"weights")
    rng = np.random.default_rng(0)
    truth = Calibration("", 1.5, (-1.5, 0.5, 1.0))
    trials = []
    for _ in range(6000):
        tau = int(rng.integers(1, 5))
        u = float(1 / (1 + np.exp(-rng.normal(2.0, 1.5))))
        trials.append({"u": u, "tau": tau, "success": bool(rng.random() < truth.probability(u, tau))})
    cal = fit_calibration(trials, model, max_size=3, ridge=0.1)
    assert cal.slope == pytest.approx(1.5, abs=0.15)
    assert cal.offsets == pytest.approx((-1.5, 0.5, 1.0), abs=0.25)
    assert cal.model_sha256 == sha256_file(model) and cal.n_trials == 6000
    with pytest.raises(ValueError, match="at least 20"):
        fit_calibration(trials[:5], model)
    flat = [{"u": t["u"], "tau": t["tau"], "success": t["u"] < 0.8} for t in trials]  # U anti-predicts
    with pytest.raises(ValueError, match="does not predict"):
        fit_calibration(flat, model)


def _checkpoint(tmp_path):
    torch.manual_seed(0)
    return save_checkpoint(tmp_path / "model.safetensors", build_unet(TINY), TINY)


def test_calibration_file_beside_the_checkpoint(tmp_path):
    path = _checkpoint(tmp_path)
    assert calibration_path(path).name == "model.calibration.json"
    assert load_planner(path, device="cpu").calibration is None  # none there: raw U
    cal = Calibration(sha256_file(path), 1.2, (-1.0, 0.5), 100, {"seeds": "930000000-"})
    cal.write(calibration_path(path))
    assert load_planner(path, device="cpu").calibration == cal
    assert load_planner(path, device="cpu", calibrated=False).calibration is None
    # another checkpoint's calibration is refused, not used
    Calibration("0" * 64, 1.2, (-1.0, 0.5)).write(calibration_path(path))
    with pytest.raises(CheckpointError, match="fitted for checkpoint"):
        load_calibration(path, sha256_file(path))
    calibration_path(path).write_text("{not json")
    with pytest.raises(CheckpointError, match="not valid JSON"):
        load_planner(path, device="cpu")
    calibration_path(path).write_text(json.dumps({"format": "loggrasp.u_calibration", "format_version": "1.0",
                                                  "model_sha256": sha256_file(path), "slope": -1, "offsets": [0]}))
    with pytest.raises(CheckpointError, match="not a valid U calibration"):
        load_planner(path, device="cpu")


def _peaks(us):
    """Network stand-in: subset k (batch order) gets a single U peak ``us[k]`` at one pixel."""
    def fn(x):
        out = np.zeros((len(x), 5, 32, 32), np.float32)
        out[:, 0], out[:, 2], out[:, 3], out[:, 4] = -1.0, 0.8, -10.0, 1.0
        for k in range(len(x)):
            out[k, 3, 16, 16] = math.log(us[k] / (1 - us[k]))
        return out
    return fn


def test_calibration_moves_the_choice_from_a_confident_single_log_to_a_pair():
    torch.manual_seed(0)
    pl = Planner(build_unet(TINY), TINY, precision="fp32", quality_smoothing_px=0.0)
    pl.predict = _peaks([0.99, 0.95, 0.95, 0.97, 0.95, 0.95, 0.95])  # subsets: 3 singles, 3 pairs, the triple
    obs = observation(3)
    raw = plan(obs, pl, Objective("f1")).best
    assert raw.targets == (0,) and raw.success_p is None
    pl.calibration = Calibration("x", 1.0, (-2.0, 0.0, 0.0))  # single logs succeed far less often
    best = plan(obs, pl, Objective("f1")).best
    assert best.targets == (0, 1) and best.graspability == pytest.approx(0.97, abs=1e-3)
    assert best.success_p == pytest.approx(0.97, abs=1e-3) and best.quality == pytest.approx(best.success_p)
    assert json.loads(plan(obs, pl).to_json())["grasps"][0]["success_p"] == pytest.approx(best.success_p)
