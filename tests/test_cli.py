"""Every ``loggrasp`` command as a field engineer or a script meets it (issue 20): ``--help`` for
each; each command's happy path, tiny; each bad input of the issue. Every case asserts the exit
code, one ``error:`` line naming the problem and the flag or file to fix, no traceback, nothing
half-written, and standard output that parses as JSON where ``--json`` is given.

Commands run in-process through :func:`field.cli.run` (the one error handler); what only a real
process shows (C libraries' output on file descriptors 1 and 2, a crane in another process) runs
as a subprocess. The heavy fixtures (the demo's trial, a trial over twin://) are module-scoped and
shared."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from field.cli import app, run
from field.demo import DEMO_DATA

ROOT = Path(__file__).resolve().parents[1]
SCAN, GNSS = DEMO_DATA / "scan", DEMO_DATA / "gnss.csv"
OLD = "1e9"  # the bundled scan is old: a --max-pile-age it passes


@dataclass
class Result:
    code: int
    out: str
    err: str

    @property
    def error(self) -> str:
        lines = [ln for ln in self.err.splitlines() if ln.startswith("error:")]
        assert len(lines) == 1, f"want exactly one error line:\n{self.err}"
        return lines[0]

    def json(self) -> dict:
        def strict(c):
            raise ValueError(f"{c} is not JSON")

        d = json.loads(self.out, parse_constant=strict)  # the whole of stdout: one document
        assert isinstance(d.get("format"), str) and d["format"].startswith("loggrasp.") and d.get("format_version")
        return d


def cli(capsys, *args, stdin: str | None = None, monkeypatch=None) -> Result:
    capsys.readouterr()
    if stdin is not None:
        monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err, err
    return Result(code, out, err)


def fails(r: Result, code: int, *words: str) -> str:
    """``r`` exited with ``code`` and one error line that contains every word."""
    assert r.code == code, (r.code, r.err)
    line = r.error
    for w in words:
        assert w in line, (w, line)
    return line


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("cli")


@pytest.fixture(scope="module")
def a_file(work) -> Path:
    """A plain file: an output path under it can never be made (also as root)."""
    f = work / "a_file"
    f.write_text("x")
    return f


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
        named = set(re.findall(r"(?<![\w-])--[a-z][a-z-]*", line))
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


@pytest.mark.slow
def test_synth_dataset_and_train_a_64px_network(capsys, work, a_file):
    """A 64 px data set trains from the command line (the network takes the data set's size), either
    mask injection."""
    from planner.checkpoint import load_checkpoint

    fails(cli(capsys, "synth", "dataset", "--piles", "1", "--engine", "spark", "--out", work / "d"), 2, "--engine")
    fails(cli(capsys, "synth", "dataset", "--piles", "1", "--out", a_file / "d"), 2, "--out")
    for logs in ("5-3", "2-12", "two"):
        fails(cli(capsys, "synth", "dataset", "--piles", "1", "--logs", logs, "--out", work / "d"), 2, "--logs")
    assert not (work / "d").exists()
    r = cli(capsys, "synth", "dataset", "--piles", "2", "--logs", "2", "--size", "64", "--renders", "1",
            "--max-trials-per-subset", "1", "--workers", "1", "--out", work / "data", "--json")
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


def test_train_outcome_labels_and_the_beta_map(capsys, work, tmp_path):
    """``--labels outcome`` trains on every trial of a data set made by `synth dataset` (after the test
    above); a data set without trials, or with --skip-no-candidates, is a one-line error."""
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
                      (["--field-error", "0.03,90"], "--field-error: positioning error")):
        fails(cli(capsys, "eval", *bad, "--out", work / "e2"), 2, flag)
    fails(cli(capsys, "eval", "--out", a_file / "e"), 2, "--out", str(a_file))
    assert not (work / "e2").exists()


# -- survey -------------------------------------------------------------------------------------------
RAW = ROOT / "tests" / "data" / "gnss" / "raw"


@pytest.mark.parametrize("logs", [["f9p_rover.ubx"], ["reach_rover.nmea"], ["ucenter_mixed.ubx"],
                                  ["f9p_rover.ubx", "reach_rover.nmea"]])
def test_survey_reads_each_receiver_kind_and_its_csv_reads_back(capsys, tmp_path, logs):
    from reconstruct.survey.gnss import read_gnss_csv

    out = tmp_path / "gnss.csv"
    r = cli(capsys, "survey", *[RAW / f for f in logs], "--windows", RAW / "windows.csv", "--out", out, "--json")
    assert r.code == 0, r.err
    d = r.json()
    assert d["format"] == "loggrasp.survey-report" and len(d["logs"]) == len(logs)
    assert [(p["log_id"], p["end"], p["n_epochs"], p["fix"]) for p in d["points"]] == [
        (k, e, 5 * len(logs), "rtk_fixed") for k, e in (("log0", "a"), ("log0", "b"), ("log1", "a"), ("log1", "b"))]
    back = read_gnss_csv(out)  # what reconstruct --gnss reads
    assert [p.n_epochs for p in back.points] == [5 * len(logs)] * 4
    assert abs(back.points[0].spread_h_m - d["points"][0]["spread_h_m"]) < 1e-4
    for f in logs:
        assert f"{f}: 20 epochs" in r.err  # per file: what was read


def test_survey_prints_per_end_and_per_file(capsys, tmp_path):
    r = cli(capsys, "survey", RAW / "ucenter_mixed.ubx", "--windows", RAW / "windows.csv", "--out", tmp_path / "g.csv")
    assert r.code == 0, r.err
    assert "skipped 20 RTCM3, 65 UBX; 60 bytes not in any frame" in r.out
    assert re.search(r"log0\s+a\s+5\s+rtk_fixed\s+0\.0123\s+0\.0186\s+0\.0031", r.out), r.out


def test_survey_of_a_field_app_export(capsys, tmp_path):
    from reconstruct.survey.gnss import read_gnss_csv

    export = tmp_path / "export.csv"
    export.write_text("Punkt;Lat;Lon;Ellipsoidhöjd;Lösning\n"
                      "log0a;64,1000036164;19,9999630838;250,1131;FIX\nlog0b;64,1000182231;20,0000401711;250,2950;FIX\n")
    fails(cli(capsys, "survey", export, "--out", tmp_path / "g.csv"), 2, "no coordinate columns", "--columns")
    r = cli(capsys, "survey", export, "--columns", "id=Punkt,lat=Lat,lon=Lon,height=Ellipsoidhöjd,fix=Lösning",
            "--out", tmp_path / "g.csv", "--crs", "EPSG:3006")
    assert r.code == 0, r.err
    assert [p.log_id for p in read_gnss_csv(tmp_path / "g.csv").points] == ["log0", "log0"]


def test_survey_bad_input(capsys, tmp_path):
    out = tmp_path / "g.csv"
    late = tmp_path / "late.csv"
    late.write_text("log_id,end,t_start_utc,t_end_utc\nlog0,a,2026-05-14T10:00:00Z,2026-05-14T10:01:00Z\n"
                    "log0,b,2026-05-14T10:02:00Z,2026-05-14T10:03:00Z\n")
    fails(cli(capsys, "survey", RAW / "f9p_rover.ubx", "--windows", late, "--out", out), 2, "late.csv:2",
          "log 'log0' end 'a'", "the logs span f9p_rover.ubx 2026-05-14T09:30:00.000Z to 2026-05-14T09:31:34.000Z")
    fails(cli(capsys, "survey", SCAN / "pair_000" / "left.png", "--windows", RAW / "windows.csv", "--out", out), 2,
          "left.png is not a receiver log")
    one = tmp_path / "one.csv"
    one.write_text("\n".join((RAW / "windows.csv").read_text().splitlines()[:-1]) + "\n")
    fails(cli(capsys, "survey", RAW / "f9p_rover.ubx", "--windows", one, "--out", out), 2,
          "log 'log1' has a window for end 'a' but none for end 'b'")
    assert not out.exists()
    r = cli(capsys, "survey", RAW / "f9p_rover.ubx", "--windows", one, "--out", out, "--allow-one-end")
    assert r.code == 0 and "log1 (no end b)" in r.err
    out.unlink()
    fails(cli(capsys, "survey", RAW / "f9p_rover.ubx", "--out", out), 2, "--windows")
    fails(cli(capsys, "survey", RAW / "f9p_rover.ubx", "--windows", RAW / "windows.csv", "--out", tmp_path / "g.txt"),
          2, "--out", ".csv")
    fails(cli(capsys, "survey", RAW / "f9p_rover.ubx", "--windows", RAW / "windows.csv", "--out", out,
              "--date", "14/5/2026"), 2, "--date")
    assert not out.exists() and not list(tmp_path.glob(".*"))


def test_reconstruct_takes_raw_logs(capsys, tmp_path):
    """The demo's survey points as a raw F9P capture: reconstruct --gnss LOG --gnss-windows FILE places the same
    logs as the survey CSV does."""
    import numpy as np

    from reconstruct.survey.gnss import read_gnss_csv
    from synth.scene.pile import read_pile
    from tests.reconstruct.survey import raw_captures as rc

    survey = read_gnss_csv(GNSS)
    points = {(p.log_id, p.end): (p.lat_deg, p.lon_deg, p.h_ell_m) for p in survey.points}
    files = rc.write_captures(tmp_path / "raw", points)
    fails(cli(capsys, "reconstruct", SCAN, "--gnss", files["f9p"], "--out", tmp_path / "r"), 2, "--gnss-windows")
    fails(cli(capsys, "reconstruct", SCAN, "--gnss", GNSS, "--gnss-windows", files["windows"], "--out", tmp_path / "r"),
          2, "--gnss-windows goes with raw receiver logs")
    r = cli(capsys, "reconstruct", SCAN, "--gnss", files["f9p"], "--gnss", files["nmea"], "--gnss-windows",
            files["windows"], "--out", tmp_path / "r", "--json")
    assert r.code == 0, r.err
    rep = r.json()
    assert str(files["windows"]) in rep["gnss"]
    pile = read_pile(tmp_path / "r")
    assert pile.n_logs >= len(survey.log_ids)
    assert np.isfinite([log.length_m for log in pile.logs]).all()


def test_reconstruct_with_the_joint_estimator(capsys, tmp_path):
    """--estimator joint reconstructs the demo scan and says so in its report; an unknown estimator is bad input."""
    r = cli(capsys, "reconstruct", SCAN, "--gnss", GNSS, "--out", tmp_path / "j", "--estimator", "joint", "--json")
    assert r.code == 0, r.err
    rep = r.json()
    assert rep["estimator"] == "joint" and rep["estimator_revision"] >= 1 and len(rep["logs"]) >= 4
    assert all("outlier_prob" in e for log in rep["logs"] for e in log["ends"])
    fails(cli(capsys, "reconstruct", SCAN, "--gnss", GNSS, "--out", tmp_path / "k", "--estimator", "rules23"), 2,
          "--estimator")


# -- reconstruct, compare-piles --------------------------------------------------------------------------
def run_captured(*args) -> Result:
    """:func:`run` for a module-scoped fixture (no capsys there)."""
    import contextlib

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = run([str(a) for a in args])
    r = Result(code, out.getvalue(), err.getvalue())
    assert "Traceback" not in r.out + r.err, r.err
    return r


@pytest.fixture(scope="module")
def recon_run(work) -> tuple[Path, Result]:
    return work / "recon", run_captured("reconstruct", SCAN, "--gnss", GNSS, "--out", work / "recon", "--json")


@pytest.fixture(scope="module")
def recon(recon_run) -> Path:
    assert recon_run[1].code == 0, recon_run[1].err
    return recon_run[0]


@pytest.mark.slow
def test_reconstruct_prints_the_per_log_report(recon_run):
    r = recon_run[1]
    rep = r.json()
    assert r.code == 0 and rep["format"] == "loggrasp.reconstruction-report"
    for title in ("log", "fit", "length m", "diam. m", "GNSS res. a m", "GNSS res. b m", "fit rms m", "coverage"):
        assert title in r.err, r.err  # the table goes to stderr under --json
    for log in rep["logs"]:
        assert log["log_id"] in r.err and log["fit"] in ("scan", "partial", "hidden")
    from reconstruct.cli import log_table_row

    row = log_table_row({**rep["logs"][0], "rms_m": float("nan"), "top_diameter_m": None})
    assert row[1] in ("scan", "partial", "hidden") and "-" in row


@pytest.mark.slow
def test_compare_piles(capsys, recon, work):
    r = cli(capsys, "compare-piles", DEMO_DATA / "truth", recon, "--json")
    assert r.code == 0 and r.json()["format"] == "loggrasp.pile-comparison" and r.json()["summary"]["n_matched"] == 4
    r = cli(capsys, "compare-piles", DEMO_DATA / "truth", recon)
    assert r.code == 0 and "endpoint_err_m" in r.out and "{" not in r.out
    fails(cli(capsys, "compare-piles", DEMO_DATA / "truth", work / "none"), 2, "RECON", "none")


def test_reconstruct_warns_of_each_end_the_pile_check_moved(capsys, work, monkeypatch):
    """An end the twin's pile check moved within its uncertainty (or put at its survey point) is a
    warning on the terminal, not only a line in report.json."""
    import types

    import reconstruct.pipeline as pipeline

    note = "log3: end b (float, +-20 cm) moved 23.0 cm (1.1 sigma) within its uncertainty: where it was placed it ran 15.5 cm into log 4"
    rep = {"logs": [], "end_moves": [note], "registration": {}}
    fake = types.SimpleNamespace(report=rep, pile=types.SimpleNamespace(n_logs=0, n_obstacles=0), time_s=1.0)
    monkeypatch.setattr(pipeline, "reconstruct", lambda *a, **k: fake)
    r = cli(capsys, "reconstruct", SCAN, "--gnss", GNSS, "--out", work / "o-moved")
    said = " ".join((r.err + r.out).split())
    assert r.code == 0 and f"pile check: {note}" in said, said


def test_reconstruct_bad_input(capsys, work, a_file):
    fails(cli(capsys, "reconstruct", SCAN, "--gnss", GNSS, "--out", work / "o", "--log-direction", "north"), 2,
          "--log-direction must be an angle in degrees or 'site'")
    fails(cli(capsys, "reconstruct", SCAN, "--gnss", GNSS, "--out", work / "o", "--log-direction", "400"), 2,
          "--log-direction must be in [-180, 180]")
    fails(cli(capsys, "reconstruct", SCAN, "--gnss", GNSS, "--out", a_file / "o"), 2, "--out", str(a_file))
    fails(cli(capsys, "reconstruct", SCAN, "--gnss", work / "none.csv", "--out", work / "o"), 2, "--gnss")
    fails(cli(capsys, "reconstruct", SCAN, "--gnss", GNSS, "--out", work / "o", "--pair-poses", "magic"), 2,
          "--pair-poses")
    floaty = work / "float.csv"
    floaty.write_text(GNSS.read_text().replace("rtk_fixed", "rtk_float", 1))
    r = cli(capsys, "reconstruct", SCAN, "--gnss", floaty, "--out", work / "o")
    line = fails(r, 2, "--allow-float", str(floaty))
    assert "allow_float" not in line
    assert not (work / "o").exists()


def test_gnss_without_a_crs_line_warns():
    from reconstruct.cli import gnss_crs_warning

    assert gnss_crs_warning(GNSS) is None
    d = Path(tempfile.mkdtemp())
    try:
        (d / "g.csv").write_text("\n".join(ln for ln in GNSS.read_text().splitlines() if "crs" not in ln.lower()))
        assert "no '# crs:' line" in gnss_crs_warning(d / "g.csv")
    finally:
        shutil.rmtree(d)


# -- field: demo, trial, replay, crane-sim ----------------------------------------------------------------
@pytest.fixture(scope="module")
def demo_record(work) -> Path:
    r = run_captured("demo", "--out", work / "demo", "--json", "--foxglove", _free_port())  # also served live
    assert r.code == 0, r.err
    d = r.json()
    assert d["format"] == "loggrasp.trial-result" and d["final_state"] == "SUCCESS"
    return work / "demo" / "trial"


@pytest.mark.slow
def test_demo_record_is_complete(demo_record):
    rec = json.loads((demo_record / "record.json").read_text())
    assert rec["final_state"] == "SUCCESS" and rec["outcome"]["class"] == "SUCCESS"
    for f in ("plan/plan.png", "plan/grasp_map.png", "plan/plan.json", "reconstruction/pile.json", "link/traffic.blf"):
        assert (demo_record / f).exists(), f
    plan = json.loads((demo_record / "plan" / "plan.json").read_text())
    assert plan["format"] == "loggrasp.plan" and plan["format_version"]
    assert not list(demo_record.parent.glob(".*tmp*"))
    # verified planning is on by default: the grasp sent is the one the twin chose on the reconstruction
    v = rec["verification"]
    assert v["ok"] and v["k"] == 8 and rec["verified"] is True and rec["chosen_rank"] == v["chosen_rank"] + 1
    assert (demo_record / "plan" / "verification.json").exists()
    assert run(["audit", "verify", str(demo_record)]) == 0  # the record's hash chain verifies


@pytest.mark.slow
def test_demo_writes_a_foxglove_recording(demo_record):
    """The demo's trial.mcap, read back with the mcap package's reader (not the SDK that wrote it)."""
    from tests.field.mcap_check import check_trial_mcap

    rec = json.loads((demo_record / "record.json").read_text())
    check_trial_mcap(demo_record, rec)
    assert not list(demo_record.parent.glob(".*.part")) and not list(demo_record.glob(".*.part"))


@pytest.mark.slow
def test_demo_without_verification_sends_the_networks_best(capsys, work):
    r = cli(capsys, "demo", "--out", work / "demo_nv", "--no-verify", "--json")
    d = r.json()
    assert r.code == 0, r.err
    assert d["final_state"] == "SUCCESS" and d["verification"] is None and d["verified"] is False
    assert d["chosen_rank"] == 1 and "verification off" in r.err and "verifying" not in r.err
    assert not (work / "demo_nv" / "trial" / "plan" / "verification.json").exists()


def test_demo_bad_input(capsys, work, a_file):
    fails(cli(capsys, "demo", "--link", "foo://x", "--out", work / "d2"), 3, "--link", "foo://")
    fails(cli(capsys, "demo", "--link", "twin://", "--out", work / "d2"), 3, "--link", "twin://")
    fails(cli(capsys, "demo", "--out", a_file / "d"), 2, "--out", str(a_file))
    assert not (work / "d2").exists()
    with socket.socket() as busy:  # the live view's port in use: stopped before the trial, nothing recorded
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        fails(cli(capsys, "demo", "--out", work / "d3", "--foxglove", busy.getsockname()[1]), 2, "--foxglove",
              "in use", "nothing was recorded")
    assert not (work / "d3" / "trial").exists() and not list((work / "d3").glob(".*part"))


def _replay_temp_dirs() -> set[str]:
    return {p.name for p in Path(tempfile.gettempdir()).glob("loggrasp-replay-*")}


@pytest.mark.slow
def test_replay_identical_json_and_no_leaks(capsys, demo_record):
    before = _replay_temp_dirs()
    r = cli(capsys, "replay", demo_record, "--json", "--link", "twin://")  # the README's example
    d = r.json()
    assert r.code == 0 and d["format"] == "loggrasp.replay" and d["identical"] is True
    assert d["verification_identical"] is True and d["verification_differences"] == []
    assert "verification trials are bit-identical" in r.err
    assert d["resent"]["outcome"]["class"] == "SUCCESS"  # a plain twin:// takes the old record's command
    assert "replay of" in r.err and "replay of" not in r.out  # progress and words on stderr only
    assert _replay_temp_dirs() <= before, "replay left its temporary folder"


@pytest.mark.slow
def test_replay_names_the_changed_input(capsys, work, demo_record, a_file):
    edited = work / "edited"
    shutil.copytree(demo_record, edited)
    gnss = edited / "inputs" / "gnss.csv"
    gnss.write_text(gnss.read_text().replace("rtk_fixed", "rtk_float", 1))
    fails(cli(capsys, "replay", edited), 2, "inputs/gnss.csv", "changed")
    (edited / "inputs" / "extra.txt").write_text("x")
    shutil.copy(demo_record / "inputs" / "gnss.csv", gnss)
    fails(cli(capsys, "replay", edited), 2, "inputs/extra.txt")
    fails(cli(capsys, "replay", demo_record, "--out", a_file / "w"), 2, "--out", str(a_file))
    fails(cli(capsys, "replay", work / "none"), 2, "none", "does not exist")
    fails(cli(capsys, "replay", a_file.parent), 2, "record.json")
    fails(cli(capsys, "replay", demo_record, "--link", "foo://x"), 3, "--link")


@pytest.fixture(scope="module")
def twin_trial(work) -> tuple[Path, Result]:
    """A plain twin:// trial: the twin crane stands where the laptop thinks (in reach)."""
    rec = work / "t_twin"
    return rec, run_captured("trial", "--scan", SCAN, "--gnss", GNSS, "--link", "twin://", "--record", rec, "--yes",
                             "--max-pile-age", OLD, "--json")


@pytest.mark.slow
def test_trial_over_plain_twin_succeeds(twin_trial):
    rec, r = twin_trial
    assert r.code == 0, r.err
    d = r.json()
    assert d["format"] == "loggrasp.trial-result" and d["final_state"] == "SUCCESS"
    # verified by default: the command carries the grasp the twin chose on the reconstruction
    v = d["verification"]
    assert v["ok"] and v["k"] == 8 and d["verified"] is True and d["chosen_rank"] == v["chosen_rank"] + 1
    assert "verifying: the twin tries the best 8 grasps" in r.err
    assert r.err.index("verifying") < r.err.index("sending command")
    held = d["command"]["target_log_count"]
    assert f"SUCCESS: {held} logs held" in r.err and "{'class'" not in r.err  # words, not a Python dict
    assert "crane link twin://" in r.err  # the link was reached before the reconstruction
    assert r.err.index("crane link twin://") < r.err.index("reconstructing")
    assert ".tmp" not in r.err  # progress names the record's own folder


@pytest.mark.slow
def test_trial_with_standard_input_closed_leaves_a_record(capsys, monkeypatch, work):
    rec = work / "t_closed"
    r = cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--link", "twin://", "--record", rec,
            "--max-pile-age", OLD, "--json", stdin="", monkeypatch=monkeypatch)
    fails(r, 4, "no answer", str(rec))
    assert r.json()["final_state"] == "NOT SENT"
    saved = json.loads((rec / "record.json").read_text())
    assert saved["final_state"] == "NOT SENT" and "no answer" in saved["reason"] and saved["command"]
    # the confirmation showed the plan table, the SWEREF grasp and pictures that exist
    assert re.search(r"^#\s+targets\s+Q\s+U\s+B", r.err, re.M) and "SWEREF 99 TM" in r.err
    shown = re.search(r"look before sending: (.*)", r.err).group(1).split(", ")
    assert shown and all(Path(p).exists() and str(rec) in p for p in shown), shown


