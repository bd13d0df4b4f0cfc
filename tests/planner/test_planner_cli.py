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
