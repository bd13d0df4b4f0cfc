"""Verified planning (planner.verify): selection logic against a stand-in twin, one real trial run.

The stand-in (:func:`fake_trial`) reads what each candidate does from the pile's ``notes`` (JSON:
the copy number, and per candidate - keyed by its grasp's x in tenths of a metre - the outcome on
each copy and how long to take), so that it works in worker processes too."""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace

import numpy as np
import pytest

from planner.errors import PlannerError
from planner.inference import Objective, Plan, PlannedGrasp
from planner.pile_copies import PerturbationConfig, perturb_pile
from planner.verify import (NOT_CHECKED, PRUNED, NoVerifiedGrasp, VerificationBudgetError, VerificationError, VerifyConfig,
                            measured_quality, select_candidates, verify_plan)
from synth.geometry.grasp import Grasp
from synth.scene.pile import LogSpec, PileSpec, RockSpec, TerrainSpec, quat_from_x_axis
from synth.physics.trial import Outcome, TrialResult


# -- a stand-in twin --------------------------------------------------------------------------
def flat_pile(n_logs: int = 4, resolution: int = 32) -> PileSpec:
    heights = tuple(tuple(0.0 for _ in range(resolution)) for _ in range(resolution))
    logs = tuple(LogSpec(centre_m=(-1.2 + 0.8 * i, 0.0, 0.41 * 0.16), orientation=quat_from_x_axis((0, 1, 0)),
                         length_m=2.5, diameter_m=0.16) for i in range(n_logs))
    return PileSpec(terrain=TerrainSpec(resolution=resolution, heights_m=heights), logs=logs)


def result(outcome: str, grasp: Grasp, targets, cos_beta: float = 0.999) -> TrialResult:
    held = tuple(targets) if outcome == "success" else ()
    return TrialResult(outcome=Outcome(outcome), grasp=grasp, targets=tuple(targets), n_targets=len(targets),
                       grasped=held, enclosed=held, cos_beta=cos_beta if held else math.nan, final_gap_m=0.02,
                       max_force_n=0.0, max_collision_force_n=0.0, max_penetration_m=0.0, max_log_speed_m_s=0.0,
                       phase_s={}, sim_time_s=1.0, wall_time_s=0.01, cpu_time_s=0.01, stop_reason="inside",
                       final_poses=())


def fake_trial(pile, grasp, targets, cfg):
    spec = json.loads(pile.notes)
    key = str(round(grasp.x_m * 10))
    time.sleep(spec.get("sleep", {}).get(key, 0.0))
    what = spec["outcomes"][key]
    outcome = what[spec["copy"]] if isinstance(what, list) else what
    if outcome == "raise":
        raise RuntimeError("the stand-in twin broke")
    return result(outcome, grasp, targets, spec.get("cos_beta", {}).get(key, 0.999))


def plan_of(*cands) -> Plan:
    """A plan from (targets, network quality) pairs, best first; candidate i at x = i / 10 m."""
    grasps = [PlannedGrasp(Grasp(i / 10, 0.0, 0.0, 0.8), q, q, 1.0, tuple(t), (0, i)) for i, (t, q) in enumerate(cands)]
    return Plan(sorted(grasps, key=lambda g: -g.quality), len(grasps), 0.0)


def piles_for(outcomes: dict, copies: int = 0, **extra) -> list[PileSpec]:
    base = flat_pile()
    return [replace(base, notes=json.dumps({"copy": c, "outcomes": outcomes, **extra})) for c in range(copies + 1)]


def run(plan, outcomes, objective="f3", copies=0, **cfg):
    piles = piles_for(outcomes, copies, **cfg.pop("extra", {}))
    config = VerifyConfig(**{"time_budget_s": None, "workers": 1, **cfg},
                          perturbation=PerturbationConfig(copies=copies))
    from planner.verify import Verifier

    with Verifier(config, fake_trial) as v:
        return v.verify(plan, piles[0], Objective(objective), piles=piles)


