"""The outcome recipe (U trained on every trial's outcome) and the standardised B map (beta in 10 deg units)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.data import DataConfig, ShardStream, list_shards
from planner.errors import DataError
from planner_helpers import bar_pile, make_dataset, observation, subset_grasp
from synth.data.shards import Manifest, Sample, ShardWriter, write_manifest
from synth.data.maps import encode_grasps
from synth.geometry.frames import OrthoGrid

SIZE = 32
GRID = OrthoGrid(SIZE, 5.0)
FAIL_SHIFT_M = 0.6  # the failed trial's centre: this far from the good grasp along pile x [m]


def make_outcome_dataset(out_dir, n_piles: int = 4, n_logs: int = 3) -> Manifest:
    """Bar piles whose every subset has a successful trial (the accepted grasp) and a failed trial
    ``FAIL_SHIFT_M`` to its right; the one-log subsets' trials hit the cap."""
    w = ShardWriter(out_dir, "t", 0)
    for p in range(n_piles):
        inten, depth, inst, _ = bar_pile(n_logs, SIZE, seed=p)
        for subset in [(i,) for i in range(n_logs)] + [tuple(range(n_logs))]:
            g = subset_grasp(inst, subset, GRID)
            trials = np.array([[g.x_m + FAIL_SHIFT_M, g.y_m, g.phi_rad, g.width_m, 0.0, np.nan],
                               [g.x_m, g.y_m, g.phi_rad, g.width_m, 1.0, 0.95]])
            w.add(Sample(pile_id=f"pile_{p:03d}", render=0, subset=subset, intensity=inten, depth=depth,
                         target_mask=np.isin(inst, [i + 1 for i in subset]), maps=encode_grasps(GRID, [g], [0.95]),
                         grasps=np.array([[g.x_m, g.y_m, g.phi_rad, g.width_m, 0.95]]), negative=False,
                         n_logs=n_logs, n_candidates=5, trials=trials, capped=len(subset) == 1))
    man = Manifest(params={"test": True}, grid={"size_px": SIZE, "extent_m": 5.0, "camera_height_m": 5.0},
                   shards=[w.close()], summary={})
    write_manifest(out_dir, man)
    return man


def _targets(data_dir, cfg: DataConfig, **kw) -> list[np.ndarray]:
    shards, _ = list_shards(data_dir)
    stream = ShardStream(shards, "val", cfg, **kw)
    return [y for _, y in stream]


def _px(x, y):
    r, c = GRID.pile_to_pixel(x, y)
    return int(round(float(r))), int(round(float(c)))


def test_outcome_targets_label_the_failed_centre_negative(tmp_path):
    """Per subset: the successful centre 1, the failed centre 0, both at full weight; the untried
    pixels 0 at the untried weight, or weightless where the subset's trials hit the cap."""
    from planner.data import load_samples

    make_outcome_dataset(tmp_path / "d", n_piles=1)
    shards, _ = list_shards(tmp_path / "d")
    cfg = DataConfig(val_fraction=0.999, labels="outcome")  # every pile on the validation side: stored order
    ys = [y for _, y in ShardStream(shards, "val", cfg)]
    samples = load_samples(shards[0])
    assert len(ys) == len(samples) == 4 and all(y.shape == (6, SIZE, SIZE) for y in ys)
    for y, s in zip(ys, samples):
        ok, bad = _px(*s.trials[1, :2]), _px(*s.trials[0, :2])
        assert y[3][ok] == 1.0 and y[5][ok] == 1.0
        assert y[3][bad] == 0.0 and y[5][bad] == 1.0  # the failure: a negative at full weight
        assert y[3][0, 0] == 0.0 and y[5][0, 0] == (0.0 if s.capped else np.float32(0.05))
    assert sum(s.capped for s in samples) == 3


def test_accepted_labels_stay_the_papers(tmp_path):
    """The default recipe's targets are the stored maps unchanged (5 channels, failures unseen)."""
    make_outcome_dataset(tmp_path / "d", n_piles=1)
    ys = _targets(tmp_path / "d", DataConfig(val_fraction=0.999))
    assert all(y.shape == (5, SIZE, SIZE) for y in ys)


def test_data_without_trials_is_a_clear_error_for_the_outcome_recipe(tmp_path):
    make_dataset(tmp_path / "d", n_piles=2, shards=1)
    with pytest.raises(DataError, match="carries no trial outcomes.*--labels accepted"):
        _targets(tmp_path / "d", DataConfig(val_fraction=0.999, labels="outcome"))


def test_outcome_recipe_refuses_to_hide_subsets_without_candidates():
    with pytest.raises(ValueError, match="skip_no_candidates cannot be combined with outcome labels"):
        DataConfig(labels="outcome", skip_no_candidates=True)


