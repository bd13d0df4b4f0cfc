"""The evaluation loop: planners as functions, same piles, same trials, tables and resume."""

import json
import math

import pytest

from planner.evaluate import EvalConfig, evaluate_pile, run_evaluation
from planner.planners import PlannerSpec, geometric_planner
from planner.inference import checkpoint_precision
from planner.runtime import cpu_has_native_int8, default_precision, int8_kernels_available
from synth.scene.generate import GenerationConfig, generate_pile
from synth.geometry.grasp import Grasp
from synth.render.ortho import OrthoRenderConfig, render_ortho
from synth.physics.world import World


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


def test_records_of_another_trial_revision_are_not_reused(tmp_path, monkeypatch):
    """An evaluation made before the twin's physics changed is not resumed with the new physics."""
    import synth.physics.trial_spec

    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=1)
    run_evaluation([PlannerSpec("random")], cfg, tmp_path, workers=1)
    monkeypatch.setattr(synth.physics.trial_spec, "TRIAL_REVISION", synth.physics.trial_spec.TRIAL_REVISION + 1)
    with pytest.raises(ValueError, match="trial revision"):
        run_evaluation([PlannerSpec("random")], cfg, tmp_path, workers=1)


def test_bad_specs():
    with pytest.raises(ValueError):
        EvalConfig(per_cell=0)
    with pytest.raises(ValueError, match="unknown planner"):
        from planner.planners import build_planner

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


def test_the_verified_row_checks_on_a_perturbed_copy_never_on_the_test_pile():
    """The verifier in the evaluation tries the plan's grasps on a perturbed copy of the test pile
    (on the pile itself it would be the oracle) and returns the grasp that succeeded there."""
    from planner.planners import verified_planner
    from planner.inference import Objective, Plan, PlannedGrasp
    from synth.physics.trial import Outcome, TrialResult

    from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, quat_from_x_axis

    flat = tuple(tuple(0.0 for _ in range(32)) for _ in range(32))
    pile = PileSpec(terrain=TerrainSpec(resolution=32, heights_m=flat), seed=5,
                    logs=tuple(LogSpec((-1.0 + 0.8 * i, 0.0, 0.066), quat_from_x_axis((0, 1, 0)), 2.5, 0.16)
                               for i in range(3)))
    grasps = [PlannedGrasp(Grasp(0.1 * i, 0.0, 0.0, 0.8), 0.9 - 0.1 * i, 0.9, 1.0, (i,), (0, i)) for i in range(3)]
    seen = []

    def twin(p, grasp, targets, cfg):
        seen.append(p)
        ok = targets == (1,)
        held = targets if ok else ()
        return TrialResult(Outcome.SUCCESS if ok else Outcome.COLLISION, grasp, targets, len(targets), held, held,
                           1.0, 0.0, 0.0, 0.0, 0.0, 0.0, {}, 0.0, 0.0, 0.0, "inside", ())

    fn = verified_planner(lambda obs, p: Plan(list(grasps), 3, 0.0), "f1", k=3, trial_fn=twin)
    assert fn(None, pile) == (grasps[1].grasp, (1,))
    assert len(seen) == 2 and all(p != pile and p.n_logs == pile.n_logs for p in seen)
    assert all(p == seen[0] for p in seen)  # one stand-in for the reconstruction, the same for every candidate
    moved = [math.dist(a.centre_m, b.centre_m) for a, b in zip(seen[0].logs, pile.logs)]
    assert 0.0 < max(moved) < 0.1
    assert fn(None, pile) == (grasps[1].grasp, (1,)) and seen[2] == seen[0]  # repeatable
    declines = verified_planner(lambda obs, p: Plan(list(grasps), 3, 0.0), "f1", k=1, trial_fn=twin)
    assert declines(None, pile) is None  # the only grasp tried failed: no grasp, counted as a failure
    assert PlannerSpec("unet", model="m", objective="f3", verify_k=8).name == "unet-f3-verify8"
    assert PlannerSpec("unet", model="m", objective="f3", verify_k=8, verify_copies=3).name == "unet-f3-verify8x3"
    with pytest.raises(ValueError, match="verify_k"):
        from planner.planners import build_planner

        build_planner(PlannerSpec("unet", model="m", objective="f3", verify_k=-1))