# -- choosing ------------------------------------------------------------------------------------
def test_a_verified_grasp_wins_over_a_higher_scored_failing_one():
    plan = plan_of(((0, 1, 2), 0.9), ((0, 1), 0.8), ((3,), 0.5))
    v = run(plan, {"0": "collision", "1": "success", "2": "success"})
    assert v.ok and v.chosen.rank == 1, v.reason
    assert v.grasp is plan.grasps[1]
    assert v.candidates[0].outcome == "collision" and v.candidates[0].checked
    assert "verified" in v.reason and "rank 2" in v.reason


def test_the_measured_objective_decides_between_successes():
    """f3 scores what the trial held: the 3-log success beats the better-ranked 2-log one; f1 (u only)
    keeps the network's order among successes."""
    plan = plan_of(((0, 1), 0.9), ((1, 2, 3), 0.8))
    outcomes = {"0": "success", "1": "success"}
    assert run(plan, outcomes, "f3").chosen.rank == 1
    assert run(plan, outcomes, "f1").chosen.rank == 0
    g = Grasp(0.0, 0.0, 0.0, 0.8)
    f3 = Objective("f3")
    assert measured_quality(f3, result("success", g, (0, 1, 2), 0.999)) > measured_quality(f3, result("success", g, (0, 1)))
    assert measured_quality(f3, result("success", g, (0,), 0.6)) < measured_quality(f3, result("success", g, (0,), 1.0))
    assert measured_quality(f3, result("collision", g, (0, 1, 2))) == 0.0


def test_no_success_is_a_typed_refusal_that_says_why():
    plan = plan_of(((0, 1), 0.9), ((2,), 0.8), ((3,), 0.7))
    v = run(plan, {"0": "collision", "1": "not_closed", "2": "raise"})
    assert not v.ok and v.chosen is None and v.grasp is None
    assert [c.outcome for c in v.candidates] == ["collision", "not_closed", "trial_error"]
    assert all(c.checked for c in v.candidates)
    assert "no checked grasp succeeded" in v.reason
    for word in ("collision", "not_closed", "trial_error"):
        assert word in v.reason
    assert "the stand-in twin broke" in v.candidates[2].trials[0].error  # the cause is kept
    with pytest.raises(NoVerifiedGrasp) as info:
        v.require()
    assert info.value.verification is v and isinstance(info.value, PlannerError)
    d = v.to_dict()
    assert d["ok"] is False and [c["outcome"] for c in d["candidates"]] == ["collision", "not_closed", "trial_error"]


def test_pruning_skips_only_what_cannot_win():
    plan = plan_of(((0, 1, 2), 0.9), ((0, 1), 0.8), ((1, 2, 3, 0), 0.7))
    outcomes = {"0": "success", "1": "success", "2": "collision"}
    pruned = run(plan, outcomes, "f3")
    full = run(plan, outcomes, "f3", prune=False)
    assert pruned.chosen.rank == full.chosen.rank == 0
    # the 2-log grasp cannot beat a verified 3-log one; the 4-log one could, so it is tried
    assert [c.status for c in pruned.candidates] == ["checked", PRUNED, "checked"]
    assert all(c.checked for c in full.candidates)
    assert pruned.candidates[1].trials == ()


def test_perturbed_copies_prefer_the_grasp_that_succeeds_most_often():
    plan = plan_of(((0, 1, 2), 0.9), ((1, 2, 3), 0.8), ((3,), 0.7))
    outcomes = {"0": ["success", "dropped", "collision", "success"],  # 2 of 4
                "1": ["success", "success", "success", "dropped"],  # 3 of 4
                "2": ["not_closed", "success", "success", "success"]}  # fails on the pile as given
    v = run(plan, outcomes, "f3", copies=3)
    assert v.chosen.rank == 1 and v.chosen.successes == 3
    assert [len(c.trials) for c in v.candidates] == [4, 4, 1]  # no copies after a failure
    assert not v.candidates[2].verified
    assert run(plan, outcomes, "f3", copies=0).chosen.rank == 0  # without copies: the first success