def test_weighted_bce_ignores_pixels_of_weight_zero():
    import torch

    from planner.loss import LossWeights, grasp_loss

    torch.manual_seed(0)
    target = torch.zeros(2, 6, 8, 8)
    target[:, 3, 2:4, 2:4] = 1.0
    target[:, 5, :4, :4] = 1.0  # only the top-left quarter counts
    pred = torch.randn(2, 5, 8, 8)
    w = LossWeights(u_pos_weight=1.0)
    base, _ = grasp_loss(pred, target, w)
    moved = pred.clone()
    moved[:, 3, 4:, 4:] += 5.0
    assert math.isclose(float(grasp_loss(moved, target, w)[0]), float(base), rel_tol=1e-6)
    moved[:, 3, 0, 0] += 5.0
    assert float(grasp_loss(moved, target, w)[0]) > float(base)


def test_beta_encoding_round_trip_and_its_target(tmp_path):
    from planner.model import decode_balance, encode_balance

    cb = np.cos(np.radians([0.0, 6.0, 12.0, 45.0]))
    assert np.allclose(encode_balance(cb, "beta_10deg"), [0.0, 0.6, 1.2, 4.5], atol=1e-3)
    assert np.allclose(decode_balance(encode_balance(cb, "beta_10deg"), "beta_10deg"), cb, atol=1e-5)
    assert np.array_equal(decode_balance(cb.astype(np.float32), "cos_beta"), cb.astype(np.float32))
    make_outcome_dataset(tmp_path / "d", n_piles=1)
    for y in _targets(tmp_path / "d", DataConfig(val_fraction=0.999), b_encoding="beta_10deg"):
        on = y[3] > 0
        assert np.allclose(y[4][on], math.degrees(math.acos(0.95)) / 10, atol=1e-4) and not y[4][~on].any()


def test_old_checkpoint_config_reads_as_cos_beta():
    from planner.model import UNetConfig

    d = UNetConfig.tiny().to_dict()
    del d["b_encoding"]
    assert UNetConfig.from_dict(d).b_encoding == "cos_beta"


def test_planner_decodes_a_beta_checkpoints_balance(tmp_path):
    """A network whose B is beta in 10 deg units plans with cos(beta): the chosen grasp's balance is
    cos(10 deg x the raw output) at its pixel, not the raw output."""
    import torch

    from planner.checkpoint import save_checkpoint
    from planner.data import make_inputs
    from planner.inference import Objective, load_planner, observation_arrays, plan
    from planner.model import UNetConfig, build_unet

    cfg = UNetConfig.tiny(b_encoding="beta_10deg")
    torch.manual_seed(0)
    save_checkpoint(tmp_path / "m.safetensors", build_unet(cfg), cfg, {})
    planner = load_planner(tmp_path / "m.safetensors", device="cpu", precision="fp32", quality_smoothing_px=0.0)
    assert planner.config.b_encoding == "beta_10deg"
    obs = observation(2, SIZE)
    p = plan(obs, planner, Objective("f3"))
    g = p.grasps[0]
    inten, depth, inst, _, cam_h = observation_arrays(obs)
    x = make_inputs(inten, depth, np.isin(inst, [t + 1 for t in g.targets])[None], 3, cam_h)
    raw = float(planner.predict(x)[0, 4][g.pixel])
    assert raw > 0 and math.isclose(g.balance, math.cos(math.radians(10 * raw)), rel_tol=1e-5)


def test_fine_tuning_starts_from_the_checkpoint_and_refuses_one_that_does_not_fit(tmp_path):
    """--init-from: the run's first weights are the checkpoint's (a tiny learning rate keeps them);
    a checkpoint of another network (here: another B encoding) is a CheckpointError naming it."""
    import torch

    from planner.checkpoint import load_checkpoint, save_checkpoint
    from planner.errors import CheckpointError
    from planner.model import UNetConfig, build_unet
    from planner.train import TrainConfig, train

    make_outcome_dataset(tmp_path / "d", n_piles=2)
    model_cfg = UNetConfig.tiny(b_encoding="beta_10deg")
    torch.manual_seed(5)
    start = build_unet(model_cfg)
    save_checkpoint(tmp_path / "start.safetensors", start, model_cfg, {})
    cfg = TrainConfig(model=model_cfg, epochs=1, batch_size=2, lr=1e-12, precision="fp32", max_steps_per_epoch=1,
                      data=DataConfig(val_fraction=0.0, labels="outcome"), init_from=str(tmp_path / "start.safetensors"))
    got, _, _ = load_checkpoint(train(tmp_path / "d", tmp_path / "run", cfg).model_path)
    w0, w1 = start.state_dict(), got.state_dict()
    convs = [k for k in w0 if k.endswith("weight") and w0[k].ndim == 4]
    assert convs and all(torch.allclose(w0[k], w1[k], atol=1e-6) for k in convs)
    from dataclasses import replace

    retarget = replace(cfg, model=UNetConfig.tiny())  # another B encoding: same shapes, the B head re-learnt
    got, _, _ = load_checkpoint(train(tmp_path / "d", tmp_path / "run3", retarget).model_path)
    assert all(torch.allclose(w0[k], got.state_dict()[k], atol=1e-6) for k in convs)
    other = replace(cfg, model=UNetConfig.tiny(base_channels=6))
    with pytest.raises(CheckpointError, match="does not fit this run: its network differs in base_channels"):
        train(tmp_path / "d", tmp_path / "run2", other)