def test_trial_bad_input_fails_before_any_work(capsys, work, a_file):
    rec = work / "t_bad"
    base = ["trial", "--scan", SCAN, "--gnss", GNSS, "--record", rec, "--yes"]
    t = time.perf_counter()
    fails(cli(capsys, *base, "--link", "foo://x"), 3, "--link", "foo://")
    fails(cli(capsys, *base, "--link", ""), 3, "--link", "empty")
    fails(cli(capsys, *base, "--link", "zenoh://127.0.0.1:9"), 3, "--link", "zenoh://")
    fails(cli(capsys, *base, "--link", "twin://", "--base", "abc"), 2, "--base")
    fails(cli(capsys, *base, "--link", "twin://", "--objective", "f9"), 2, "--objective")
    fails(cli(capsys, *base, "--link", "twin://", "--verify", "0"), 2, "--verify 0", "--no-verify")
    fails(cli(capsys, *base, "--link", "twin://", "--verify-budget", "0.1"), 2, "--verify-budget 0.1",
          "too small for one twin trial")
    fails(cli(capsys, *base, "--link", "twin://", "--send-rank", "0"), 2, "--send-rank")
    fails(cli(capsys, *base, "--link", "twin://", "--foxglove", "0"), 2, "--foxglove")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        fails(cli(capsys, *base, "--link", "twin://", "--foxglove", busy.getsockname()[1]), 2, "--foxglove",
              "in use")
    assert not list(work.glob(".t_bad*"))
    fails(cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--record", a_file / "r", "--link", "twin://"), 2,
          "--record", str(a_file))
    fails(cli(capsys, "trial", "--scan", work / "none", "--gnss", GNSS, "--record", rec, "--link", "twin://"), 2,
          "--scan")
    late = work / "late_windows.csv"
    late.write_text("log_id,end,t_start_utc,t_end_utc\nlog0,a,2026-05-14T10:00:00Z,2026-05-14T10:01:00Z\n"
                    "log0,b,2026-05-14T10:02:00Z,2026-05-14T10:03:00Z\n")
    fails(cli(capsys, "trial", "--scan", SCAN, "--gnss", RAW / "f9p_rover.ubx", "--gnss-windows", late, "--record", rec,
              "--link", "twin://"), 2, "late_windows.csv:2", "the logs span f9p_rover.ubx")
    fails(cli(capsys, "trial", "--scan", SCAN, "--gnss", RAW / "f9p_rover.ubx", "--record", rec, "--link", "twin://"),
          2, "--gnss-windows")
    assert time.perf_counter() - t < 20, "bad input must stop the trial before the reconstruction"
    assert not rec.exists()
    (work / "exists").mkdir(exist_ok=True)
    fails(cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--record", work / "exists", "--link", "twin://"), 2,
          "--record", "already exists")