@pytest.mark.parametrize("copies, best", [(0, 3), (2, 0)])
def test_the_choice_is_the_same_with_one_or_two_workers(copies, best):
    """Rank 0 is slow, so with two workers rank 1 finishes first and is the best for a while; the
    choice must not depend on that. On the pile alone the 4-log grasp (rank 3) wins; with copies the
    3-log one that succeeds on all of them (rank 0)."""
    plan = plan_of(((0, 1, 2), 0.9), ((0, 1), 0.85), ((2, 3), 0.8), ((0, 1, 2, 3), 0.7), ((3,), 0.6))
    outcomes = {"0": ["success", "success", "success"], "1": ["success"] * 3, "2": ["collision"] * 3,
                "3": ["success", "dropped", "success"], "4": ["success"] * 3}
    extra = {"sleep": {"0": 0.4}}
    one = run(plan, outcomes, "f3", copies=copies, workers=1, extra=extra)
    two = run(plan, outcomes, "f3", copies=copies, workers=2, extra=extra)
    assert one.chosen.rank == two.chosen.rank == best
    assert one.chosen.trials == two.chosen.trials


# -- the time budget -------------------------------------------------------------------------------
def test_a_timed_out_verification_says_what_was_checked_and_never_offers_the_rest():
    plan = plan_of(*[((i % 4,), 0.9 - 0.1 * i) for i in range(6)])
    outcomes = {str(i): "collision" for i in range(6)} | {"5": "success"}
    v = run(plan, outcomes, "f1", time_budget_s=0.5, extra={"sleep": {str(i): 0.2 for i in range(6)}})
    assert v.timed_out and not v.ok
    checked = [c.rank for c in v.candidates if c.checked]
    # the best ranks first, none skipped, and the budget stopped it before rank 5, the one success
    assert checked[:1] == [0] and checked == list(range(checked[-1] + 1)) and len(checked) <= 4, checked
    assert 5 not in checked and all(c.outcome == "collision" for c in v.candidates if c.checked)
    assert all(c.status == NOT_CHECKED and c.trials == () for c in v.candidates[len(checked):])
    assert "time budget" in v.reason and "not_checked" in v.reason


def test_a_grasp_whose_copies_the_budget_cut_off_is_not_offered_as_checked():
    plan = plan_of(((0, 1), 0.9), ((2,), 0.8))
    outcomes = {"0": ["collision"] * 3, "1": ["success"] * 3}
    v = run(plan, outcomes, "f1", copies=2, time_budget_s=0.35, extra={"sleep": {"0": 0.2, "1": 0.2}})
    assert v.timed_out and not v.ok, v.reason
    assert v.candidates[1].status == NOT_CHECKED and v.candidates[1].nominal.success  # ran on the pile, not its copies
    with pytest.raises(NoVerifiedGrasp):
        v.require()


def test_budgets_too_small_for_one_trial_are_clear_errors():
    with pytest.raises(ValueError, match="too small for one twin trial"):
        VerifyConfig(time_budget_s=0.01)
    plan = plan_of(((0, 1), 0.9))
    with pytest.raises(VerificationBudgetError, match="before any candidate was checked") as info:
        run(plan, {"0": ["success"] * 3}, "f1", copies=2, time_budget_s=0.2, extra={"sleep": {"0": 0.25}})
    assert info.value.verification.candidates[0].nominal.success


# -- bad input ---------------------------------------------------------------------------------------
def test_bad_input_is_refused_clearly(monkeypatch):
    plan = plan_of(((0, 1), 0.9))
    f1 = Objective("f1")
    for k in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="k"):
            VerifyConfig(k=k)
    with pytest.raises(VerificationError, match="needs the pile the plan was made on"):
        verify_plan(plan, None, f1, VerifyConfig(workers=1), trial_fn=fake_trial)
    with pytest.raises(VerificationError, match="the plan targets log 3 but the pile has 2 logs"):
        verify_plan(plan_of(((0, 3), 0.9)), flat_pile(2), f1, VerifyConfig(workers=1), trial_fn=fake_trial)
    with pytest.raises(VerificationError, match="needs a planner.inference.Plan"):
        verify_plan({"grasps": []}, flat_pile(), f1, VerifyConfig(workers=1), trial_fn=fake_trial)
    flat_rock = RockSpec(position_m=(1.8, 1.8, 0.0), orientation=(0.0, 0.0, 0.0, 1.0),
                         vertices_m=((0, 0, 0), (0.3, 0, 0), (0, 0.3, 0), (0.3, 0.3, 0)))
    with pytest.raises(VerificationError, match="the twin cannot load the pile") as info:
        verify_plan(plan, replace(flat_pile(), rocks=(flat_rock,)), f1, VerifyConfig(workers=1), trial_fn=fake_trial)
    assert info.value.__cause__ is not None
    with pytest.raises(ValueError, match="copies"):
        PerturbationConfig(copies=-1)


