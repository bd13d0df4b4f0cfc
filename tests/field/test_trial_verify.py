"""Verified planning in the field trial (issue 17): the command carries the best grasp that
succeeded in the twin on the reconstruction; none -> nothing sent unless the operator names a
plan rank; a verification cut short by its budget chooses only among what it checked; the record
keeps every verification trial and ``replay`` reproduces them bit for bit (exit 5 when not).

The bundled scan is reconstructed and planned on for real; the twin's *verification* trials are a
stand-in (``planner.verify.run_trial`` replaced, one worker) whose rule is stated per test, so each
test knows which grasp must win. The crane is ``twin://`` with its fixed executor (no physics)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import pytest

import planner.verify
from field.cli import run
from field.cli.options import twin_url
from field.demo import DEMO_DATA, default_crane_base
from field.trial import NotVerified, TrialAborted, TrialOptions
from field.trial_record import replay_record, run_trial_record
from planner.verify import read_verification
from synth.scene.pile import read_pile
from synth.physics.trial import Outcome, TrialResult

pytestmark = pytest.mark.slow
SCAN, GNSS = DEMO_DATA / "scan", DEMO_DATA / "gnss.csv"
BASE = default_crane_base(read_pile(DEMO_DATA / "truth" / "pile.json"))
AGE = 10 * 365 * 86400.0  # the bundled scan is old: judge it against its own age limit here
LINK = twin_url("twin://", BASE, 10.0, AGE)


def options(**kw) -> TrialOptions:
    base = dict(objective="f3", max_pile_age_s=AGE, crane_base_tm=BASE, max_reach_m=10.0, verify_workers=1,
                verify_budget_s=None)
    return TrialOptions(**{**base, **kw})


def outcome(kind: str, grasp, targets, held=None, cos_beta: float = 0.999) -> TrialResult:
    held = tuple(targets if held is None else held) if kind == "success" else ()
    return TrialResult(outcome=Outcome(kind), grasp=grasp, targets=tuple(targets), n_targets=len(targets),
                       grasped=held, enclosed=held, cos_beta=cos_beta if held else math.nan, final_gap_m=0.02,
                       max_force_n=0.0, max_collision_force_n=0.0, max_penetration_m=0.0, max_log_speed_m_s=0.0,
                       phase_s={}, sim_time_s=1.0, wall_time_s=0.01, cpu_time_s=0.01, stop_reason="inside",
                       final_poses=())


def pile_print(pile) -> float:
    """A number in [0, 1) that changes with every log position of ``pile`` (a perturbed copy too)."""
    return math.fsum(c * (i + 1) for i, lg in enumerate(pile.logs) for c in lg.centre_m) * 1000.0 % 1.0


def log3_collides(pile, grasp, targets, cfg):
    """Every grasp that targets log 3 collides; every other one lifts all its targets, balanced by
    how the pile lies (so a trial on another pile copy measures another cos beta)."""
    return outcome("collision" if 3 in targets else "success", grasp, targets, cos_beta=0.95 + 0.04 * pile_print(pile))


def everything_collides(pile, grasp, targets, cfg):
    return outcome("collision", grasp, targets)


def slow_and_log3_holds_one(pile, grasp, targets, cfg):
    """0.6 s a trial; a grasp on log 3 lifts only its first target, every other one all of them."""
    time.sleep(0.6)
    return outcome("success", grasp, targets, held=targets[:1] if 3 in targets else None)


def twin(monkeypatch, fn) -> None:
    monkeypatch.setattr(planner.verify, "run_trial", fn)


@pytest.fixture(scope="module", autouse=True)
def reconstruct_once(tmp_path_factory):
    """The bundled scan is reconstructed once for this module (the reconstruction is deterministic, and
    what these tests check starts after it): later calls with the same inputs and configuration get a
    copy of the first one's folder. The reconstruction's own replay is checked for real in
    test_field_trial.py."""
    import copy
    import shutil
    from dataclasses import replace

    import reconstruct.pipeline as pipeline

    real, memo, mp = pipeline.reconstruct, {}, pytest.MonkeyPatch()

    def once(scan_dir, gnss_path, out_dir, config=None, **kw):
        files = sorted(f for f in Path(scan_dir).rglob("*") if f.is_file())
        key = (tuple((str(f.relative_to(scan_dir)), f.read_bytes()) for f in files), Path(gnss_path).read_bytes(),
               repr(config))
        if key not in memo:
            result = real(scan_dir, gnss_path, out_dir, config, **kw)
            memo[key] = moved(result, shutil.copytree(result.out_dir, tmp_path_factory.mktemp("reconstruction")
                                                      / "kept"))
            return result
        out_dir = Path(out_dir)
        shutil.copytree(memo[key].out_dir, out_dir, dirs_exist_ok=True)
        return moved(memo[key], out_dir)

    def moved(result, out_dir: Path):
        return replace(result, report=copy.deepcopy(result.report), out_dir=out_dir,
                       files={k: out_dir / Path(v).relative_to(result.out_dir) for k, v in result.files.items()})

    mp.setattr(pipeline, "reconstruct", once)
    yield
    mp.undo()


# -- the verified grasp is sent ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def verified(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    twin(mp, log3_collides)
    rec = tmp_path_factory.mktemp("verified") / "t"
    try:
        record = run_trial_record(SCAN, GNSS, LINK, rec, options(verify_k=6, verify_copies=1))
    finally:
        mp.undo()
    return rec, record


def test_the_command_carries_the_verified_grasp_not_a_higher_scored_failing_one(verified):
    rec, record = verified
    v = record["verification"]
    plan = record["plan"]["grasps"]
    cands = v["candidates"]
    assert v["ok"] and v["k"] == 6 and len(cands) == 6
    # the precondition: the network ranks a grasp on log 3 above the one the twin chose
    chosen = cands[[c["rank"] for c in cands].index(v["chosen_rank"])]
    assert 3 not in chosen["targets"] and chosen["outcome"] == "success"
    assert any(3 in c["targets"] and c["outcome"] == "collision" and c["rank"] < chosen["rank"] for c in cands)
    # of the successes, the one that measured best under f3: the most logs held
    succeeded = [c for c in cands if c["status"] == "checked" and c["outcome"] == "success"]
    assert len(chosen["held"]) == max(len(c["held"]) for c in succeeded)
    # the command is that grasp, and the record says it was verified
    assert record["chosen_rank"] == v["chosen_rank"] + 1 and record["verified"] is True
    assert record["command"]["target_log_count"] == len(plan[v["chosen_rank"]]["targets"])
    assert record["final_state"] == "SUCCESS"
    # every trial the twin ran is in the record and in plan/verification.json, the same; a grasp that
    # succeeded on the pile was tried on its perturbed copy too
    assert all(c["trials"] for c in cands if c["status"] == "checked")
    assert all([t["copy"] for t in c["trials"]] == [0, 1] for c in succeeded)
    assert chosen["trials"][0]["trial"]["cos_beta"] != chosen["trials"][1]["trial"]["cos_beta"]
    assert read_verification(rec / "plan" / "verification.json")["candidates"] == json.loads(
        (rec / "record.json").read_text())["verification"]["candidates"]


def test_the_perturbed_copies_jitter_each_log_by_the_reconstructions_own_sigma(verified):
    """Each log's copies move its ends by at least the reconstruction's sigma of its less certain end
    (an end from an RTK float point would be jittered by decimetres, not its fit class's centimetre;
    the bundled survey is all fixed, and one of its logs is still less sure than its class)."""
    from planner.pile_copies import FIT_SIGMAS_M
    from reconstruct.report import log_end_sigmas, read_report

    rec, record = verified
    report = read_report(rec / "reconstruction" / "report.json")
    got = record["verification"]["log_sigmas_m"]
    fits = [lg["fit"] for lg in report["logs"]]
    want = [max(FIT_SIGMAS_M[f][0], s / math.sqrt(3)) for f, s in zip(fits, log_end_sigmas(report))]
    assert [g[0] for g in got] == pytest.approx(want) and len(got) == len(fits)
    assert any(w > FIT_SIGMAS_M[f][0] for w, f in zip(want, fits))  # the case the wiring decides


def test_replay_reproduces_the_verification_bit_for_bit(verified, monkeypatch, tmp_path):
    rec, record = verified
    twin(monkeypatch, log3_collides)
    result = replay_record(rec, tmp_path / "w")
    assert result["identical"], result
    assert result["verification_identical"] and result["verification_differences"] == []


def test_replay_says_which_verification_trial_differs_and_exits_5(verified, monkeypatch, capsys, tmp_path):
    """The twin now drops what it lifted before: the command may be unchanged, the trials are not."""
    rec, record = verified

    def drops(pile, grasp, targets, cfg):
        return outcome("collision" if 3 in targets else "dropped", grasp, targets)

    twin(monkeypatch, drops)
    capsys.readouterr()
    code = run(["replay", str(rec), "--out", str(tmp_path / "w"), "--json"])
    out, err = capsys.readouterr()
    doc = json.loads(out)
    assert code == 5 and doc["identical"] is False and doc["verification_differences"]
    diffs = doc["verification_differences"]
    assert all(d.endswith(("copy 0: another result", "copy 1: not run again")) for d in diffs), diffs
    assert any(d.endswith("another result") for d in diffs) and any(d.endswith("not run again") for d in diffs)
    line = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(line) == 1 and "differs from the record" in line[0] and "verification rank" in line[0], err
    assert "Traceback" not in err


# -- nothing verified ------------------------------------------------------------------------------------
def test_nothing_is_sent_when_no_grasp_verified_unless_the_operator_names_a_rank(monkeypatch, tmp_path):
    twin(monkeypatch, everything_collides)
    with pytest.raises(NotVerified, match="no checked grasp succeeded.*operator_rank") as info:
        run_trial_record(SCAN, GNSS, LINK, tmp_path / "r", options(verify_k=3))
    assert info.value.kind == "refused"  # exit 4 in the CLI
    rec = json.loads((tmp_path / "r" / "record.json").read_text())
    assert rec["final_state"] == "NOT SENT" and "command" not in rec and "messages" not in rec
    assert [c["outcome"] for c in rec["verification"]["candidates"]] == ["collision"] * 3
    assert len(rec["plan"]["grasps"]) >= 3  # the plan the trials were of
    # the refusal replays as a refusal, with the same trials
    again = replay_record(tmp_path / "r", tmp_path / "w")
    assert again["identical"] and again["command_replayed"] is None, again

    # the operator names plan rank 2: it is sent, and marked as not verified everywhere
    seen = []
    record = run_trial_record(SCAN, GNSS, LINK, tmp_path / "r2", options(verify_k=3, operator_rank=2),
                              confirm=lambda p: seen.append(p) or True)
    prepared = seen[0]
    assert prepared.best is prepared.plan.grasps[1] and not prepared.verified
    lines = prepared.summary_lines()
    assert lines[0].startswith("WARNING: NOT VERIFIED") and "plan rank 2" in lines[1] and "collision" in lines[1]
    assert record["verified"] is False and record["chosen_rank"] == 2 and record["command"]
    assert record["command"]["target_log_count"] == len(record["plan"]["grasps"][1]["targets"])

    with pytest.raises(TrialAborted, match="operator_rank 99: the plan has only") as info:
        run_trial_record(SCAN, GNSS, LINK, tmp_path / "r3", options(verify_k=3, operator_rank=99))
    assert info.value.kind == "input"


# -- the time budget ---------------------------------------------------------------------------------------
def test_a_verification_cut_short_chooses_among_what_it_checked_and_replays_so(monkeypatch, tmp_path):
    """0.3 s of budget, 0.6 s a trial: only the network's best is checked (it lifts one log of its
    targets); the better grasps after it are never offered as checked. Without the budget the replay
    runs them all, and still chooses among the candidates the record checked."""
    twin(monkeypatch, slow_and_log3_holds_one)
    seen = []
    record = run_trial_record(SCAN, GNSS, LINK, tmp_path / "r", options(verify_k=4, verify_budget_s=0.3),
                              confirm=lambda p: seen.append(p) or True)
    v = record["verification"]
    assert 3 in record["plan"]["grasps"][0]["targets"]  # the precondition
    assert v["timed_out"] and v["chosen_rank"] == 0 and record["chosen_rank"] == 1
    status = [c["status"] for c in v["candidates"]]
    assert status[0] == "checked" and "not_checked" in status[1:] and set(status[1:]) <= {"not_checked", "pruned"}
    assert all(c["trials"] == [] for c in v["candidates"][1:])
    assert "1 of 4 candidates checked before the time budget ran out" in seen[0].summary_lines()[0]
    result = replay_record(tmp_path / "r", tmp_path / "w")
    assert result["identical"], result

    # a budget that runs out before one candidate has all the trials it needs: nothing sent, exit 2
    with pytest.raises(TrialAborted, match="verify_budget_s 0.3 s.*before any of the 2 candidates") as info:
        run_trial_record(SCAN, GNSS, LINK, tmp_path / "r2", options(verify_k=2, verify_budget_s=0.3,
                                                                  verify_copies=1))
    assert info.value.kind == "input"
    rec = json.loads((tmp_path / "r2" / "record.json").read_text())
    assert rec["final_state"] == "NOT SENT" and rec["verification"]["candidates"][0]["trials"]


def test_bad_verification_options_are_clear_errors():
    with pytest.raises(ValueError, match="verify_k must be a whole number >= 0"):
        options(verify_k=-1)
    with pytest.raises(ValueError, match="too small for one twin trial"):
        options(verify_budget_s=0.05)
    with pytest.raises(ValueError, match="operator_rank is a plan rank"):
        options(operator_rank=0)
    assert options(verify_k=0, verify_budget_s=0.05).verify_k == 0  # off: its budget is not used


def test_bad_ranker_options_are_clear_errors():
    with pytest.raises(ValueError, match="re-ranking is off"):
        options(rerank=False, ranker="r.safetensors")
    with pytest.raises(ValueError, match="rerank_k must be a whole number >= 1"):
        options(rerank_k=0)
    with pytest.raises(ValueError, match="u_weight must be in"):
        options(ranker_u_weight=1.5)


def test_trial_refuses_ranker_flags_that_contradict_or_name_no_file(capsys, tmp_path):
    from tests.cli_helpers import cli, fails

    args = ("trial", "--scan", DEMO_DATA / "scan", "--gnss", DEMO_DATA / "gnss.csv", "--link",
            "can://virtual/flags?insecure=1", "--record", tmp_path / "rec", "--yes")
    fails(cli(capsys, *args, "--ranker", DEMO_DATA / "gnss.csv", "--no-ranker"), 2, "--no-ranker")
    fails(cli(capsys, *args, "--ranker", tmp_path / "missing.safetensors"), 2, "--ranker")
    assert not (tmp_path / "rec").exists()  # refused before any work
