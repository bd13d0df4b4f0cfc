"""Each command: --help works, bad input exits non-zero with a clear message, a tiny real run."""

import json
import subprocess
import sys
import time

import pytest
from typer.testing import CliRunner

from field.cli import app

runner = CliRunner()


COMMANDS = [[], ["synth"], ["synth", "piles"], ["synth", "render"], ["synth", "dataset"], ["synth", "scan"],
            ["train"], ["plan"], ["eval"], ["reconstruct"], ["compare-piles"], ["crane-sim"], ["trial"],
            ["replay"], ["demo"]]


@pytest.mark.parametrize("args", COMMANDS)
def test_help(args):
    result = runner.invoke(app, [*args, "--help"])
    assert result.exit_code == 0, result.output
    assert "Usage" in result.output


def test_help_is_fast_and_imports_nothing_heavy():
    code = ("import sys, time; t=time.time(); from field.cli import app; "
            "heavy=[m for m in ('torch','pybullet','cv2','open3d','zenoh','can','pyproj') if m in sys.modules]; "
            "print(heavy, time.time()-t)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.startswith("[]"), out


def test_synth_piles_tiny_run_and_bad_input(tmp_path):
    result = runner.invoke(app, ["synth", "piles", "--count", "1", "--logs", "2", "--renders", "1",
                                 "--workers", "1", "--out", str(tmp_path / "p")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "p" / "pile_00000" / "ortho.npz").exists()
    bad = runner.invoke(app, ["synth", "piles", "--count", "1", "--logs", "x", "--out", str(tmp_path / "q")])
    assert bad.exit_code != 0 and "--logs" in bad.output


def test_synth_render_rejects_malformed_pile(tmp_path):
    (tmp_path / "pile.json").write_text("{")
    result = runner.invoke(app, ["synth", "render", str(tmp_path)])
    assert result.exit_code != 0 and "not valid JSON" in result.output


def test_synth_scan_rejects_swapped_site(tmp_path):
    result = runner.invoke(app, ["synth", "scan", "--out", str(tmp_path / "s"), "--site", "20.0,64.1"])
    assert result.exit_code != 0 and "swap" in result.output
    assert not (tmp_path / "s").exists()


def test_plan_with_missing_model_fails_clearly(tmp_path):
    result = runner.invoke(app, ["plan", str(tmp_path), "--model", str(tmp_path / "none.safetensors")])
    assert result.exit_code != 0 and "none.safetensors" in result.output


def test_eval_rejects_bad_obstacles_option(tmp_path):
    result = runner.invoke(app, ["eval", "--out", str(tmp_path), "--obstacles", "maybe"])
    assert result.exit_code != 0 and "--obstacles" in result.output


def test_trial_refuses_an_existing_record(tmp_path):
    (tmp_path / "rec").mkdir()
    result = runner.invoke(app, ["trial", "--scan", str(tmp_path), "--gnss", str(tmp_path / "g.csv"),
                                 "--link", "twin://", "--record", str(tmp_path / "rec"), "--yes"])
    assert result.exit_code != 0 and "already exists" in result.output


def test_plan_with_averaged_views_and_bad_views(tmp_path):
    made = runner.invoke(app, ["synth", "piles", "--count", "1", "--logs", "3", "--renders", "1", "--size", "128",
                               "--workers", "1", "--out", str(tmp_path / "p")])
    assert made.exit_code == 0, made.output
    pile = str(tmp_path / "p" / "pile_00000")
    result = runner.invoke(app, ["plan", pile, "--objective", "f3", "--views", "8", "--view-spread", "1", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["grasps"][0]["targets"]
    bad = runner.invoke(app, ["plan", pile, "--views", "3"])
    assert bad.exit_code != 0 and "views must be one of" in bad.output
    bad = runner.invoke(app, ["plan", pile, "--view-spread", "1"])
    assert bad.exit_code != 0 and "needs views > 1" in bad.output


def test_reconstruct_names_a_bad_log_direction(tmp_path):
    result = runner.invoke(app, ["reconstruct", str(tmp_path), "--gnss", str(tmp_path / "g.csv"), "--out",
                                 str(tmp_path / "o"), "--log-direction", "north"])
    assert result.exit_code != 0
    assert "--log-direction must be an angle in degrees or 'site'" in result.output
    result = runner.invoke(app, ["reconstruct", str(tmp_path), "--gnss", str(tmp_path / "g.csv"), "--out",
                                 str(tmp_path / "o"), "--log-direction", "400"])
    assert result.exit_code != 0 and "log_direction_deg must be in [-180, 180]" in result.output


def test_reconstruct_prints_the_per_log_report(tmp_path):
    """The per-log table names each log, how it was fitted, its length, diameter, GNSS residuals,
    fit RMS and coverage (the report keys, not stale names)."""
    from field.cli import DEMO_DATA

    result = runner.invoke(app, ["reconstruct", str(DEMO_DATA / "scan"), "--gnss", str(DEMO_DATA / "gnss.csv"),
                                 "--out", str(tmp_path / "o")], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    for title in ("log", "fit", "length m", "diam. m", "GNSS res. a m", "GNSS res. b m", "fit rms m", "coverage"):
        assert title in result.output, result.output
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    for log in report["logs"]:
        assert log["log_id"] in result.output and log["fit"] in ("scan", "partial", "hidden")
    from reconstruct.cli import log_table_row

    row = log_table_row({**report["logs"][0], "rms_m": float("nan"), "top_diameter_m": None})
    assert row[1] in ("scan", "partial", "hidden") and "-" in row