def test_an_empty_plan_gives_a_refusal():
    v = verify_plan(Plan([], 0, 0.0), flat_pile(), Objective("f1"), VerifyConfig(workers=1), trial_fn=fake_trial)
    assert not v.ok and v.candidates == () and "no grasp" in v.reason


# -- candidates and copies --------------------------------------------------------------------------
def test_candidates_are_the_k_best_distinct_ones():
    g = lambda x, phi=0.0: Grasp(x, 0.0, phi, 0.8)  # noqa: E731
    grasps = [PlannedGrasp(g(0.0), 0.9, 0.9, 1.0, (0, 1), (0, 0)),
              PlannedGrasp(g(0.01), 0.85, 0.9, 1.0, (0, 1), (0, 0)),  # same targets, 1 cm away: the same trial
              PlannedGrasp(g(0.01), 0.8, 0.9, 1.0, (0,), (0, 0)),  # other targets: worth trying
              PlannedGrasp(g(0.0, 0.5), 0.7, 0.9, 1.0, (0, 1), (0, 0)),  # same targets, turned 29 deg
              PlannedGrasp(g(0.3), 0.6, 0.9, 1.0, (2,), (0, 0))]
    plan = Plan(grasps, 4, 0.0)
    assert [r for r, _ in select_candidates(plan, 8)] == [0, 2, 3, 4]
    assert [r for r, _ in select_candidates(plan, 2)] == [0, 2]


def test_perturbed_copies_are_repeatable_physical_and_about_sigma_away():
    pile = flat_pile(3)
    cfg = PerturbationConfig(copies=2, seed=5, log_end_sigma_m=0.02, diameter_sigma_m=0.01)
    a, b = perturb_pile(pile, cfg, 1), perturb_pile(pile, cfg, 1)
    assert a == b
    c = perturb_pile(pile, cfg, 2)
    assert c != a and perturb_pile(pile, replace(cfg, seed=6), 1) != a
    moved = [np.linalg.norm(np.subtract(x.endpoints_m()[0], y.endpoints_m()[0])[:2])
             for p in (a, c) for x, y in zip(p.logs, pile.logs)]
    assert 0.001 < float(np.median(moved)) < 0.08
    from synth.physics.world import World

    for p in (a, c):
        assert p.n_logs == pile.n_logs
        with World(p, visuals=False) as w:
            w.check_valid(0.006)  # nothing pushed into the ground or another body
    still = perturb_pile(pile, PerturbationConfig(log_end_sigma_m=0.0, log_end_sigma_z_m=0.0, diameter_sigma_m=0.0,
                                                 obstacle_sigma_m=0.0, obstacle_scale_sigma=0.0), 1)
    for x, y in zip(still.logs, pile.logs):
        assert np.allclose(x.centre_m, y.centre_m, atol=1e-9) and np.allclose(x.orientation, y.orientation, atol=1e-9)
    with pytest.raises(ValueError):
        perturb_pile(pile, cfg, 0)


# -- the real twin ------------------------------------------------------------------------------------
def test_the_real_twin_verifies_the_grasp_on_the_log_over_a_better_scored_miss():
    """One log lies along y at x = -1.2; the network's best grasp misses it by a metre, the second is
    centred on it: run_trial tells them apart."""
    pile = flat_pile(1)
    miss = PlannedGrasp(Grasp(-0.2, 0.0, 0.0, 0.6), 0.9, 0.9, 1.0, (0,), (0, 0))
    hit = PlannedGrasp(Grasp(-1.2, 0.0, 0.0, 0.6), 0.8, 0.8, 1.0, (0,), (0, 0))
    v = verify_plan(Plan([miss, hit], 1, 0.0), pile, Objective("f3"), VerifyConfig(workers=1, time_budget_s=None))
    assert v.ok and v.chosen.rank == 1, v.reason
    assert v.candidates[0].outcome != "success" and v.chosen.held == (0,)
    assert v.chosen.cos_beta > 0.95 and v.trial_cpu_s > 0