def test_trial_records_raw_logs_and_the_survey_made_from_them(tmp_path):
    """A trial given raw logs keeps them in its record and reads the survey averaged from them, dated
    like the newest raw file (the pile's age check sees when the survey was made, not now)."""
    from field.trial_record import _record_raw_survey
    from reconstruct.survey.gnss import RawGnss, read_gnss_csv

    raw = tmp_path / "in"
    raw.mkdir()
    for f in ("f9p_rover.ubx", "windows.csv"):
        shutil.copy(RAW / f, raw / f)
        os.utime(raw / f, (1.7e9, 1.7e9))
    _record_raw_survey(RawGnss((raw / "f9p_rover.ubx",), raw / "windows.csv"), tmp_path / "inputs", False)
    assert sorted(p.name for p in (tmp_path / "inputs" / "gnss-raw").iterdir()) == ["0_f9p_rover.ubx", "1_windows.csv"]
    survey = read_gnss_csv(tmp_path / "inputs" / "gnss.csv")
    assert [p.n_epochs for p in survey.points] == [5] * 4
    assert (tmp_path / "inputs" / "gnss.csv").stat().st_mtime == 1.7e9


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _loggrasp(*args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "field.cli", *args], stdout=subprocess.PIPE, cwd=ROOT,
                            stderr=subprocess.PIPE, text=True, env=env, **kw)


