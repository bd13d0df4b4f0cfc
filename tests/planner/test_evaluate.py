"""The evaluation loop: planners as functions, same piles, same trials, tables and resume."""

import json

import pytest

from planner.evaluate import EvalConfig, PlannerSpec, evaluate_pile, geometric_planner, run_evaluation
from synth.generate import GenerationConfig, generate_pile
from synth.grasp import Grasp
from synth.render import OrthoRenderConfig, render_ortho
from synth.world import World


def test_geometric_planner_grasps_across_an_isolated_pair():
    pile, _ = generate_pile(4, GenerationConfig(n_logs=2))
    with World(pile) as w:
        obs = render_ortho(w, OrthoRenderConfig(n_renders=1))
    choice = geometric_planner()(obs, pile)
    assert choice is not None
    grasp, targets = choice
    assert isinstance(grasp, Grasp) and len(targets) >= 1


def test_planner_passed_as_a_function_and_tables(tmp_path):
    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=2)
    calls = []

    def declines(obs, pile):
        calls.append(pile.seed)
        return None

    recs = evaluate_pile(cfg.tasks()[0], [PlannerSpec("geometric"), PlannerSpec("random", label="mine")], cfg,
                         planners={"mine": declines})
    assert [r["planner"] for r in recs] == ["geometric", "mine"]
    assert recs[1]["outcome"] == "no_grasp" and len(calls) == 1
    assert recs[0]["outcome"] in {"success", "more_than_intended", "fewer_or_other", "collision", "not_closed",
                                  "dropped", "no_grasp"}

    tables = run_evaluation([PlannerSpec("random")], cfg, tmp_path, workers=1)
    t = tables["planners"]["random"]["total"]
    assert t["piles"] == 2 and 0.0 <= t["success_rate"] <= 1.0
    assert "Table 1" in (tmp_path / "results.md").read_text()
    # resume: records exist, a second run recomputes nothing and gives the same tables
    before = sorted(p.read_text() for p in (tmp_path / "records").glob("*.json"))
    again = run_evaluation([PlannerSpec("random")], cfg, tmp_path, workers=1)
    assert again == json.loads(json.dumps(tables))
    assert sorted(p.read_text() for p in (tmp_path / "records").glob("*.json")) == before


def test_other_configuration_refused(tmp_path):
    run_evaluation([PlannerSpec("random")], EvalConfig(logs=(2,), obstacles=(False,), per_cell=1), tmp_path, workers=1)
    with pytest.raises(ValueError, match="another configuration"):
        run_evaluation([PlannerSpec("random")], EvalConfig(logs=(3,), obstacles=(False,), per_cell=1), tmp_path,
                       workers=1)
    # more piles per cell extends the same evaluation: the first pile's record is kept as it is
    first = sorted((tmp_path / "records").glob("*.json"))
    kept = first[0].read_bytes()
    tables = run_evaluation([PlannerSpec("random")], EvalConfig(logs=(2,), obstacles=(False,), per_cell=2), tmp_path,
                            workers=1)
    assert tables["planners"]["random"]["total"]["piles"] == 2 and first[0].read_bytes() == kept


def test_bad_specs():
    with pytest.raises(ValueError):
        EvalConfig(per_cell=0)
    with pytest.raises(ValueError, match="unknown planner"):
        from planner.evaluate import build_planner

        build_planner(PlannerSpec("magic"))


def test_resume_adds_planners_and_reruns_records_of_another_checkpoint(tmp_path):
    from dataclasses import replace

    import torch

    from planner.checkpoint import save_checkpoint
    from planner.model import UNetConfig, build_unet

    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=1)
    out = tmp_path / "eval"
    run_evaluation([PlannerSpec("random")], cfg, out, workers=1)
    rec_file = next((out / "records").glob("*.json"))
    random_rec = json.loads(rec_file.read_text())[0]

    # a planner added later runs on the same pile; the random record is kept byte for byte
    net_cfg = replace(UNetConfig.tiny(), size_px=cfg.size_px)
    ckpt = tmp_path / "m.safetensors"
    torch.manual_seed(0)
    save_checkpoint(ckpt, build_unet(net_cfg), net_cfg, {})
    unet = PlannerSpec("unet", model=str(ckpt), objective="f1")
    run_evaluation([unet, PlannerSpec("random")], cfg, out, workers=1)
    recs = {r["planner"]: r for r in json.loads(rec_file.read_text())}
    assert recs["random"] == random_rec
    sha1 = recs["unet-f1"]["model_sha256"]
    assert len(sha1) == 64
    assert json.loads((out / "eval.json").read_text())["planners"][0]["model_sha256"] == sha1

    # another model written to the same path: its records are not reused
    torch.manual_seed(1)
    save_checkpoint(ckpt, build_unet(net_cfg), net_cfg, {})
    run_evaluation([unet, PlannerSpec("random")], cfg, out, workers=1)
    recs = {r["planner"]: r for r in json.loads(rec_file.read_text())}
    assert recs["unet-f1"]["model_sha256"] not in ("", sha1) and recs["random"] == random_rec

    rec_file.write_text("{not json")
    with pytest.raises(ValueError, match="corrupt.*delete it"):
        run_evaluation([PlannerSpec("random")], cfg, out, workers=1)
