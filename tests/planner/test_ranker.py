"""The grasp ranker: its crops, its training, its checkpoints and the re-ranking of a plan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.errors import CheckpointError, DataError, TrainingError
from planner.ranker import (LEGACY_CROP_CHANNELS, RankerConfig, build_ranker, claw_footprint, grasp_crops, grasp_scalars, load_ranker,
                            rerank, save_ranker, Ranker)
from planner.ranker_train import (Examples, RankerTrainConfig, _pile_runs, fit, load_examples, pairwise_loss,
                                  within_pile_auc)
from synth.geometry.frames import OrthoGrid
from synth.geometry.grasp import Grasp

GRID = OrthoGrid(128, 5.0)
CFG = RankerConfig(crop_channels=LEGACY_CROP_CHANNELS)  # crops of images without an instance map


def _point_image(x_m: float, y_m: float) -> np.ndarray:
    img = np.zeros((128, 128), np.float32)
    r, c = (int(round(float(v))) for v in GRID.pile_to_pixel(x_m, y_m))
    img[r, c] = 1.0
    return img


@pytest.mark.parametrize("phi, row_off, col_off", [(0.0, 0, 8), (-math.pi / 2, -8, 0),
                                                    (math.pi / 3, 8 * math.sin(math.pi / 3), 4)])
def test_the_crop_turns_with_the_closing_axis(phi, row_off, col_off):
    """A point 8 px along pile +x from the grasp centre lies 8 px along the closing axis (columns) when
    the grasp closes along x, 8 px to its left (rows, up) when it closes along -y, and in between."""
    g = Grasp(*(float(v) for v in GRID.pixel_to_pile(60, 70)), phi, 0.6)
    p = GRID.pixel_m
    img = _point_image(g.x_m + 8 * p, g.y_m)
    crop = grasp_crops(img, np.zeros_like(img), img > 0, GRID, [g], CFG)[0]
    r, c = np.unravel_index(np.argmax(crop[0]), crop[0].shape)
    centre = (CFG.crop_px - 1) / 2
    assert (r - centre, c - centre) == pytest.approx((row_off, col_off), abs=0.51)


def test_the_claws_come_down_just_outside_the_opening():
    s = CFG.crop_px
    c = (np.arange(s) - (s - 1) / 2) * CFG.pixel_m
    u, v = np.meshgrid(c, -c)
    f = claw_footprint(u, v, 0.8, CFG)
    on = np.abs(u[f > 0])
    assert on.min() >= 0.4 and on.max() <= 0.4 + CFG.claw_plate_m
    assert np.abs(v[f > 0]).max() <= CFG.claw_width_m / 2
    assert (u[f > 0] > 0).any() and (u[f > 0] < 0).any()


def test_height_is_measured_from_the_targets_top():
    height = np.zeros((128, 128), np.float32)
    mask = np.zeros((128, 128), bool)
    height[60:68, :] = 0.4  # the target, 0.4 m high
    mask[60:68, :] = True
    height[40:44, :] = 0.7  # a neighbour on top of it
    g = Grasp(*GRID.pixel_to_pile(63.5, 64), math.pi / 2, 0.6)
    crop = grasp_crops(np.zeros_like(height), height, mask, GRID, [g], CFG)[0]
    assert crop[1][crop[2] > 0].max() == pytest.approx(0.0, abs=1e-6)
    assert crop[1].max() == pytest.approx(0.3, abs=1e-5)


def test_other_logs_and_obstacles_have_channels_of_their_own():
    """M_L marks the logs that are not this grasp's targets, M_O the obstacles (instance codes from 1000)."""
    inst = np.zeros((128, 128), np.int16)
    inst[60:68, :] = 1  # log 0: the target
    inst[50:58, :] = 2  # log 1: beside it
    inst[70:76, 60:68] = 1003  # a rock against the target
    g = Grasp(*GRID.pixel_to_pile(63.5, 64), math.pi / 2, 0.6)
    cfg = RankerConfig()
    assert cfg.crop_channels == ("I", "H", "M_T", "claws", "M_L", "M_O") and cfg.needs_instance
    crop = grasp_crops(np.zeros((128, 128), np.float32), np.zeros((128, 128), np.float32), inst == 1, GRID, [g], cfg,
                       inst)[0]
    m_t, m_l, m_o = crop[2], crop[4], crop[5]
    assert m_t.sum() > 0 and m_l.sum() > 0 and m_o.sum() > 0
    assert not (m_t * m_l).any() and not (m_t * m_o).any() and not (m_l * m_o).any()
    # at the image's pitch: the rock's 6 x 8 px, log 1's 8 px across the crop's whole side
    assert m_o.sum() == pytest.approx(6 * 8, abs=8) and m_l.sum() == pytest.approx(8 * CFG.crop_px, abs=2 * CFG.crop_px)
    # the target's own pixels are not "other logs": with log 1 the target too, M_L empties
    both = grasp_crops(np.zeros((128, 128), np.float32), np.zeros((128, 128), np.float32), np.isin(inst, [1, 2]), GRID,
                       [g], cfg, inst)[0]
    assert both[4].sum() == 0 and both[5].sum() == m_o.sum()