def _tiny_checkpoint(path, cfg: EvalConfig, seed: int = 0):
    """An untrained tiny U-Net at the evaluation's image size, saved to ``path``."""
    from dataclasses import replace

    import torch

    from planner.checkpoint import save_checkpoint
    from planner.model import UNetConfig, build_unet

    net_cfg = replace(UNetConfig.tiny(), size_px=cfg.size_px)
    torch.manual_seed(seed)
    save_checkpoint(path, build_unet(net_cfg), net_cfg, {})
    return path


def test_a_row_with_a_subset_cap_plans_only_the_subsets_it_keeps(tmp_path, monkeypatch):
    """``max_subsets`` rows measure the pre-selection's cost in success: the plan sees only the capped
    subsets (a 2-log pile capped at 1 keeps its two single logs, never the pair)."""
    import planner.inference as inference

    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=1)
    ckpt = _tiny_checkpoint(tmp_path / "m.safetensors", cfg)
    seen = []
    real_plan = inference.plan

    def spy(*a, **k):
        p = real_plan(*a, **k)
        seen.append(sorted(tuple(g.targets) for g in real_plan(*a, **{**k, "top_k": None}).grasps))
        return p

    monkeypatch.setattr(inference, "plan", spy)
    capped = PlannerSpec("unet", model=str(ckpt), objective="f1", max_subsets=1)
    assert capped.name == "unet-f1-cap1" and capped.subset_policy().mode == "fit"
    assert PlannerSpec("unet", model="m", max_subsets=8, verify_k=4).name == "unet-f1-cap8-verify4"
    tables = run_evaluation([capped, PlannerSpec("unet", model=str(ckpt), objective="f1")], cfg, tmp_path / "e",
                            workers=1)
    assert set(tables["planners"]) == {"unet-f1-cap1", "unet-f1"}
    assert seen[0] == [(0,), (1,)] and seen[1] == [(0,), (0, 1), (1,)], seen
    with pytest.raises(ValueError, match="max_subsets"):
        from planner.planners import build_planner

        build_planner(PlannerSpec("unet", model=str(ckpt), max_subsets=-1))


def test_a_row_with_test_time_views_plans_with_them_and_keeps_its_own_records(tmp_path, monkeypatch):
    """``views`` rows plan with the planner's averaged dihedral views (the planner the row builds has
    them), carry them in their name and in the fingerprint that decides whether a record is reused:
    the same label planned with other views is tried again."""
    from dataclasses import replace

    import planner.inference as inference
    from planner.evaluate import _fingerprint
    from planner.planners import build_planner

    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=1)
    ckpt = _tiny_checkpoint(tmp_path / "m.safetensors", cfg)
    seen = []
    real_plan = inference.plan

    def spy(obs, net, *a, **k):
        seen.append((net.views, net.view_spread_k))
        return real_plan(obs, net, *a, **k)

    monkeypatch.setattr(inference, "plan", spy)
    plain = PlannerSpec("unet", model=str(ckpt), objective="f3")
    viewed = PlannerSpec("unet", model=str(ckpt), objective="f3", views=8, view_spread_k=2.0)
    assert viewed.name == "unet-f3-views8k2" and PlannerSpec("unet", model="m", views=4).name == "unet-f1-views4"
    tables = run_evaluation([plain, viewed], cfg, tmp_path / "e", workers=1)
    assert set(tables["planners"]) == {"unet-f3", "unet-f3-views8k2"}
    assert sorted(seen) == [(1, 0.0), (8, 2.0)], seen
    assert len({_fingerprint(plain), _fingerprint(viewed), _fingerprint(replace(viewed, view_spread_k=1.0)),
                _fingerprint(replace(viewed, views=4))}) == 4
    with pytest.raises(ValueError, match="views must be one of"):
        build_planner(PlannerSpec("unet", model=str(ckpt), views=3))


