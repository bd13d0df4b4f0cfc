"""``loggrasp train-ranker``, ``loggrasp round`` and ``plan --ranker``: tiny real runs and bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tests.cli_helpers import cli, fails


def _trial_dataset(out, n_piles: int = 12, instance: bool = True):
    """128 px bar piles whose subsets each hold a centred grasp that worked and one 1.2 m along the logs'
    ends that did not (a synthetic store's shards: trials with success values)."""
    from synth.data.shards import Manifest, Sample, ShardWriter, write_manifest
    from synth.geometry.frames import OrthoGrid
    from tests.planner.planner_helpers import bar_pile, subset_grasp

    grid = OrthoGrid(128, 5.0)
    w = ShardWriter(out, "t", 0)
    for p in range(n_piles):
        inten, depth, inst, _ = bar_pile(3, 128, seed=p)
        for subset in [(0,), (1,), (0, 1, 2)]:
            g = subset_grasp(inst, subset, grid)
            trials = np.array([[g.x_m, g.y_m, g.phi_rad, g.width_m, 1.0, 0.99],
                               [g.x_m + 1.2, g.y_m, g.phi_rad, g.width_m, 0.0, math.nan]])
            w.add(Sample(pile_id=f"pile_{p:03d}", render=0, subset=subset, intensity=inten, depth=depth,
                         target_mask=np.isin(inst, [i + 1 for i in subset]), maps=np.zeros((5, 128, 128), np.float32),
                         grasps=trials[:1, :5], negative=False, n_logs=3, trials=trials, capped=False,
                         instance=inst.astype(np.int16) if instance else None))
    write_manifest(out, Manifest(params={"test": True}, grid={"size_px": 128, "extent_m": 5.0, "camera_height_m": 5.0},
                                 shards=[w.close()], summary={}))
    return out


@pytest.fixture(scope="module")
def trials_dir(tmp_path_factory):
    return _trial_dataset(tmp_path_factory.mktemp("trials"))


def test_train_ranker_writes_a_checkpoint_that_loads(capsys, tmp_path, trials_dir):
    from planner.ranker import load_ranker

    out = tmp_path / "r.safetensors"
    r = cli(capsys, "train-ranker", "--data", trials_dir, "--out", out, "--epochs", "2", "--batch-size", "8", "--json")
    assert r.code == 0, r.err
    d = r.json()
    assert d["format"] == "loggrasp.train_ranker" and d["examples"]["train"] + d["examples"]["val"] == 72
    assert 0.0 <= d["final"]["val_auc"] <= 1.0
    rk = load_ranker(out)
    assert rk.meta["examples"] == d["examples"] and json.loads((tmp_path / "r.safetensors.json").read_text())["history"]


def test_train_ranker_bad_input(capsys, tmp_path, trials_dir):
    from tests.planner.planner_helpers import make_dataset

    fails(cli(capsys, "train-ranker", "--data", trials_dir, "--out", tmp_path / "r.pt"), 2, "--out", ".safetensors")
    fails(cli(capsys, "train-ranker", "--data", tmp_path / "nothing", "--out", tmp_path / "r.safetensors"), 2,
          "--data")
    make_dataset(tmp_path / "old", n_piles=2, size=128, shards=1)
    fails(cli(capsys, "train-ranker", "--data", tmp_path / "old", "--out", tmp_path / "r.safetensors"), 2,
          "keeps no trials")
    fails(cli(capsys, "train-ranker", "--data", trials_dir, "--out", tmp_path / "r.safetensors", "--crop-channels",
              "I,H,rocks"), 2, "--crop-channels")
    fails(cli(capsys, "train-ranker", "--data", trials_dir, "--out", tmp_path / "r.safetensors", "--crop-channels",
              "H,I"), 2, "--crop-channels")


def test_train_ranker_without_instance_maps_needs_the_legacy_channels(capsys, tmp_path):
    from planner.ranker import LEGACY_CROP_CHANNELS, load_ranker

    old = _trial_dataset(tmp_path / "old", n_piles=6, instance=False)
    fails(cli(capsys, "train-ranker", "--data", old, "--out", tmp_path / "r.safetensors"), 2, "keeps no instance maps")
    r = cli(capsys, "train-ranker", "--data", old, "--out", tmp_path / "r.safetensors", "--epochs", "1",
            "--crop-channels", ",".join(LEGACY_CROP_CHANNELS))
    assert r.code == 0, r.err
    assert load_ranker(tmp_path / "r.safetensors").config.crop_channels == LEGACY_CROP_CHANNELS



@pytest.fixture(scope="module")
def legacy_ranker(tmp_path_factory, trials_dir):
    """A four-channel ranker trained one epoch (not the default crop, so that --init-from must keep it)."""
    from planner.ranker import LEGACY_CROP_CHANNELS
    from tests.cli_helpers import run_captured

    first = tmp_path_factory.mktemp("legacy") / "first.safetensors"
    r = run_captured("train-ranker", "--data", trials_dir, "--out", first, "--epochs", "1", "--batch-size", "8",
                     "--crop-channels", ",".join(LEGACY_CROP_CHANNELS))
    assert r.code == 0, r.err
    return first


def test_train_ranker_init_fine_tunes_the_checkpoint_it_is_given(capsys, tmp_path, trials_dir, legacy_ranker):
    """With a vanishing learning rate a fine-tune returns its --init-from weights: training starts from them (a
    random start with another seed differs by about 0.1)."""
    import hashlib

    from planner.checkpoint import load_tensors
    from planner.ranker import LEGACY_CROP_CHANNELS, RANKER_FORMAT_NAME, load_ranker

    first = legacy_ranker
    tuned = tmp_path / "tuned.safetensors"
    r = cli(capsys, "train-ranker", "--data", trials_dir, "--out", tuned, "--epochs", "1", "--batch-size", "8",
            "--lr", "1e-12", "--init-from", first, "--seed", "3")
    assert r.code == 0, r.err
    a, _ = load_tensors(first, RANKER_FORMAT_NAME)
    b, _ = load_tensors(tuned, RANKER_FORMAT_NAME)
    assert a.keys() == b.keys() and all(np.allclose(a[k], b[k], rtol=0, atol=1e-9) for k in a)
    rk = load_ranker(tuned)
    assert rk.config.crop_channels == LEGACY_CROP_CHANNELS  # the checkpoint's crop, not the default's
    assert rk.meta["init"] == {"path": str(first), "sha256": hashlib.sha256(first.read_bytes()).hexdigest()}


def test_train_ranker_init_bad_input(capsys, tmp_path, trials_dir, tiny_model, legacy_ranker):
    out = tmp_path / "r.safetensors"
    train = ("train-ranker", "--data", trials_dir, "--out", out)
    fails(cli(capsys, *train, "--init-from", tmp_path / "none.safetensors"), 2, "--init-from", "does not exist")
    fails(cli(capsys, *train, "--init-from", tiny_model), 2, str(tiny_model))
    line = fails(cli(capsys, *train, "--init-from", legacy_ranker, "--crop-channels", "I,H,M_T,claws,M_L,M_O"), 2,
                 "crop_channels", "leave those options out")
    assert not out.exists(), line

@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    import torch

    from planner.checkpoint import save_checkpoint
    from planner.model import UNetConfig, build_unet

    path = tmp_path_factory.mktemp("m") / "tiny.safetensors"
    torch.manual_seed(0)
    save_checkpoint(path, build_unet(UNetConfig.tiny(size_px=128)), UNetConfig.tiny(size_px=128), {})
    return path


def test_round_runs_a_pile_and_refuses_bad_flags(capsys, tmp_path, tiny_model):
    r = cli(capsys, "round", "--round", "0", "--piles", "1", "--model", tiny_model, "--top-k", "1", "--repeats", "1",
            "--logs", "2-2", "--workers", "1", "--out", tmp_path / "r0", "--json")
    assert r.code == 0, r.err
    d = r.json()
    assert d["chunks_done"] == 1 and d["complete"] and d["trials"] == d["subsets"] >= 1
    base = ["round", "--round", "0", "--piles", "1", "--model", tiny_model, "--out", tmp_path / "r1"]
    fails(cli(capsys, *base, "--error", "3cm"), 2, "--error")
    fails(cli(capsys, *base, "--logs", "7"), 2, "--logs")
    fails(cli(capsys, *base, "--logs", "5-3"), 2, "max_logs")
    fails(cli(capsys, "round", "--round", "0", "--piles", "2", "--model", tmp_path / "none.safetensors", "--out",
              tmp_path / "r2"), 2, "--model")


def test_plan_with_a_ranker_lists_its_probabilities(capsys, tmp_path, trials_dir):
    """plan --ranker: the listed grasps' U are the blend of the network's U and the ranker's probability,
    in the objective's order; --ranker-u-weight 0 lists the ranker's p itself."""
    assert cli(capsys, "synth", "piles", "--count", "1", "--logs", "3", "--renders", "1", "--workers", "1",
               "--out", tmp_path / "piles").code == 0
    out = tmp_path / "r.safetensors"
    assert cli(capsys, "train-ranker", "--data", trials_dir, "--out", out, "--epochs", "1").code == 0
    pile = tmp_path / "piles" / "pile_00000"
    plain = cli(capsys, "plan", pile, "--json", "--top", "7", "--no-ranker").json()
    assert "ranker" not in plain
    r = cli(capsys, "plan", pile, "--json", "--top", "7", "--ranker", out, "--rerank-k", "2")
    assert r.code == 0, r.err
    ranked = r.json()
    n = ranked["ranker"]["reranked"]
    assert 2 <= n <= 4
    us = [g["graspability"] for g in ranked["grasps"][:n]]
    assert [g["quality"] for g in ranked["grasps"][:n]] == pytest.approx(sorted(us, reverse=True))  # f1: Q = U
    assert [g["quality"] for g in ranked["grasps"][n:]] == [0.0] * (len(ranked["grasps"]) - n)
    assert set(ranked["ranker"]["u_network"].values()) <= {g["graspability"] for g in plain["grasps"]}
    from planner.ranker import U_WEIGHT, blend

    rk = ranked["ranker"]
    key = [",".join(map(str, g["targets"])) for g in ranked["grasps"][:n]]
    assert rk["u_weight"] == U_WEIGHT
    assert us == pytest.approx([float(blend(rk["u_network"][k], rk["p_ranker"][k])) for k in key])
    p_only = cli(capsys, "plan", pile, "--json", "--top", "7", "--ranker", out, "--rerank-k", "2",
                 "--ranker-u-weight", "0").json()
    assert [g["graspability"] for g in p_only["grasps"][:n]] == pytest.approx(
        sorted(p_only["ranker"]["p_ranker"].values(), reverse=True))
    fails(cli(capsys, "plan", pile, "--ranker", out, "--ranker-u-weight", "1.5"), 2, "--ranker-u-weight")
    fails(cli(capsys, "plan", pile, "--ranker", tmp_path / "missing.safetensors"), 2, "--ranker")
    fails(cli(capsys, "plan", pile, "--ranker", out, "--no-ranker"), 2, "--no-ranker")


def test_plan_uses_the_shipped_ranker_by_default(capsys, tmp_path):
    """plan without ranker flags re-scores with planner/weights/ranker.safetensors, as --ranker naming it does."""
    from planner.checkpoint import DEFAULT_RANKER

    assert cli(capsys, "synth", "piles", "--count", "1", "--logs", "3", "--renders", "1", "--workers", "1",
               "--seed", "7", "--out", tmp_path / "piles").code == 0
    pile = tmp_path / "piles" / "pile_00000"
    default = cli(capsys, "plan", pile, "--json", "--top", "7").json()
    named = cli(capsys, "plan", pile, "--json", "--top", "7", "--ranker", DEFAULT_RANKER).json()
    assert default["ranker"]["reranked"] >= 1
    assert default["ranker"] == named["ranker"]
    assert [g["targets"] for g in default["grasps"]] == [g["targets"] for g in named["grasps"]]


def test_piles_of_two_data_sets_stay_apart(trials_dir):
    """Two data sets name their piles alike (pile_00000 ...): the examples keep them apart (the
    within-pile AUC pairs grasps of one pile only), and validation reports each set's AUC."""
    from planner.ranker import RankerConfig
    from planner.ranker_train import RankerTrainConfig, load_examples

    ex = load_examples([trials_dir, trials_dir], RankerConfig(), RankerTrainConfig())
    assert len(np.unique(ex.piles)) == 24 and len(ex.labels) == 144
    assert {p.split("/")[0] for p in ex.piles} == {"0", "1"}


def test_each_repeat_of_a_round_is_an_example_of_its_own(tmp_path, tiny_model):
    """A round's grasp tried exactly and twice moved: three examples, the moved ones labelled by their own
    outcome at the pose executed; --no-repeats keeps the grasp as tried, labelled by the success fraction."""
    import gzip

    from planner.onpolicy import RoundConfig, run_round
    from planner.ranker import RankerConfig
    from planner.ranker_train import RankerTrainConfig, load_examples

    run_round(RoundConfig(round=0, piles=1, top_k=1, repeats=2, min_logs=2, max_logs=2), tiny_model, tmp_path / "r0")
    chunk = json.loads(gzip.decompress((tmp_path / "r0" / "chunks" / "chunk_00000.json.gz").read_bytes()))
    trials = [t for s in chunk["piles"][0]["subsets"] for t in s["trials"]]
    ex = load_examples([tmp_path / "r0"], RankerConfig(), RankerTrainConfig())
    assert len(ex.labels) == 3 * len(trials) and int(ex.repeat.sum()) == 2 * len(trials)
    want = sorted(float(r[4] == "success") for t in trials for r in t["r"])
    assert sorted(ex.labels[ex.repeat].tolist()) == want
    plain = load_examples([tmp_path / "r0"], RankerConfig(), RankerTrainConfig(repeats=False))
    assert len(plain.labels) == len(trials) and not plain.repeat.any()
    assert sorted(plain.labels.tolist()) == sorted([r[4] for r in t["r"]].count("success") / 2 for t in trials)
