"""``loggrasp survey``, ``reconstruct`` and ``compare-piles`` as a field engineer meets them (the
conventions of tests/test_cli.py)."""


from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path

import pytest

from field.demo import DEMO_DATA
from tests.cli_helpers import GNSS, RAW, SCAN, Result, cli, fails, run_captured


# -- survey -------------------------------------------------------------------------------------------

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