@pytest.mark.skipif(not int8_kernels_available(), reason="this torch has no oneDNN int8 kernels")
def test_an_int8_row_plans_with_the_int8_network_and_keeps_its_own_records(tmp_path, monkeypatch):
    """``precision`` rows plan with the network in that number format, are named ``unet-f1-int8`` and
    fingerprinted apart, with the calibration's own hash: a recalibrated model's int8 records are made
    again. "auto" keeps the name it had; it runs, and is fingerprinted, as load_planner resolves it: int8
    where the CPU has int8 dot products and the model a calibration, else the float format of the records
    made before the field existed."""
    from dataclasses import replace

    import numpy as np
    import torch

    import planner.inference as inference
    from planner.checkpoint import load_checkpoint
    from planner.evaluate import _fingerprint
    from planner.int8 import calibrate, calibration_path, write_calibration

    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=1)
    ckpt = _tiny_checkpoint(tmp_path / "m.safetensors", cfg)
    model = load_checkpoint(ckpt)[0]
    rng = np.random.default_rng(0)
    x = np.zeros((4, 3, cfg.size_px, cfg.size_px), np.float32)
    x[:, 0], x[:, 1], x[:, 2] = rng.random(x.shape[2:]), rng.random(x.shape[2:]) * 0.5, rng.random(x[:, 2].shape) > 0.7
    with torch.no_grad():
        write_calibration(calibration_path(ckpt), calibrate(model, [x]))
    seen = []
    real_plan = inference.plan

    def spy(obs, net, *a, **k):
        seen.append(net.precision)
        return real_plan(obs, net, *a, **k)

    monkeypatch.setattr(inference, "plan", spy)
    plain = PlannerSpec("unet", model=str(ckpt), objective="f1")
    int8, fp32 = replace(plain, precision="int8"), replace(plain, precision="fp32")
    assert int8.name == "unet-f1-int8" and plain.name == "unet-f1" and fp32.name == "unet-f1-fp32"
    tables = run_evaluation([plain, int8, fp32], cfg, tmp_path / "e", workers=1)
    assert set(tables["planners"]) == {"unet-f1", "unet-f1-int8", "unet-f1-fp32"}
    auto = checkpoint_precision(ckpt, "cpu")  # int8 where this CPU has int8 dot products: it is calibrated
    assert auto == ("int8" if cpu_has_native_int8() else default_precision("cpu"))
    assert sorted(seen) == sorted([auto, "int8", "fp32"])
    before = _fingerprint(int8)
    assert _fingerprint(fp32) not in (before, _fingerprint(plain))
    assert (_fingerprint(plain) == before) == (auto == "int8")  # "auto" in int8 is int8's records' kind
    with torch.no_grad():
        write_calibration(calibration_path(ckpt), calibrate(model, [x[:2]]))
    assert _fingerprint(int8) != before and _fingerprint(int8).startswith(_fingerprint(fp32).split("+")[0] + "+int8-")
    calibration_path(ckpt).unlink()  # no calibration: "auto" is the float format, its records those made before
    assert "+" not in _fingerprint(plain) and checkpoint_precision(ckpt, "cpu") == default_precision("cpu")


def test_an_f3_row_with_another_balance_tolerance_or_source_plans_with_it_and_keeps_its_own_records(tmp_path, monkeypatch):
    """``sigma_b`` and ``balance`` rows score f3's Q with their balance tolerance and source (the
    objective the planner is called with carries them), are named ``unet-f3-sbS`` / ``unet-f3-hang``
    and fingerprinted apart; f1 ignores them; a tolerance of 0 or an unknown source is refused."""
    from dataclasses import replace

    import planner.inference as inference
    from planner.evaluate import _fingerprint
    from planner.planners import build_planner

    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=1)
    ckpt = _tiny_checkpoint(tmp_path / "m.safetensors", cfg)
    seen = []
    real_plan = inference.plan

    def spy(obs, net, objective, *a, **k):
        seen.append((objective.kind, objective.sigma_b, objective.balance))
        return real_plan(obs, net, objective, *a, **k)

    monkeypatch.setattr(inference, "plan", spy)
    plain = PlannerSpec("unet", model=str(ckpt), objective="f3")
    harsh = PlannerSpec("unet", model=str(ckpt), objective="f3", sigma_b=0.05)
    hang = PlannerSpec("unet", model=str(ckpt), objective="f3", balance="hang")
    assert harsh.name == "unet-f3-sb0.05" and PlannerSpec("unet", model="m", sigma_b=0.05).name == "unet-f1"
    tables = run_evaluation([plain, harsh, hang], cfg, tmp_path / "e", workers=1)
    assert set(tables["planners"]) == {"unet-f3", "unet-f3-sb0.05", "unet-f3-hang"}
    assert sorted(seen) == [("f3", 0.05, "network"), ("f3", 0.25, "hang"), ("f3", 0.25, "network")], seen
    assert len({_fingerprint(plain), _fingerprint(harsh), _fingerprint(replace(harsh, sigma_b=0.1)),
                _fingerprint(replace(harsh, balance="hang"))}) == 4
    assert replace(harsh, balance="hang").name == "unet-f3-hang-sb0.05"
    with pytest.raises(ValueError, match="sigma_b"):
        build_planner(PlannerSpec("unet", model=str(ckpt), objective="f3", sigma_b=0.0))
    with pytest.raises(ValueError, match="balance must be one of"):
        build_planner(PlannerSpec("unet", model=str(ckpt), objective="f3", balance="guess"))


