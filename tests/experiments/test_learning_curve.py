"""The learning curve's training side: nested shares trained with one recipe, a finished share not
trained again once its resume state is left out (as committed), its convergence in the table."""

import pytest

import experiments.learning_curve as lc
from planner.train import read_log
from tests.planner.planner_helpers import make_dataset


def _train(data, out, shares, epochs=1):
    return lc.train_shares([str(data)], out, shares, epochs=epochs, base_channels=4, device="cpu",
                           precision="fp32", max_steps_per_epoch=2, batch_size=4, progress=lambda m: None)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("lc")
    data, out = root / "data", root / "out"
    data.mkdir()
    make_dataset(data, n_piles=8)
    return data, out, _train(data, out, (0.5, 1.0))


def test_each_share_trains_its_own_model(trained):
    data, out, models = trained
    assert set(models) == {0.5, 1.0}
    for s, path in models.items():
        assert path == lc.share_dir(out, s) / "model.safetensors" and path.exists()
        assert read_log(path.parent / "log.json")["config"]["data"]["train_fraction"] == s
        assert read_log(path.parent / "log.json")["config"]["loss"]["u_pos_weight"] == lc.U_POS_WEIGHT


def test_a_committed_share_without_resume_state_is_not_trained_again(trained, monkeypatch):
    data, out, _ = trained
    folder = lc.share_dir(out, 1.0)
    assert lc.finished_share(folder, 1)
    (folder / "state.safetensors").unlink()  # what the commit leaves out
    import planner.train

    monkeypatch.setattr(planner.train, "train", lambda *a, **k: pytest.fail("a finished share was trained again"))
    assert _train(data, out, (1.0,)) == {1.0: folder / "model.safetensors"}


def test_a_share_with_epochs_missing_is_not_finished(trained, tmp_path):
    data, out, _ = trained
    folder = lc.share_dir(out, 0.5)
    assert lc.finished_share(folder, 1) and not lc.finished_share(folder, 2)
    assert not lc.finished_share(tmp_path, 1)  # nothing there


def test_the_table_says_where_each_share_converged(trained, tmp_path):
    data, out, models = trained
    conv = lc.convergence(lc.share_dir(out, 0.5))
    assert conv["best_epoch"] == 1 and conv["epochs_run"] == 1 and conv["val_loss"] > 0
    rows = [{"share": 0.5, "objective": "f1", "train_piles": 3, "piles": 24, "success_rate": 0.75,
             "avg_logs_success": 2.0, "beta_avg_deg": 9.0, **conv}]
    lc.write_curve(rows, tmp_path)
    table = (tmp_path / "learning_curve.md").read_text()
    assert "| curve | 0.5 | 3 | f1 | 24 | 75.0 % ± 17.3 | 2.00 | 9.0° | 1 / 1 |" in table
    assert (tmp_path / "learning_curve.png").stat().st_size > 1000


def test_another_recipes_model_gets_its_own_rows_with_its_share(trained):
    data, out, models = trained
    total = {"piles": 24, "success_rate": 0.5, "avg_logs_success": 2.0, "beta_avg_deg": 9.0}
    tables = {"planners": {n: {"total": total} for n in ("share1-f1", "other-f1")}}
    rows = lc.curve_rows(tables, {1.0: models[1.0]}, ["f1"], {0.5: 3, 1.0: 6}, extra={"other": models[0.5]})
    assert [(r["recipe"], r["share"], r["train_piles"]) for r in rows] == [("curve", 1.0, 6), ("other", 0.5, 3)]


def test_a_model_without_its_training_log_is_compared_as_a_level(trained, tmp_path):
    data, out, models = trained
    alone = tmp_path / "shipped.safetensors"
    alone.write_bytes(models[1.0].read_bytes())  # no log.json beside it
    assert lc.model_share(alone) is None
    total = {"piles": 24, "success_rate": 0.5, "avg_logs_success": 2.0, "beta_avg_deg": 9.0}
    tables = {"planners": {n: {"total": total} for n in ("share1-f1", "shipped-f1")}}
    rows = lc.curve_rows(tables, {1.0: models[1.0]}, ["f1"], {1.0: 6}, extra={"shipped": alone})
    assert rows[1]["share"] is None and rows[1]["train_piles"] is None and rows[1]["val_loss"] is None
    lc.write_curve(rows, tmp_path)
    assert "| shipped | - | - | f1 | 24 | 50.0 % ± 20.0 | 2.00 | 9.0° | - | - |" in (tmp_path / "learning_curve.md").read_text()