def test_instance_channels_need_the_instance_map():
    with pytest.raises(ValueError, match="instance map"):
        grasp_crops(np.zeros((128, 128), np.float32), np.zeros((128, 128), np.float32), np.ones((128, 128), bool), GRID,
                    [Grasp(0, 0, 0, 0.5)], RankerConfig())


@pytest.mark.parametrize("channels", [(), ("H", "I"), ("I", "rocks"), ("M_O", "M_O")])
def test_crop_channels_must_be_a_sub_sequence_of_the_known_ones(channels):
    with pytest.raises(ValueError, match="crop_channels"):
        RankerConfig(crop_channels=channels)


def test_a_checkpoint_without_crop_channels_reads_as_the_four_channel_ranker():
    d = RankerConfig().to_dict()
    del d["crop_channels"]
    old = RankerConfig.from_dict(d)
    assert old.crop_channels == LEGACY_CROP_CHANNELS and not old.needs_instance
    assert RankerConfig.from_dict(RankerConfig().to_dict()) == RankerConfig()
    assert build_ranker(old).features[0].in_channels == 4 and build_ranker(RankerConfig()).features[0].in_channels == 6


def test_within_pile_auc_pools_pairs_and_counts_ties_half():
    scores = np.array([0.9, 0.1, 0.5, 0.5, 0.7, 0.2])
    labels = np.array([1.0, 0.0, 1.0, 0.0, 1.0, 1.0])
    piles = np.array(["a", "a", "b", "b", "c", "c"])  # c has no failure: no pairs
    auc, pairs, mixed = within_pile_auc(scores, labels, piles)
    assert (auc, pairs, mixed) == (pytest.approx(0.75), 2, 2)


