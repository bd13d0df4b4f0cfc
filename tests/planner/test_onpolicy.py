"""On-policy rounds: the network's choices tried in the twin under the positioning error, stored as labels."""

from __future__ import annotations

import gzip
import json

import pytest

from planner.onpolicy import RoundConfig, RoundError, run_round
from synth.physics.perturb import PositioningError


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    import torch

    from planner.checkpoint import save_checkpoint
    from planner.model import UNetConfig, build_unet

    path = tmp_path_factory.mktemp("m") / "tiny.safetensors"
    cfg = UNetConfig.tiny(size_px=128)
    torch.manual_seed(0)
    save_checkpoint(path, build_unet(cfg), cfg, {})
    return path


CFG = RoundConfig(round=0, piles=1, top_k=1, repeats=3, error=PositioningError(0.03, 2.0), min_logs=2, max_logs=2)


def test_a_round_stores_each_choice_with_its_repeated_outcomes(tmp_path, tiny_model):
    """Each tried grasp is one trial whose repeats are real twin trials of the grasp moved by the
    positioning error; the round is a store whose shards carry the success fraction as the label."""
    from synth.data.datastore import materialize
    from synth.data.shards import iter_samples

    store = run_round(CFG, tiny_model, tmp_path / "r0")
    assert store["summary"]["complete"] and store["params"]["onpolicy"]["repeats"] == 3
    d = json.loads(gzip.decompress((tmp_path / "r0" / "chunks" / "chunk_00000.json.gz").read_bytes()))
    subsets = d["piles"][0]["subsets"]
    assert len(subsets) in (1, 2) and all(s["capped"] for s in subsets)  # top-1 by f1 and by f3
    fractions = {}
    for s in subsets:
        (t,) = s["trials"]
        assert len(t["r"]) == 3 and all(len(r) == 5 for r in t["r"]) and 0.0 <= t["u"] <= 1.0
        fractions[tuple(s["targets"])] = [r[4] for r in t["r"]].count("success") / 3
        assert bool(s["accepted"]) == (fractions[tuple(s["targets"])] >= 0.5)
    samples = list(iter_samples(materialize(tmp_path / "r0", tmp_path / "cache")))
    assert {tuple(s.subset): float(s.trials[0, 4]) for s in samples} == fractions
    assert all(s.capped for s in samples)


def test_the_repeats_are_the_grasp_moved_by_the_error(tmp_path, tiny_model):
    """Replaying the stored grasp moved by the round's draws gives the stored outcomes."""
    from planner.evaluate import EvalConfig, eval_scene
    from synth.geometry.grasp import Grasp
    from synth.physics.perturb import grasp_rng, perturbed_grasps
    from synth.physics.trial import TrialConfig, run_trial

    run_round(CFG, tiny_model, tmp_path / "r0")
    d = json.loads(gzip.decompress((tmp_path / "r0" / "chunks" / "chunk_00000.json.gz").read_bytes()))
    s = d["piles"][0]["subsets"][0]
    pile, _ = eval_scene(CFG.task(0), EvalConfig())
    g = Grasp(*s["trials"][0]["g"])
    moved = perturbed_grasps(g, CFG.error, 3, grasp_rng(CFG.task(0)[3], "onpolicy", tuple(s["targets"])))
    trial = TrialConfig.preset("fast")
    assert [[m.x_m, m.y_m, m.phi_rad, m.width_m, run_trial(pile, m, s["targets"], trial).outcome.value]
            for m in moved] == s["trials"][0]["r"]
    assert run_trial(pile, g, s["targets"], trial).outcome.value == s["trials"][0]["o"]  # the exact execution


def test_a_round_resumes_and_refuses_another_model_or_other_piles(tmp_path, tiny_model):
    from dataclasses import replace

    run_round(CFG, tiny_model, tmp_path / "r0")
    calls = []
    run_round(CFG, tiny_model, tmp_path / "r0", plan_fn=lambda o, p: calls.append(1))
    assert calls == []  # the finished pile is kept, not planned again
    other = tmp_path / "other.safetensors"
    other.write_bytes(tiny_model.read_bytes() + b" ")
    with pytest.raises(RoundError, match="made with another model"):
        run_round(CFG, other, tmp_path / "r0")
    with pytest.raises(RoundError, match="other piles or settings.*round"):
        run_round(replace(CFG, round=1), tiny_model, tmp_path / "r0")
    with pytest.raises(RoundError, match="cannot read the checkpoint"):
        run_round(CFG, tmp_path / "none.safetensors", tmp_path / "r1")