def test_a_smaller_balance_tolerance_prefers_the_better_balanced_pixel():
    """f3's Q: a pixel of U 0.97 at beta 20 deg beats one of U 0.90 at beta 5 deg under the paper's
    sigma_b 0.25, and loses under 0.05."""
    from planner.inference import Objective

    u, b = [0.97, 0.90], [math.cos(math.radians(20)), math.cos(math.radians(5))]
    assert Objective("f3").quality(u, 1.0, b).argmax() == 0
    assert Objective("f3", sigma_b=0.05).quality(u, 1.0, b).argmax() == 1


def test_field_row_executes_each_choice_moved_by_one_shared_draw(tmp_path):
    """With a field error every planner's chosen grasp is tried again moved by the same draw of the
    positioning error on a pile (paired), the table gets a '(field)' row per planner stating the
    error, and that row counts the field trials' outcomes."""
    import math

    from synth.physics.perturb import PositioningError, grasp_rng, perturbed_grasps
    from planner.evaluate import eval_scene
    from synth.geometry.grasp import Grasp
    from synth.physics.trial import TrialConfig, run_trial

    err = PositioningError(0.03, 2.0)
    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=2, field_error=err)
    tables = run_evaluation([PlannerSpec("random"), PlannerSpec("geometric")], cfg, tmp_path, workers=1)
    recs = [r for p in sorted((tmp_path / "records").glob("*.json")) for r in json.loads(p.read_text())]
    offsets = {}
    for r in recs:
        if r["grasp"] is None:
            assert r["field"]["outcome"] == "no_grasp"
            continue
        g, f = r["grasp"], r["field"]["grasp"]
        (want,) = perturbed_grasps(Grasp(g["x_m"], g["y_m"], g["phi_rad"], g["width_m"]), err, 1,
                                   grasp_rng(r["seed"], "eval-field"))
        assert math.isclose(f["x_m"], want.x_m) and math.isclose(f["phi_rad"], want.phi_rad)
        assert (f["x_m"], f["y_m"]) != (g["x_m"], g["y_m"]) and f["width_m"] == g["width_m"]
        offsets.setdefault(r["seed"], set()).add((round(f["x_m"] - g["x_m"], 9), round(f["y_m"] - g["y_m"], 9)))
    assert offsets and all(len(v) == 1 for v in offsets.values())  # the same draw for every planner on a pile
    r = next(r for r in recs if r["grasp"] is not None)
    pile, _ = eval_scene((r["n_logs"], r["obstacles"], r["k"], r["seed"]), cfg)
    moved = Grasp(**{k: r["field"]["grasp"][k] for k in ("x_m", "y_m", "phi_rad", "width_m")})
    t = run_trial(pile, moved, r["targets"], TrialConfig.preset(cfg.trial))  # the field outcome is the moved grasp's
    assert t.outcome.value == r["field"]["outcome"]
    for name in ("random", "geometric"):
        field = [x for x in recs if x["planner"] == name]
        want = sum(x["field"]["outcome"] == "success" for x in field) / len(field)
        assert tables["planners"][name + " (field)"]["total"]["success_rate"] == want
    assert tables["field_error"] == {"sigma_xy_m": 0.03, "sigma_phi_deg": 2.0}
    md = (tmp_path / "results.md").read_text()
    assert "σ 3 cm, 2°" in md and "| random (field) |" in md