def test_unreachable_zenoh_crane_fails_fast_without_rust_paths(capsys, work):
    rec = work / "t_unreachable"
    t = time.perf_counter()
    r = cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--record", rec, "--yes", "--max-pile-age", OLD,
            "--link", f"zenoh://127.0.0.1:{_free_port()}/nocrane?connect_timeout_s=1", "--insecure-link")
    line = fails(r, 3, "cannot reach the crane controller")
    assert ".rs:" not in line and time.perf_counter() - t < 20 and not rec.exists()


@pytest.mark.slow
def test_crane_sim_says_why_it_rejects(capsys, work):
    """A crane in its own process with its own staleness limit rejects the trial's command
    (STALE) although the laptop's --max-pile-age lets it through; both sides say why."""
    url = f"zenoh://127.0.0.1:{_free_port()}/crane-test"
    crane = _loggrasp("crane-sim", "--link", url, "--insecure-link", "--pile", str(DEMO_DATA / "truth" / "pile.json"),
                      "--max-pile-age", "60", "--max-mac-failures", "50")
    try:
        deadline = time.time() + 60
        line = ""
        while "serving" not in line and time.time() < deadline:
            line = crane.stdout.readline()
            assert line or crane.poll() is None, crane.stderr.read()
        assert "FAULT past 50 MAC failures in 10 s" in line, line
        rec = work / "t_stale"
        r = cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--record", rec, "--yes", "--max-pile-age", OLD,
                "--link", url, "--insecure-link")
        fails(r, 4, "rejected", "STALE", "crane-sim --max-pile-age", str(rec))
        record = json.loads((rec / "record.json").read_text())
        assert record["reject_reason"] == "STALE" and record["link"].endswith("insecure=1")  # the record says so
        assert "NOT authenticated" in r.err  # and so does the trial, before the confirmation
    finally:
        crane.send_signal(signal.SIGTERM)
        out, err = crane.communicate(timeout=30)
    assert crane.returncode == 0, err
    assert re.search(r"command \d+: REJECTED \(STALE\)", out), out
    assert "stopped in state" in out and "Traceback" not in err and "pybullet build time" not in out + err