def test_replayed_trials_are_compared_bit_for_bit_but_for_their_times():
    from planner.verify import trial_differences

    plan = plan_of(((0, 1), 0.9), ((2,), 0.8))
    rec = json.loads(json.dumps(run(plan, {"0": "collision", "1": "success"}).to_dict()))
    again = run(plan, {"0": "collision", "1": "success"}).to_dict()
    again["candidates"][0]["trials"][0]["trial"]["wall_time_s"] = 99.0
    assert trial_differences(rec, again) == []  # NaN cos beta of the failure compares equal too
    other = run(plan, {"0": "collision", "1": "success"}, extra={"cos_beta": {"1": 0.998}}).to_dict()
    assert trial_differences(rec, other) == ["rank 2 copy 0: another result"]
    fewer = run(plan_of(((0, 1), 0.9)), {"0": "collision"}).to_dict()
    assert trial_differences(rec, fewer) == ["rank 2 copy 0: not run again"]
    assert trial_differences(fewer, rec) == []  # the replay may check more than the record did


def test_after_the_budget_what_could_not_win_anyway_is_pruned_not_unchecked():
    plan = plan_of(((0, 1, 2), 0.9), ((0, 1), 0.8), ((1, 2, 3, 0), 0.7))
    v = run(plan, {"0": "success", "1": "success", "2": "success"}, "f3", time_budget_s=0.3,
            extra={"sleep": {"0": 0.4}})
    assert v.ok and v.chosen.rank == 0
    assert [c.status for c in v.candidates] == ["checked", PRUNED, NOT_CHECKED]  # the 4-log one could have won
    assert v.timed_out and "time budget" in v.reason


def test_a_written_verification_reads_back_and_a_newer_major_version_is_refused(tmp_path):
    from planner.verify import read_verification

    v = run(plan_of(((0, 1), 0.9)), {"0": "success"})
    path = tmp_path / "verification.json"
    path.write_text(json.dumps(v.to_dict()))
    d = read_verification(path)
    assert d["ok"] and d["chosen_rank"] == 0 and d["candidates"][0]["trials"][0]["outcome"] == "success"
    path.write_text(json.dumps({**v.to_dict(), "format_version": "2.0"}))
    with pytest.raises(VerificationError, match="newer"):
        read_verification(path)


def test_logs_the_reconstruction_hardly_saw_are_jittered_more():
    from planner.pile_copies import FIT_SIGMAS_M, perturbation_for_fits

    cfg = perturbation_for_fits(["scan", "partial", "hidden", "what"], PerturbationConfig(copies=2, seed=3))
    assert cfg.copies == 2 and cfg.seed == 3
    assert cfg.log_sigmas_m == (FIT_SIGMAS_M["scan"], FIT_SIGMAS_M["partial"], FIT_SIGMAS_M["hidden"],
                                FIT_SIGMAS_M["hidden"])  # an unknown class counts as the least certain
    assert FIT_SIGMAS_M["scan"] < FIT_SIGMAS_M["partial"] < FIT_SIGMAS_M["hidden"]
    with pytest.raises(VerificationError, match="log_sigmas_m gives 4 logs but the pile has 3"):
        perturb_pile(flat_pile(3), cfg, 1)


def test_ends_the_reconstruction_is_unsure_of_are_jittered_by_its_own_sigma():
    """A log whose end came from an RTK float point (+-17 cm, 3-D) is jittered by that, not by its fit
    class's centimetre; a log the reconstruction is surer of than its class keeps the class figure."""
    from planner.pile_copies import FIT_SIGMAS_M, perturbation_for_fits

    cfg = perturbation_for_fits(["scan", "scan", "partial"], PerturbationConfig(copies=1), [0.17, 0.005, None])
    assert cfg.log_sigmas_m[0] == (pytest.approx(0.17 / math.sqrt(3)), FIT_SIGMAS_M["scan"][1])
    assert cfg.log_sigmas_m[1] == FIT_SIGMAS_M["scan"] and cfg.log_sigmas_m[2] == FIT_SIGMAS_M["partial"]
    with pytest.raises(ValueError, match="end_sigmas_m gives 1 logs but fits 3"):
        perturbation_for_fits(["scan", "scan", "partial"], None, [0.1])