def test_a_field_row_added_later_remakes_the_records_without_it(tmp_path):
    plain = EvalConfig(logs=(2,), obstacles=(False,), per_cell=1)
    run_evaluation([PlannerSpec("random")], plain, tmp_path, workers=1)
    (rec,) = json.loads(next((tmp_path / "records").glob("*.json")).read_text())
    assert rec["field"] is None
    from dataclasses import replace

    from synth.physics.perturb import PositioningError

    tables = run_evaluation([PlannerSpec("random")], replace(plain, field_error=PositioningError(0.03, 2.0)), tmp_path,
                            workers=1)
    (rec,) = json.loads(next((tmp_path / "records").glob("*.json")).read_text())
    assert rec["field"] is not None and rec["model_sha256"] == "+field0.03m2deg"
    assert "random (field)" in tables["planners"]


def test_field_rows_count_the_field_trials_not_the_exact_ones():
    from planner.evaluate import summarise
    from synth.physics.perturb import PositioningError

    cfg = EvalConfig(logs=(2,), obstacles=(False,), per_cell=2, field_error=PositioningError(0.03, 2.0))
    base = {"planner": "unet-f1", "n_logs": 2, "obstacles": False, "targets": [0, 1], "cos_beta": 1.0}
    recs = [{**base, "k": 0, "outcome": "success", "grasped": [0, 1],
             "field": {"outcome": "collision", "grasped": [], "cos_beta": float("nan"), "grasp": None}},
            {**base, "k": 1, "outcome": "success", "grasped": [0, 1],
             "field": {"outcome": "success", "grasped": [0], "cos_beta": 0.99, "grasp": None}}]
    t = summarise(recs, cfg, ["unet-f1"])["planners"]
    assert t["unet-f1"]["total"]["success_rate"] == 1.0 and t["unet-f1"]["total"]["avg_logs_success"] == 2.0
    field = t["unet-f1 (field)"]["total"]
    assert field["success_rate"] == 0.5 and field["avg_logs_success"] == 1.0 and field["failures"] == {"collision": 1}


def test_planning_clear_of_obstacles_remakes_only_the_records_of_piles_with_obstacles(tmp_path):
    from dataclasses import replace

    import torch

    from planner.checkpoint import save_checkpoint
    from planner.evaluate import _pile_tag
    from planner.model import UNetConfig, build_unet

    cfg = EvalConfig(logs=(2,), obstacles=(True, False), per_cell=1)
    net_cfg = replace(UNetConfig.tiny(), size_px=cfg.size_px)
    ckpt = tmp_path / "m.safetensors"
    torch.manual_seed(0)
    save_checkpoint(ckpt, build_unet(net_cfg), net_cfg, {})
    clear, noclear = (PlannerSpec("unet", model=str(ckpt), objective="f1", clear_obstacles=c) for c in (True, False))
    assert (clear.name, noclear.name) == ("unet-f1", "unet-f1-noclear")
    with_obst, without = sorted(cfg.tasks(), key=lambda t: not t[1])
    assert (_pile_tag(clear, with_obst), _pile_tag(clear, without), _pile_tag(noclear, with_obst)) == ("+claws", "", "")
    run_evaluation([clear, noclear], cfg, tmp_path, workers=1)
    sha = {t[1]: {r["planner"]: r["model_sha256"] for r in json.loads((tmp_path / "records" / f"{t[3]}.json").read_text())}
           for t in (with_obst, without)}
    assert sha[True]["unet-f1"] == sha[False]["unet-f1"] + "+claws" == sha[True]["unet-f1-noclear"] + "+claws"
    assert sha[False]["unet-f1"] == sha[False]["unet-f1-noclear"]


def test_records_of_the_openings_footprint_are_not_the_claws(monkeypatch):
    """A record planned clear of obstacles with the opening's rectangle ("+clear") is made again once the claws'
    footprint is the default ("+claws"), and would be reused were the opening's the default again."""
    import planner.constraints
    from planner.evaluate import _pile_tag
    from synth.geometry.grasp import RECT_WIDTH_M

    spec, task = PlannerSpec("unet", model="m.safetensors", objective="f3"), (3, True, 0, 1)
    assert _pile_tag(spec, task) == "+claws"
    opening = planner.constraints.Constraints(claw_plate_m=0.0, claw_width_m=RECT_WIDTH_M)
    monkeypatch.setattr(planner.constraints, "Constraints", lambda: opening)
    assert _pile_tag(spec, task) == "+clear"
