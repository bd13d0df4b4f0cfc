"""``loggrasp demo``, ``trial``, ``replay`` and ``crane-sim`` as a field engineer meets them (the
conventions of tests/test_cli.py)."""


from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import tempfile
import time
from pathlib import Path

import pytest

from field.cli import run
from field.demo import DEMO_DATA
from tests.cli_helpers import GNSS, OLD, RAW, SCAN, Result, cli, fails, free_port, loggrasp_process, run_captured

# -- field: demo, trial, replay, crane-sim ----------------------------------------------------------------
@pytest.fixture(scope="module")
def demo_record(work) -> Path:
    r = run_captured("demo", "--out", work / "demo", "--json", "--foxglove", free_port())  # also served live
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
    rec = work / "t_closed"  # one grasp verified (not eight): the question comes after verification either way
    r = cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--link", "twin://", "--record", rec,
            "--max-pile-age", OLD, "--verify", "1", "--json", stdin="", monkeypatch=monkeypatch)
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


def test_unreachable_zenoh_crane_fails_fast_without_rust_paths(capsys, work):
    rec = work / "t_unreachable"
    t = time.perf_counter()
    r = cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--record", rec, "--yes", "--max-pile-age", OLD,
            "--link", f"zenoh://127.0.0.1:{free_port()}/nocrane?connect_timeout_s=1", "--insecure-link")
    line = fails(r, 3, "cannot reach the crane controller")
    assert ".rs:" not in line and time.perf_counter() - t < 20 and not rec.exists()


@pytest.mark.slow
def test_crane_sim_says_why_it_rejects(capsys, work):
    """A crane in its own process with its own staleness limit rejects the trial's command
    (STALE) although the laptop's --max-pile-age lets it through; both sides say why."""
    url = f"zenoh://127.0.0.1:{free_port()}/crane-test"
    crane = loggrasp_process("crane-sim", "--link", url, "--insecure-link", "--pile", str(DEMO_DATA / "truth" / "pile.json"),
                      "--max-pile-age", "60", "--max-mac-failures", "50")
    try:
        deadline = time.time() + 60
        line = ""
        while "serving" not in line and time.time() < deadline:
            line = crane.stdout.readline()
            assert line or crane.poll() is None, crane.stderr.read()
        assert "FAULT past 50 MAC failures in 10 s" in line, line
        rec = work / "t_stale"  # one grasp verified (not eight): the crane judges the command, not how it was chosen
        r = cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--record", rec, "--yes", "--max-pile-age", OLD,
                "--verify", "1", "--link", url, "--insecure-link")
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
