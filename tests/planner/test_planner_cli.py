"""planner.cli: what ``loggrasp train`` shows while it runs."""

from __future__ import annotations

from pathlib import Path

import typer
from typer.testing import CliRunner

import planner.cli
import planner.data
import planner.train
from planner.train import TrainResult
from synth.common.cli import LineProgress


def test_a_resumed_training_shows_the_epochs_already_done(monkeypatch, tmp_path):
    """Resuming at epoch 3 of 16, the first progress line says 3/16, not 0/16."""
    def resumed_train(data, out, cfg, progress=None):
        progress({"kind": "step", "epoch": 3, "step": 1, "loss": 0.06, "samples_per_s": 23.0})
        progress({"kind": "epoch", "epoch": 3, "train_loss": 0.06, "val_loss": 0.05})
        p = Path(out)
        return TrainResult(p / "model.safetensors", p / "state.safetensors", p / "log.json", p / "curve.png", [],
                           {"epoch": 3})

    monkeypatch.setattr(planner.data, "list_shards", lambda d: ([], {"size_px": 64}))
    monkeypatch.setattr(planner.train, "train", resumed_train)
    monkeypatch.setattr(planner.cli, "progress_bar", lambda: LineProgress(every_s=0.0))
    (tmp_path / "data").mkdir()
    app = typer.Typer()
    app.command()(planner.cli.train_command)
    r = CliRunner().invoke(app, ["--data", str(tmp_path / "data"), "--out", str(tmp_path / "run"), "--epochs", "16"])
    assert r.exit_code == 0, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("training:")]
    assert lines[0].startswith("training: 3/16, step 1"), lines
    assert lines[1].startswith("training: 4/16, train 0.0600 val 0.0500"), lines


def test_eval_rows_with_a_ranker_and_in_another_precision(tmp_path):
    """eval's rows: --ranker adds a re-ranked copy of each plain U-Net row (not --extra-model or views
    rows), --ranked-only keeps only the copies; --precision applies to every U-Net row, never to a
    baseline, and is refused in one line for a model without its int8 calibration."""
    import pytest

    from planner.checkpoint import DEFAULT_MODEL
    from planner.cli.eval_specs import base_specs, view_specs, with_precision, with_ranker
    from synth.common.cli import CliError

    rk = tmp_path / "r.safetensors"
    rk.write_bytes(b"x")
    specs = base_specs(str(DEFAULT_MODEL), "f1,f3", "random", [f"other={DEFAULT_MODEL}"], None, 0)
    specs += view_specs(str(DEFAULT_MODEL), "f1", 4, 0.0)
    names = [s.name for s in with_ranker(specs, rk, 4, 0.0, False)]
    assert names == ["unet-f1", "unet-f3", "other", "random", "unet-f1-views4", "unet-f1-ranked4", "unet-f3-ranked4"]
    names = [s.name for s in with_ranker(specs, rk, 4, 0.0, True)]
    assert names == ["other", "random", "unet-f1-views4", "unet-f1-ranked4", "unet-f3-ranked4"]
    assert with_ranker(specs, None, 4, 0.0, False) == specs
    with pytest.raises(CliError, match="--ranked-only needs --ranker"):
        with_ranker(specs, None, 4, 0.0, True)
    int8 = with_precision(with_ranker(specs, rk, 4, 0.0, True), "int8")
    assert [s.name for s in int8] == ["other", "random", "unet-f1-int8-views4", "unet-f1-int8-ranked4",
                                      "unet-f3-int8-ranked4"]  # a labelled row keeps its label
    assert {s.precision for s in int8 if s.kind == "unet"} == {"int8"} and int8[1].precision == "auto"
    bare = tmp_path / "bare.safetensors"
    bare.write_bytes(Path(DEFAULT_MODEL).read_bytes())
    with pytest.raises(CliError, match="--precision int8: .*bare.safetensors has no int8 calibration beside it"):
        with_precision(base_specs(str(bare), "f1", "", [], None, 0), "int8")