def _rule_examples(n: int, seed: int = 0) -> Examples:
    """Crops whose label is 1 exactly when the target mask covers the crop's centre."""
    rng = np.random.default_rng(seed)
    s = 16
    crops = rng.normal(0, 0.1, (n, 4, s, s)).astype(np.float16)
    labels = (rng.random(n) < 0.5).astype(np.float32)
    crops[:, 2] = 0
    for i in np.flatnonzero(labels):
        crops[i, 2, s // 2 - 3:s // 2 + 3, s // 2 - 3:s // 2 + 3] = 1
    for i in np.flatnonzero(labels == 0):  # the mask elsewhere: in a corner
        crops[i, 2, :4, :4] = 1
    piles = np.array([f"0/p{i % 40}" for i in range(n)])
    return Examples(crops, np.zeros((n, 2), np.float32), labels, piles, np.zeros(n, int),
                    np.array([i % 40 < 8 for i in range(n)]))


def test_fit_learns_what_the_crops_show():
    """Trained on crops labelled by where the target mask lies, the ranker orders held-out piles' crops."""
    ex = _rule_examples(1200)
    _, history = fit(ex, RankerTrainConfig(epochs=4, batch_size=32, lr=3e-3), RankerConfig(crop_px=16, channels=8, crop_channels=LEGACY_CROP_CHANNELS))
    assert history[-1]["val_auc"] > 0.95 and history[-1]["val_auc_piles"] == 8


def test_pairwise_loss_counts_only_one_pile_s_pairs_that_differ_weighted_by_the_difference():
    import torch

    logits = torch.tensor([2.0, 0.0, -1.0, 3.0, 0.5], requires_grad=True)
    labels = torch.tensor([1.0, 0.0, 0.5, 0.0, 1.0])
    piles = torch.tensor([0, 0, 0, 1, 2])  # pile 1 and 2 have one example each: no pairs there
    sp = torch.nn.functional.softplus
    # pile 0's pairs (better, worse, weight): (0, 1, 1), (0, 2, 0.5), (2, 1, 0.5)
    want = (1.0 * sp(torch.tensor(0.0 - 2.0)) + 0.5 * sp(torch.tensor(-1.0 - 2.0))
            + 0.5 * sp(torch.tensor(0.0 - -1.0))) / 2.0
    got = pairwise_loss(logits, labels, piles)
    assert float(got.detach()) == pytest.approx(float(want), rel=1e-6)
    got.backward()
    assert logits.grad[3] == 0 and logits.grad[4] == 0  # another pile's examples pull nothing
    assert logits.grad[0] < 0 < logits.grad[1]  # the success is pushed up, the failure down


def test_pairwise_loss_grows_when_a_pile_is_ordered_the_wrong_way_and_is_zero_without_pairs():
    import torch

    labels, piles = torch.tensor([1.0, 0.0]), torch.tensor([0, 0])
    right = pairwise_loss(torch.tensor([1.0, -1.0]), labels, piles)
    wrong = pairwise_loss(torch.tensor([-1.0, 1.0]), labels, piles)
    assert float(wrong) > float(right) > 0
    x = torch.tensor([1.0, -1.0], requires_grad=True)
    none = pairwise_loss(x, torch.tensor([1.0, 1.0]), piles)  # equal labels: no pair
    none.backward()
    assert float(none.detach()) == 0.0 and x.grad is not None


def test_runs_of_one_pile_keep_every_example_and_mix_the_piles():
    piles = np.array([f"0/p{i % 7}" for i in range(56)])  # 8 examples per pile: two runs of 4
    order = np.random.default_rng(1).permutation(56)
    ran = _pile_runs(order, piles, 4, np.random.default_rng(2))
    assert sorted(ran) == sorted(order)
    names = piles[ran]
    starts = [k for k in range(56) if k == 0 or names[k] != names[k - 1]]
    lengths = set(np.diff(starts + [56]).tolist())
    assert lengths <= {4, 8}  # runs of 4 (two of a pile may meet)
    assert len(starts) > 7  # not whole piles one after another
    for p in np.unique(piles):  # a run takes 4 of its pile's examples as they come in order
        mine = [i for i in order if piles[i] == p]
        runs = [list(ran[k:k + 4]) for k in range(0, 56, 4) if piles[ran[k]] == p]
        assert sorted(runs) == sorted([mine[:4], mine[4:]])


def test_fit_with_the_pairwise_term_learns_what_the_crops_show():
    ex = _rule_examples(1200)
    _, history = fit(ex, RankerTrainConfig(epochs=4, batch_size=32, lr=3e-3, pairwise_weight=1.0),
                     RankerConfig(crop_px=16, channels=8, crop_channels=LEGACY_CROP_CHANNELS))
    assert history[-1]["val_auc"] > 0.95


@pytest.mark.parametrize("weight", [-0.1, float("nan"), float("inf")])
def test_a_pairwise_weight_that_is_not_a_finite_non_negative_number_is_refused(weight):
    with pytest.raises(ValueError, match="pairwise_weight"):
        RankerTrainConfig(pairwise_weight=weight)


def test_a_pile_run_shorter_than_a_pair_is_refused():
    with pytest.raises(ValueError, match="pile_chunk"):
        RankerTrainConfig(pile_chunk=1)


def test_fit_needs_both_sides_of_the_split():
    ex = _rule_examples(40)
    ex.val[:] = False
    with pytest.raises(TrainingError, match="validation"):
        fit(ex, RankerTrainConfig(epochs=1), RankerConfig(crop_px=16, channels=8, crop_channels=LEGACY_CROP_CHANNELS))


def _width_ranker(threshold_m: float = 0.7) -> Ranker:
    """A real ranker whose weights make p = sigmoid(10 (width - threshold)): it prefers wide grasps."""
    import torch

    cfg = RankerConfig(crop_px=16, channels=4, hidden=8)
    model = build_ranker(cfg)
    with torch.no_grad():
        for p in model.parameters():
            p.zero_()
        model.head[0].weight[0, -2] = 1.0  # hidden 0 = relu(width)
        model.head[2].weight[0, 0] = 10.0
        model.head[2].bias[0] = -10.0 * threshold_m
    model.eval()
    return Ranker(model, replace_pitch(cfg), {})


def replace_pitch(cfg: RankerConfig) -> RankerConfig:
    from dataclasses import replace

    return replace(cfg, pixel_m=GRID.pixel_m)


def test_a_checkpoint_round_trips_and_a_foreign_file_is_refused(tmp_path):
    from planner.checkpoint import save_checkpoint
    from planner.model import UNetConfig, build_unet

    rk = _width_ranker()
    path = save_ranker(tmp_path / "r.safetensors", rk.model, rk.config, {"note": 1})
    back = load_ranker(path)
    crops = np.zeros((3, len(rk.config.crop_channels), 16, 16), np.float32)
    scal = grasp_scalars([Grasp(0, 0, 0, w) for w in (0.5, 0.7, 0.9)], [1, 2, 3])
    assert np.allclose(back.probabilities(crops, scal), rk.probabilities(crops, scal))
    assert back.meta == {"note": 1} and back.config == rk.config
    unet = tmp_path / "unet.safetensors"
    save_checkpoint(unet, build_unet(UNetConfig.tiny(size_px=32)), UNetConfig.tiny(size_px=32))
    with pytest.raises(CheckpointError, match="format"):
        load_ranker(unet)
    (tmp_path / "cut.safetensors").write_bytes(path.read_bytes()[:100])
    with pytest.raises(CheckpointError, match="truncated or corrupt"):
        load_ranker(tmp_path / "cut.safetensors")


def test_rerank_puts_the_ranked_union_first_in_the_ranker_s_order():
    """The best k by f1 and by f3 are scored and ordered by the ranker's p; the rest follow unchanged."""
    from planner.inference import Objective, Plan, PlannedGrasp

    from tests.planner.planner_helpers import observation

    obs = observation(4, size=128)
    widths = [0.5, 0.9, 0.6, 1.2, 0.8, 1.0]
    grasps = [PlannedGrasp(Grasp(0.0, 0.1 * i, math.pi / 2, w), 0.9 - 0.1 * i, 0.9 - 0.1 * i, 1.0, (i % 4,) if i < 4
                           else (0, 1 + i % 3), (0, 0)) for i, w in enumerate(widths)]
    plan = Plan(grasps, 6, 0.0)
    out = rerank(plan, obs, _width_ranker(), Objective("f1"), k=2, u_weight=0.0)
    ranked = out.grasps[:out.info["reranked"]]
    assert sorted(g.grasp.width_m for g in ranked) == sorted([0.5, 0.9])  # f1 and f3 agree on the top two here
    assert [g.grasp.width_m for g in ranked] == [0.9, 0.5]
    assert ranked[0].graspability == pytest.approx(1 / (1 + math.exp(-10 * 0.2)))
    assert [g.grasp.width_m for g in out.grasps[2:]] == [0.6, 1.2, 0.8, 1.0]
    assert [g.quality for g in out.grasps[2:]] == [0.0] * 4 and out.grasps[3].graspability == pytest.approx(0.6)
    assert out.info["u_network"]["0"] == pytest.approx(0.9)


def test_the_f3_half_of_the_union_is_chosen_by_the_objective_s_own_f3():
    """An f3 objective with a harsher balance tolerance picks its own best grasp into the re-scored union:
    a level grasp of U 0.85 joins the tilted one of U 0.95 (the paper's tolerance would not take it)."""
    from planner.inference import Objective, Plan, PlannedGrasp

    from tests.planner.planner_helpers import observation

    obs = observation(4, size=128)
    tilted = PlannedGrasp(Grasp(0.0, 0.0, math.pi / 2, 0.5), 0.95, 0.95, math.cos(math.radians(20)), (0,), (0, 0))
    level = PlannedGrasp(Grasp(0.0, 0.3, math.pi / 2, 0.6), 0.85, 0.85, math.cos(math.radians(3)), (1,), (0, 0))
    plan = Plan([tilted, level], 2, 0.0)
    assert rerank(plan, obs, _width_ranker(), Objective("f3"), k=1).info["reranked"] == 1
    out = rerank(plan, obs, _width_ranker(), Objective("f3", sigma_b=0.05), k=1)
    assert out.info["reranked"] == 2 and out.grasps[0].targets == (1,)


def test_the_blend_weighs_the_network_s_u_against_the_ranker_s_p():
    """rerank's default order is the blend of U and p: a grasp the network rates far higher can stay first
    although the ranker prefers another; at weight 0 the ranker's order wins, at 1 the network's."""
    from planner.inference import Objective, Plan, PlannedGrasp
    from planner.ranker import U_WEIGHT, blend

    from tests.planner.planner_helpers import observation

    assert blend(0.9, 0.6, 0.0) == pytest.approx(0.6) and blend(0.9, 0.6, 1.0) == pytest.approx(0.9)
    assert blend(0.8, 0.2, 0.5) == pytest.approx(0.5)  # logits +1.39 and -1.39
    with pytest.raises(ValueError, match="u_weight"):
        blend(0.5, 0.5, 1.5)
    obs = observation(4, size=128)
    # U 0.995 on the narrow grasp, 0.6 on the wide one; the width ranker prefers the wide one a little
    grasps = [PlannedGrasp(Grasp(0.0, 0.0, math.pi / 2, 0.5), 0.995, 0.995, 1.0, (0,), (0, 0)),
              PlannedGrasp(Grasp(0.0, 0.3, math.pi / 2, 0.6), 0.6, 0.6, 1.0, (1,), (0, 0))]
    order = {w: [g.grasp.width_m for g in rerank(Plan(grasps, 2, 0.0), obs, _width_ranker(), Objective("f1"),
                                                 k=2, u_weight=w).grasps] for w in (0.0, U_WEIGHT, 1.0)}
    assert order == {0.0: [0.6, 0.5], U_WEIGHT: [0.5, 0.6], 1.0: [0.5, 0.6]}
    out = rerank(Plan(grasps, 2, 0.0), obs, _width_ranker(), Objective("f1"), k=2)
    assert out.info["u_weight"] == U_WEIGHT and set(out.info["p_ranker"]) == {"0", "1"}
    assert out.grasps[0].graspability == pytest.approx(float(blend(0.995, out.info["p_ranker"]["0"])))
    with pytest.raises(ValueError, match="u_weight"):
        rerank(Plan(grasps, 2, 0.0), obs, _width_ranker(), Objective("f1"), u_weight=-0.1)


def test_examples_need_stored_trials(tmp_path):
    from tests.planner.planner_helpers import make_dataset

    make_dataset(tmp_path / "d", n_piles=2, size=128, shards=1)
    with pytest.raises(DataError, match="keeps no trials"):
        load_examples([tmp_path / "d"], replace_pitch(RankerConfig()), RankerTrainConfig())


def test_a_ranked_row_is_named_and_fingerprinted_by_its_ranker(tmp_path):
    """An evaluation record planned with one ranker is not reused for another (or another k)."""
    from planner.evaluate import _fingerprint
    from planner.planners import PlannerSpec

    model = tmp_path / "m.safetensors"
    model.write_bytes(b"model")
    a, b = _width_ranker(0.7), _width_ranker(0.9)
    pa = save_ranker(tmp_path / "a.safetensors", a.model, a.config)
    pb = save_ranker(tmp_path / "b.safetensors", b.model, b.config)
    plain = PlannerSpec("unet", model=str(model), objective="f3")
    ra = PlannerSpec("unet", model=str(model), objective="f3", ranker=str(pa))
    p_only = PlannerSpec("unet", model=str(model), objective="f3", ranker=str(pa), ranker_u_weight=0.0)
    assert (plain.name, ra.name, p_only.name) == ("unet-f3", "unet-f3-ranked4u0.75", "unet-f3-ranked4")
    prints = {_fingerprint(s) for s in (plain, ra, PlannerSpec("unet", model=str(model), objective="f3",
                                                                ranker=str(pb)),
                                        PlannerSpec("unet", model=str(model), objective="f3", ranker=str(pa),
                                                    rerank_k=2), p_only)}
    assert len(prints) == 5


def test_a_balanced_epoch_draws_each_data_set_equally():
    from planner.ranker_train import _epoch_order

    n = 500
    piles = np.array([f"{0 if i < 450 else 1}/p{i % 9}" for i in range(n)])
    ex = Examples(np.zeros((n, 4, 16, 16), np.float16), np.zeros((n, 2), np.float32), np.zeros(n, np.float32), piles,
                  np.zeros(n, int), np.zeros(n, bool))
    rng = np.random.default_rng(0)
    order = _epoch_order(ex, np.arange(n), True, rng)
    assert len(order) == 500 and (order >= 450).sum() == 250
    assert sorted(_epoch_order(ex, np.arange(n), False, rng)) == list(range(n))