def test_crane_sim_on_a_busy_port_says_so_in_one_line(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = cli(capsys, "crane-sim", "--link", f"zenoh://127.0.0.1:{port}/c", "--insecure-link", "--pile",
                DEMO_DATA / "truth" / "pile.json")
    line = fails(r, 3, str(port))
    assert ".rs:" not in line and "cargo" not in line


def test_messages_lose_rust_source_paths_and_python_names():
    from field.cli import clean_message

    zenoh = ("Can not create a new TCP listener bound to tcp/127.0.0.1:7471: [127.0.0.1:7471: Address already in "
             "use (os error 98) at /root/.cargo/git/checkouts/zenoh-9c5/cc8/io/zenoh-link-commons/src/tcp.rs:61.] at "
             "/root/.cargo/git/checkouts/zenoh-9c5/cc8/io/zenoh-links/zenoh-link-tcp/src/unicast.rs:338.. Check it")
    assert clean_message(zenoh) == ("Can not create a new TCP listener bound to tcp/127.0.0.1:7471: [127.0.0.1:7471: "
                                    "Address already in use (os error 98)]. Check it")
    assert clean_message("pass allow_float=True, or per_cell must be >= 1\nsecond line") == \
        "pass --allow-float, or --per-cell must be >= 1 second line"
    kept = "twin://?crane_max_pile_age_s=S and the logs must"
    assert clean_message(kept) == kept


def test_crane_sim_bad_input(capsys, work, a_file):
    pile = DEMO_DATA / "truth" / "pile.json"
    fails(cli(capsys, "crane-sim", "--link", "twin://", "--pile", pile), 3, "--link", "twin://")
    fails(cli(capsys, "crane-sim", "--link", "foo://x", "--pile", pile), 3, "--link")
    fails(cli(capsys, "crane-sim", "--link", "can://virtual/x", "--pile", pile), 3, "no SecOC key", "--insecure-link")
    insecure = ("--link", "can://virtual/x", "--insecure-link")
    fails(cli(capsys, "crane-sim", *insecure, "--pile", work / "none.json"), 2, "--pile")
    fails(cli(capsys, "crane-sim", *insecure, "--pile", pile, "--base", "1,2"), 2, "--base")
    fails(cli(capsys, "crane-sim", *insecure, "--pile", pile, "--max-reach", "-1"), 2, "--max-reach")
    fails(cli(capsys, "crane-sim", *insecure, "--pile", pile, "--max-mac-failures", "0"), 2, "--max-mac-failures")


def test_trial_and_replay_refuse_a_crane_link_without_a_key(capsys, work, demo_record):
    fails(cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--record", work / "t_nokey", "--yes",
              "--link", "can://virtual/nokey"), 3, "no SecOC key", "--insecure-link")
    assert not (work / "t_nokey").exists()
    fails(cli(capsys, "replay", demo_record, "--link", "can://virtual/nokey"), 3, "no SecOC key", "--insecure-link")


# -- what only a real process shows ------------------------------------------------------------------------
def test_c_libraries_stay_quiet_unless_verbose(work, pile_dir):
    """pybullet's build time, EGL/OpenGL lines: on neither stream of the real command, and the
    --json output is pure; --verbose lets them through (so the quiet is the CLI's doing)."""
    p = _loggrasp("synth", "render", str(pile_dir), "--out", str(work / "quiet"), "--renders", "1", "--json")
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
    assert json.loads(out)["format"] == "loggrasp.synth-render"
    assert "pybullet build time" not in out + err and "EGL" not in out + err, (out, err)
    p = _loggrasp("--verbose", "synth", "render", str(pile_dir), "--out", str(work / "loud"), "--renders", "1")
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
    p = _loggrasp("synth", "scan", "--seed", "1", "--logs", "2", "--obstacles", "0", "--pairs", "1x1",
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
    p = _loggrasp("reconstruct", str(work / "scan" / "scan"), "--gnss", d["gnss"], "--out", str(work / "rs"))
    out, err = p.communicate(timeout=300)
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith(("reading", "matching", "warning"))]
    assert p.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:") and "left.png" in lines[0], err
    assert not (work / "rs").exists()
