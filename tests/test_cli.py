"""Every ``loggrasp`` command as a field engineer or a script meets it (issue 20): ``--help`` for
each; each command's happy path, tiny; each bad input of the issue. Every case asserts the exit
code, one ``error:`` line naming the problem and the flag or file to fix, no traceback, nothing
half-written, and standard output that parses as JSON where ``--json`` is given.

Commands run in-process through :func:`field.cli.run` (the one error handler); what only a real
process shows (C libraries' output on file descriptors 1 and 2, a crane in another process) runs
as a subprocess. The heavy fixtures (the demo's trial, a trial over twin://) are module-scoped and
shared."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from field.cli import app, run
from field.demo import DEMO_DATA
from tests.cli_helpers import ROOT, Result, cli, fails, loggrasp_process

# -- help, version, README ---------------------------------------------------------------------------
COMMANDS = [[], ["synth"], ["synth", "piles"], ["synth", "render"], ["synth", "dataset"], ["synth", "scan"],
            ["train"], ["plan"], ["eval"], ["survey"], ["reconstruct"], ["compare-piles"], ["crane-sim"], ["trial"],
            ["replay"], ["demo"], ["link-key"], ["audit", "verify"]]


@pytest.mark.parametrize("args", COMMANDS)
def test_help_shows_units_and_no_placeholders(capsys, args):
    r = cli(capsys, *args, "--help")
    assert r.code == 0 and "Usage" in r.out
    assert "<bool>" not in r.out and "[default: False]" not in r.out
    assert not re.search(r"\w \.(\s|$)", r.out), "a unit was eaten ('Boom reach .')"


@pytest.mark.parametrize("args,flag,unit", [
    (["crane-sim"], "--max-reach", "[m]"), (["crane-sim"], "--max-pile-age", "[s]"),
    (["trial"], "--capacity", "[kg]"), (["synth", "piles"], "--size", "[px]"), (["synth", "scan"], "--hfov", "[deg]"),
])
def test_help_keeps_units(capsys, args, flag, unit):
    text = cli(capsys, *args, "--help").out
    block = re.search(rf"^  {flag}\b.*?(?=^  -|\Z)", text, re.M | re.S).group(0)
    assert unit in block, block


def test_version(capsys):
    r = cli(capsys, "--version")
    assert r.code == 0 and re.fullmatch(r"loggrasp \d+\.\d+\.\d+\S*\n", r.out)


def test_no_arguments_prints_help_and_exit_codes(capsys):
    r = cli(capsys)
    assert r.code == 0 and "Commands:" in r.out and "Exit codes" in r.out


def test_help_is_fast_and_imports_nothing_heavy():
    code = ("import sys, time; t=time.time(); from field.cli import app; "
            "heavy=[m for m in ('torch','pybullet','cv2','open3d','zenoh','can','pyproj') if m in sys.modules]; "
            "print(heavy, time.time()-t)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.startswith("[]"), out


def test_readme_command_list_matches_help():
    """Every `loggrasp ...` line of the README's command list names a command and flags that
    exist, every command is listed, and with all its flags."""
    from typer.main import get_command

    root = get_command(app)
    text = (ROOT / "README.md").read_text()
    block = text[text.index("## Commands"):]
    block = block[block.index("```sh") + 5:block.index("```", block.index("```sh") + 5)]
    listed: dict[str, set[str]] = {}
    for line in block.splitlines():
        line = line.split("#")[0].strip()
        if not line.startswith("loggrasp "):
            continue
        words = line.split()[1:]
        cmd, path = root, []
        while words and hasattr(cmd, "commands") and words[0] in cmd.commands:
            cmd = cmd.commands[words[0]]
            path.append(words.pop(0))
        flags = {o for p in cmd.params for o in (*p.opts, *p.secondary_opts)}
        named = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", line))
        assert named <= flags, f"README: `loggrasp {' '.join(path)}` has no {sorted(named - flags)}"
        listed.setdefault(" ".join(path), set()).update(named)
    every = {" ".join(p) for p in COMMANDS if p != ["synth"]}
    assert every <= set(listed), f"README lists no {sorted(every - set(listed))}"
    for name in every:
        cmd = root
        for word in name.split():
            cmd = cmd.commands[word]
        flags = {o for p in cmd.params for o in p.opts if o.startswith("--")} - {"--help"}
        assert flags <= listed[name], f"README: `loggrasp {name}` lacks {sorted(flags - listed[name])}"


# -- synth --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pile_dir(work) -> Path:
    """A tiny generated pile (2 logs, one render), made with a group-readable umask."""
    old = os.umask(0o027)
    try:
        assert run(["synth", "piles", "--count", "1", "--logs", "2", "--renders", "1", "--workers", "1",
                    "--out", str(work / "piles")]) == 0
    finally:
        os.umask(old)
    return work / "piles" / "pile_00000"


def test_synth_piles_modes_follow_the_umask(pile_dir):
    for p in (pile_dir, pile_dir / "pile.json", pile_dir / "ortho.npz", pile_dir.parent / "job.json"):
        want = 0o750 if p.is_dir() else 0o640
        assert p.stat().st_mode & 0o777 == want, (p, oct(p.stat().st_mode))


def test_synth_piles_json_and_plural(capsys, work, pile_dir):
    r = cli(capsys, "synth", "piles", "--count", "1", "--logs", "2", "--renders", "1", "--workers", "1",
            "--out", work / "piles", "--json")
    assert r.code == 0 and r.json()["skipped"] == 1
    assert "0 piles generated, 1 already there" in r.err  # words on stderr under --json


def test_synth_piles_typo_leaves_nothing_and_the_fix_runs(capsys, work):
    out = work / "typo"
    for bad, flag in ((["--size", "0"], "--size"), (["--size", "20"], "--size"), (["--workers", "-3"], "--workers"),
                      (["--logs", "x"], "--logs"), (["--count", "0"], "--count")):
        fails(cli(capsys, "synth", "piles", "--count", "1", *bad, "--out", out), 2, flag)
        assert not out.exists(), f"{bad} left {list(out.rglob('*'))}"
    r = cli(capsys, "synth", "piles", "--count", "1", "--logs", "2", "--renders", "1", "--size", "64", "--workers", "1",
            "--out", out)
    assert r.code == 0 and (out / "pile_00000" / "ortho.npz").exists()
    assert not list(out.glob(".*tmp*"))


def test_synth_render(capsys, work, pile_dir, a_file):
    r = cli(capsys, "synth", "render", pile_dir, "--out", work / "render", "--renders", "1", "--json")
    assert r.code == 0 and len(r.json()["files"]) == 2 and (work / "render" / "ortho.npz").exists()
    fails(cli(capsys, "synth", "render", pile_dir, "--out", a_file / "x"), 2, "--out", str(a_file))
    fails(cli(capsys, "synth", "render", work / "nowhere"), 2, "nowhere", "does not exist")
    bad = work / "garbage"
    bad.mkdir()
    (bad / "pile.json").write_text("{")
    fails(cli(capsys, "synth", "render", bad), 2, str(bad / "pile.json"), "not valid JSON")
    (bad / "pile.json").write_text('{"format": "loggrasp.pile", "format_version": "1.0", "terrain": [1]}')
    fails(cli(capsys, "synth", "render", bad), 2, str(bad / "pile.json"), "malformed")


def test_synth_scan_bad_site_and_paths(capsys, work, a_file):
    for site in ("abc", "20.0,64.1", "1,2,3,4"):
        fails(cli(capsys, "synth", "scan", "--site", site, "--out", work / "s"), 2, "--site")
    fails(cli(capsys, "synth", "scan", "--float-fixes", "-1", "--out", work / "s"), 2, "--float-fixes")
    fails(cli(capsys, "synth", "scan", "--pairs", "9x9", "--out", work / "s"), 2, "--pairs")
    fails(cli(capsys, "synth", "scan", "--out", a_file / "s"), 2, "--out", str(a_file))
    assert not (work / "s").exists()


def test_synth_scan_pairs_auto_bad_input(capsys, work):
    """--pairs takes NXxNY or auto; auto with a camera so low its planned pairs would leave gaps is bad input."""
    assert "auto" in cli(capsys, "synth", "scan", "--help").out
    fails(cli(capsys, "synth", "scan", "--pairs", "autox", "--out", work / "s"), 2, "--pairs", "auto")
    fails(cli(capsys, "synth", "scan", "--pairs", "auto", "--height", "0.6", "--out", work / "s"), 2, "--pairs auto",
          "gaps")
    assert not (work / "s").exists()


@pytest.mark.slow
def test_synth_scan_pairs_auto(capsys, work):
    """A tiny real run: the pairs planned from the survey (a compact 2-log pile: the 2x2 grid), the plan in
    scan.json."""
    r = cli(capsys, "synth", "scan", "--seed", "1", "--logs", "2", "--obstacles", "0", "--pairs", "auto",
            "--float-fixes", "0", "--out", work / "auto", "--json")
    assert r.code == 0, r.err
    info = json.loads((work / "auto" / "scan.json").read_text())
    assert info["plan"]["grid"] == [2, 2] and info["pairs"] == 4 and "scan plan from the survey: 2x2 pairs" in r.err
    assert len(list((work / "auto" / "scan").glob("pair_*"))) == 4


SMALL_DATA = ["synth", "dataset", "--piles", "2", "--logs", "2", "--size", "64", "--renders", "1",
              "--max-trials-per-subset", "1", "--label-repeats", "0", "--workers", "1"]


@pytest.fixture(scope="module")
def small_data(work) -> Path:
    """A 64 px data set of two 2-log piles with the paper's one-success labels (--label-repeats 0),
    made once per module: re-running the command on it returns at once."""
    assert run(SMALL_DATA + ["--out", str(work / "data")]) == 0
    return work / "data"


@pytest.mark.slow
def test_synth_dataset_and_train_a_64px_network(capsys, work, a_file, small_data):
    """A 64 px data set trains from the command line (the network takes the data set's size), either
    mask injection."""
    from planner.checkpoint import load_checkpoint

    fails(cli(capsys, "synth", "dataset", "--piles", "1", "--engine", "spark", "--out", work / "d"), 2, "--engine")
    fails(cli(capsys, "synth", "dataset", "--piles", "1", "--out", a_file / "d"), 2, "--out")
    for logs in ("5-3", "2-12", "two"):
        fails(cli(capsys, "synth", "dataset", "--piles", "1", "--logs", logs, "--out", work / "d"), 2, "--logs")
    assert not (work / "d").exists()
    # the paper's one-success labels (--label-repeats 0): the same samples and trials, without the repeats
    r = cli(capsys, *SMALL_DATA, "--out", small_data, "--json")
    assert r.code == 0 and r.json()["summary"]["samples"] > 0
    fails(cli(capsys, "train", "--data", work / "data", "--out", a_file / "r"), 2, "--out")
    fails(cli(capsys, "train", "--data", work / "none", "--out", work / "r"), 2, "--data")
    r = cli(capsys, "train", "--data", work / "data", "--out", work / "run", "--epochs", "1", "--max-steps-per-epoch",
            "1", "--base-channels", "4", "--batch-size", "2", "--json")
    d = r.json()
    assert r.code == 0 and d["size_px"] == 64 and Path(d["model"]).exists()
    r = cli(capsys, "train", "--data", work / "data", "--out", work / "late", "--epochs", "1", "--max-steps-per-epoch",
            "1", "--base-channels", "4", "--batch-size", "2", "--mask-injection", "decoder", "--json")
    assert r.code == 0 and load_checkpoint(r.json()["model"])[1].mask_injection == "decoder"
    fails(cli(capsys, "train", "--data", work / "data", "--out", work / "r2", "--mask-injection", "middle"), 2,
          "--mask-injection")


def test_train_outcome_labels_and_the_beta_map(capsys, work, tmp_path, small_data):
    """``--labels outcome`` trains on every trial of a data set made by `synth dataset`; a data set without
    trials, or with --skip-no-candidates, is a one-line error."""
    import dataclasses

    from planner.checkpoint import load_checkpoint
    from synth.data.shards import ShardWriter, iter_samples, read_manifest, write_manifest

    fails(cli(capsys, "train", "--data", work / "data", "--out", work / "o1", "--labels", "outcome",
              "--skip-no-candidates"), 2, "--skip-no-candidates", "--labels outcome")
    r = cli(capsys, "train", "--data", work / "data", "--out", work / "outcome", "--epochs", "1", "--max-steps-per-epoch",
            "1", "--base-channels", "4", "--batch-size", "2", "--labels", "outcome", "--b-encoding", "beta_10deg", "--json")
    assert r.code == 0, r.err
    assert load_checkpoint(r.json()["model"])[1].b_encoding == "beta_10deg"
    cfg = json.loads((work / "outcome" / "train_config.json").read_text())
    assert cfg["data"]["labels"] == "outcome" and cfg["loss"]["u_pos_weight"] == 1.0
    old = tmp_path / "old"  # the same samples without their trials, as a data set from before outcome labels
    w = ShardWriter(old, "t", 0)
    for s in iter_samples(work / "data"):
        w.add(dataclasses.replace(s, trials=None, capped=None))
    man = read_manifest(work / "data")
    write_manifest(old, dataclasses.replace(man, shards=[w.close()]))
    fails(cli(capsys, "train", "--data", old, "--out", tmp_path / "r", "--epochs", "1", "--max-steps-per-epoch", "1",
              "--base-channels", "4", "--labels", "outcome"), 2, "no trial outcomes", "--labels accepted")


# -- plan ---------------------------------------------------------------------------------------------
def test_plan_json_png_and_table(capsys, work, pile_dir):
    png = work / "plan.png"
    r = cli(capsys, "plan", pile_dir, "--objective", "f3", "--json", "--png", png)
    d = r.json()
    assert r.code == 0 and d["format"] == "loggrasp.plan" and d["grasps"][0]["targets"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = cli(capsys, "plan", pile_dir, "--top", "3")
    rows = [ln.split() for ln in r.out.splitlines() if re.match(r"\s*\d+\s+[\d,]+\s", ln)]
    assert r.code == 0 and rows and all(len(row) == 9 for row in rows), r.out  # every column, never cut
    assert "…" not in r.out


def test_plan_f3_balance_flags_reach_the_objective(capsys, pile_dir, monkeypatch):
    """plan's f3 is the product's by default (planner.inference.PRODUCT_F3_BALANCE with its own sigma_b);
    --f3-balance hang gives the hang model (sigma_b 0.05), network the paper's B map (0.25), unless
    --f3-sigma-b; the plan is scored with that objective, its grasps carry that balance and the plan
    file names it."""
    import planner.ranker as ranker
    from planner.inference import PRODUCT_F3_BALANCE, f3_sigma_b

    seen, real = [], ranker.plan_reranked

    def spy(obs, planner, objective, *a, **k):
        seen.append((objective.balance, objective.sigma_b))
        return real(obs, planner, objective, *a, **k)

    monkeypatch.setattr(ranker, "plan_reranked", spy)
    cli(capsys, "plan", pile_dir, "--objective", "f3", "--no-ranker")
    hang = cli(capsys, "plan", pile_dir, "--objective", "f3", "--f3-balance", "hang", "--no-ranker", "--json").json()
    net = cli(capsys, "plan", pile_dir, "--objective", "f3", "--f3-balance", "network", "--no-ranker", "--json").json()
    cli(capsys, "plan", pile_dir, "--objective", "f3", "--f3-balance", "network", "--f3-sigma-b", "0.1", "--no-ranker")
    assert seen == [(PRODUCT_F3_BALANCE, f3_sigma_b(PRODUCT_F3_BALANCE)), ("hang", 0.05), ("network", 0.25),
                    ("network", 0.1)]
    assert [g["balance"] for g in hang["grasps"]] != [g["balance"] for g in net["grasps"]]
    assert hang["objective"] == {"kind": "f3", "balance": "hang", "sigma_b": 0.05}  # the file says what f3 meant
    fails(cli(capsys, "plan", pile_dir, "--f3-sigma-b", "-1"), 2, "--f3-sigma-b -1: f3's balance tolerance")


def test_plan_clears_obstacles_unless_told_to_grasp_over_them(capsys, pile_dir, monkeypatch):
    import planner.ranker as ranker

    seen, real = [], ranker.plan_reranked

    def spy(obs, planner, objective, ranker_, constraints, *a, **k):
        seen.append(constraints.clear_obstacles)
        return real(obs, planner, objective, ranker_, constraints, *a, **k)

    monkeypatch.setattr(ranker, "plan_reranked", spy)
    cli(capsys, "plan", pile_dir, "--no-ranker")
    cli(capsys, "plan", pile_dir, "--no-ranker", "--grasp-over-obstacles")
    assert seen == [True, False]


def test_plan_precision_int8_is_opt_in_and_refused_where_it_cannot_run(capsys, pile_dir, monkeypatch):
    import planner.runtime as runtime

    d = cli(capsys, "plan", pile_dir, "--objective", "f3", "--precision", "int8", "--no-ranker", "--json").json()
    assert d["grasps"][0]["targets"]
    monkeypatch.setattr(runtime, "int8_kernels_available", lambda: False)
    fails(cli(capsys, "plan", pile_dir, "--precision", "int8"), 2, "--precision int8", "use 'bf16' or 'fp32'")
    cli(capsys, "plan", pile_dir, "--no-ranker")  # auto never needs them


def test_plan_bad_input(capsys, work, pile_dir, a_file):
    fails(cli(capsys, "plan", pile_dir, "--top", "-2"), 2, "--top")
    fails(cli(capsys, "plan", pile_dir, "--top", "0"), 2, "--top")
    fails(cli(capsys, "plan", pile_dir, "--views", "3"), 2, "--views must be one of")
    fails(cli(capsys, "plan", pile_dir, "--view-spread", "1"), 2, "--view-spread", "needs views > 1")
    fails(cli(capsys, "plan", pile_dir, "--png", a_file / "x.png"), 2, "--png", str(a_file))
    fails(cli(capsys, "plan", pile_dir, "--png", work / "plan.txt"), 2, "--png", ".png")
    fails(cli(capsys, "plan", pile_dir, "--model", work / "none.safetensors"), 2, "--model", "none.safetensors")
    assert not (work / "plan.txt").exists()


def test_plan_beside_a_truncated_render(capsys, work, pile_dir):
    """A truncated ortho.npz beside a good pile.json: rendered from the pile, with a warning; a
    truncated ortho.npz alone: an error naming it."""
    both = work / "truncated"
    both.mkdir()
    shutil.copy(pile_dir / "pile.json", both)
    (both / "ortho.npz").write_bytes((pile_dir / "ortho.npz").read_bytes()[:3000])
    r = cli(capsys, "plan", both, "--json")
    assert r.code == 0 and r.json()["grasps"] and "warning:" in r.err and "ortho.npz" in r.err
    alone = work / "truncated_alone"
    alone.mkdir()
    shutil.copy(both / "ortho.npz", alone)
    fails(cli(capsys, "plan", alone / "ortho.npz"), 2, str(alone / "ortho.npz"), "truncated")


def test_plan_verify_tries_the_best_grasps_in_the_twin(capsys, work):
    """`plan --verify K` on a real pile and the real twin: the JSON carries every candidate's
    trials, the table the twin columns; exit 4 (no link involved) when none succeeded."""
    pile = DEMO_DATA / "truth" / "pile.json"
    r = cli(capsys, "plan", pile, "--objective", "f3", "--verify", "3", "--verify-workers", "1", "--json")
    d = r.json()
    v = d["verification"]
    assert r.code in (0, 4), r.err
    assert v["format"] == "loggrasp.verification" and v["k"] == 3 and len(v["candidates"]) == 3
    assert v["ok"] == (r.code == 0) and (v["ok"] or "no checked grasp succeeded" in r.error)
    assert all(c["trials"] for c in v["candidates"] if c["status"] == "checked")
    assert len(d["grasps"]) >= 5  # --top's rows, and every candidate's
    r = cli(capsys, "plan", pile, "--objective", "f3", "--verify", "2", "--verify-workers", "1", "--top", "2")
    header = next(ln for ln in r.out.splitlines() if ln.startswith("rank"))
    assert header.split()[-4:] == ["twin", "held", "beta", "deg"], header
    rows = [ln.split() for ln in r.out.splitlines() if re.match(r"\s*\d+\s+[\d,]+\s", ln)]
    assert len(rows) == 2 and all(len(row) == 12 for row in rows), r.out
    assert sum(row[9].startswith("*") for row in rows) == (1 if r.code == 0 else 0)
    assert ("verified: plan rank" in r.out) == (r.code == 0)


def test_plan_verify_bad_input(capsys, work, pile_dir):
    fails(cli(capsys, "plan", pile_dir, "--verify", "0"), 2, "--verify 0", ">= 1")
    fails(cli(capsys, "plan", pile_dir, "--verify", "-1"), 2, "--verify -1")
    fails(cli(capsys, "plan", pile_dir, "--verify", "2", "--verify-budget", "0.05"), 2, "--verify-budget 0.05",
          "too small for one twin trial")
    fails(cli(capsys, "plan", pile_dir, "--verify-copies", "2"), 2, "--verify-copies needs --verify")
    alone = work / "ortho_alone"
    alone.mkdir(exist_ok=True)
    shutil.copy(pile_dir / "ortho.npz", alone)
    fails(cli(capsys, "plan", alone / "ortho.npz", "--verify", "2"), 2, "--verify needs the pile", "no pile.json")
    fails(cli(capsys, "plan", alone, "--verify", "2"), 2, "--verify needs the pile")
    # a pile the twin cannot load (a rock whose vertices are flat has no hull): named, before the network
    d = json.loads((pile_dir / "pile.json").read_text())
    d["rocks"] = [{"position_m": [0.5, 0.5, 0.0], "orientation": [0.0, 0.0, 0.0, 1.0],
                   "vertices_m": [[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0], [0.3, 0.3, 0]]}]
    (work / "flat_rock.json").write_text(json.dumps(d))
    fails(cli(capsys, "plan", work / "flat_rock.json", "--verify", "2"), 2, "the twin cannot load the pile")
    # ... and without --verify, where the pile is only rendered: the same one line, no traceback
    fails(cli(capsys, "plan", work / "flat_rock.json"), 2, "the twin cannot load the pile")


# -- eval ---------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_eval_tiny_strict_json_and_examples(capsys, work, a_file):
    out = work / "eval"
    # on this pile the random baseline fails: a planner without successes has no beta_avg (NaN), which
    # must reach stdout and results.json as null
    r = cli(capsys, "eval", "--per-cell", "1", "--logs", "2", "--obstacles", "no", "--objectives", "f1",
            "--baselines", "random", "--seed-base", "900000001", "--workers", "1", "--out", out, "--json")
    d = r.json()
    assert r.code == 0 and d["format"] == "loggrasp.eval-results" and set(d["planners"]) == {"unet-f1", "random"}
    random_total = d["planners"]["random"]["total"]
    assert random_total["success_rate"] == 0.0 and random_total["beta_avg_deg"] is None
    Result(0, (out / "results.json").read_text(), "").json()  # no NaN in the file either
    assert (out / "examples.png").exists() and "1 pile per cell" in (out / "results.md").read_text()
    md = (out / "results.md").read_text().splitlines()
    for i, ln in enumerate(md):  # every Markdown table row has its header's cells
        if ln.startswith("|---"):
            assert ln.count("|") == md[i - 1].count("|") and md[i + 1].count("|") == ln.count("|"), md[i - 1:i + 2]
    r = cli(capsys, "eval", "--per-cell", "1", "--logs", "2", "--obstacles", "no", "--objectives", "f1",
            "--baselines", "random", "--seed-base", "900000001", "--workers", "1", "--out", out, "--field-error",
            "0.03,2", "--json")  # the same evaluation with a field row
    d = r.json()
    assert r.code == 0 and set(d["planners"]) == {"unet-f1", "random", "unet-f1 (field)", "random (field)"}
    assert d["field_error"] == {"sigma_xy_m": 0.03, "sigma_phi_deg": 2.0}
    assert "σ 3 cm, 2°" in (out / "results.md").read_text()


@pytest.mark.slow
def test_eval_verify_row_is_a_real_twin_check_on_a_copy(capsys, work):
    """``eval --verify 2`` adds a verified row that really tries grasps in the twin, on a perturbed
    copy of the test pile: on this pile the network's best grasp drops on that copy, so the verified
    row must choose another grasp, one that succeeds on the copy."""
    from planner.pile_copies import PerturbationConfig, perturb_pile
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.geometry.grasp import Grasp
    from synth.physics.trial import TrialConfig, run_trial

    out = work / "eval_verify"
    r = cli(capsys, "eval", "--per-cell", "1", "--logs", "3", "--obstacles", "no", "--objectives", "f1",
            "--baselines", "", "--verify", "2", "--seed-base", "900000000", "--workers", "1", "--out", out, "--json")
    d = r.json()
    assert r.code == 0 and set(d["planners"]) == {"unet-f1", "unet-f1-verify2"}
    seed = 900000000 + 3 * 2 * 100_000  # the cell (3 logs, no obstacles), pile 0 (trial revision 4)
    recs = {x["planner"]: x for x in json.loads((out / "records" / f"{seed}.json").read_text())}
    pile, _ = generate_pile(seed, GenerationConfig(n_logs=3, n_obstacles=0))
    cfg = TrialConfig.fast()
    copy = perturb_pile(pile, PerturbationConfig(seed=2 * seed), 1, cfg.physics)  # what the row checks on
    assert copy != pile

    def on_copy(rec):
        return run_trial(copy, Grasp(**rec["grasp"]), rec["targets"], cfg).outcome.value

    net, ver = recs["unet-f1"], recs["unet-f1-verify2"]
    assert on_copy(net) != "success", "pick a pile where the network's best grasp fails on the copy"
    assert ver["grasp"] is not None and ver["grasp"] != net["grasp"]
    assert on_copy(ver) == "success"
    assert ver["outcome"] == "success" and d["planners"]["unet-f1-verify2"]["total"]["success_rate"] == 1.0


def test_eval_bad_input(capsys, work, a_file):
    for bad, flag in ((["--engine", "spark"], "--engine"), (["--per-cell", "0"], "--per-cell"),
                      (["--workers", "-3"], "--workers"), (["--obstacles", "maybe"], "--obstacles"),
                      (["--objectives", "f9"], "--objectives"), (["--baselines", "magic"], "--baselines"),
                      (["--extra-model", "nolabel"], "--extra-model"), (["--logs", "7-2"], "--logs"),
                      (["--address", "tcp://x:1"], "--address"), (["--verify", "0"], "--verify 0"),
                      (["--verify-copies", "2"], "--verify-copies needs --verify"),
                      (["--views", "3"], "--views must be one of (1, 2, 4, 8) (dihedral views averaged), got 3"),
                      (["--views", "1"], "--views 1 is the plain row"),
                      (["--view-spread", "2"], "--view-spread needs --views"),
                      (["--views", "8", "--view-spread", "-1"], "--view-spread must be >= 0"),
                      (["--field-error", "3cm"], "--field-error: positioning error '3cm' must be"),
                      (["--field-error", "0.03,90"], "--field-error: positioning error"),
                      (["--f3-sigma-b", "0"], "--f3-sigma-b 0: f3's balance tolerance must be > 0"),
                      (["--f3-balance", "guess"], "--f3-balance"), (["--precision", "int4"], "--precision"),
                      (["--ranked-only"], "--ranked-only needs --ranker"),
                      (["--precision", "int8", "--model", a_file], "has no int8 calibration beside it")):
        fails(cli(capsys, "eval", *bad, "--out", work / "e2"), 2, flag)
    fails(cli(capsys, "eval", "--out", a_file / "e"), 2, "--out", str(a_file))
    assert not (work / "e2").exists()


# -- what only a real process shows ------------------------------------------------------------------------
def test_c_libraries_stay_quiet_unless_verbose(work, pile_dir):
    """pybullet's build time, EGL/OpenGL lines: on neither stream of the real command, and the
    --json output is pure; --verbose lets them through (so the quiet is the CLI's doing)."""
    p = loggrasp_process("synth", "render", str(pile_dir), "--out", str(work / "quiet"), "--renders", "1", "--json")
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
    assert json.loads(out)["format"] == "loggrasp.synth-render"
    assert "pybullet build time" not in out + err and "EGL" not in out + err, (out, err)
    p = loggrasp_process("--verbose", "synth", "render", str(pile_dir), "--out", str(work / "loud"), "--renders", "1")
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0 and "pybullet build time" in out + err


def test_synth_scan_says_the_next_command_with_allow_float_only_for_float_points(tmp_path):
    from reconstruct.cli import next_step

    assert next_step(tmp_path / "s", 2).endswith(f"--out {tmp_path / 's' / 'recon'} --allow-float")
    assert "--allow-float" not in next_step(tmp_path / "s", 0)


@pytest.mark.slow
def test_synth_scan_json_is_pure_and_errors_are_one_line(work):
    """synth scan renders through EGL/OpenGL: stdout is still one JSON document; a broken image
    gives one error line and no libpng chatter."""
    p = loggrasp_process("synth", "scan", "--seed", "1", "--logs", "2", "--obstacles", "0", "--pairs", "1x1",
                  "--float-fixes", "0", "--out", str(work / "scan"), "--json")
    out, err = p.communicate(timeout=600)
    assert p.returncode == 0, err
    d = json.loads(out)
    assert d["format"] == "loggrasp.synth-scan" and Path(d["gnss"]).exists()
    assert "generating" in err and "rendering stereo pair 1 of 1" in err  # progress on stderr
    # the next step, as a command to copy (no float points in this survey: no --allow-float)
    assert d["next"] == f"loggrasp reconstruct {work / 'scan' / 'scan'} --gnss {d['gnss']} --out {work / 'scan' / 'recon'}"
    assert f"next: {d['next']}" in err
    left = work / "scan" / "scan" / "pair_000" / "left.png"
    left.write_bytes(left.read_bytes()[:200])
    p = loggrasp_process("reconstruct", str(work / "scan" / "scan"), "--gnss", d["gnss"], "--out", str(work / "rs"))
    out, err = p.communicate(timeout=300)
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith(("reading", "matching", "warning"))]
    assert p.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:") and "left.png" in lines[0], err
    assert not (work / "rs").exists()
