"""experiments.not_closed: a planner's NOT_CLOSED choice tried again, as it is and with the trial changed."""

import json
from pathlib import Path

import pytest

from experiments.not_closed import choices, main, select, trial_config
from synth.physics.trial_spec import TRIAL_REVISION

ROOT = Path(__file__).resolve().parents[2]
EVAL = ROOT / "docs" / "results" / "eval-ranker-r1-970"
SEED = 970600019  # a 2-log pile without obstacles; f1 chose one 0.15 m log, the tips pinched it 0.16 m apart


def _folder(tmp_path: Path) -> Path:
    (tmp_path / "records").mkdir()
    (tmp_path / "eval.json").write_text((EVAL / "eval.json").read_text())
    rows = [r for r in json.loads((EVAL / "records" / f"{SEED}.json").read_text()) if r["planner"] == "unet-f1"]
    (tmp_path / "records" / f"{SEED}.json").write_text(json.dumps(rows))
    return tmp_path


@pytest.mark.skipif(TRIAL_REVISION != 4, reason="the committed record was made with trial revision 4")
def test_a_recorded_not_closed_choice_reproduces_and_holds_when_lifted_anyway(tmp_path):
    folder = _folder(tmp_path)
    main([str(folder), "--out", str(tmp_path / "as-is.json")])
    (row,) = json.loads((tmp_path / "as-is.json").read_text())["rows"]
    assert (row["was"], row["now"], row["stop_reason"]) == ("not_closed", "not_closed", "inside")
    assert 0.12 < row["final_gap_m"] < row["thinnest_target_m"] + 0.05  # the tips stopped on the log itself
    main([str(folder), "--set", "max_closed_gap_m=0.6", "--out", str(tmp_path / "lifted.json")])
    (row,) = json.loads((tmp_path / "lifted.json").read_text())["rows"]
    assert row["now"] == "success"


def test_the_selection_takes_every_not_closed_choice_then_a_sample_then_the_rest():
    rows = [{"outcome": o, "grasp": {}, "n": i} for i, o in enumerate(
        ["not_closed", "success", "success", "collision", "not_closed", "success", "no_grasp"])]
    picked = select(rows, successes=2, others=True, seed=0)
    assert [t for t, _ in picked] == ["not_closed", "not_closed", "success", "success", "other"]
    assert [r["n"] for t, r in picked if t == "not_closed"] == [0, 4]
    assert select(rows, successes=0, others=False, seed=0) == [("not_closed", rows[0]), ("not_closed", rows[4])]


def test_each_choice_is_taken_once_whichever_planners_chose_it():
    rows = choices(EVAL)
    keys = {(r["seed"], tuple(r["targets"]), r["grasp"]["x_m"], r["grasp"]["y_m"], r["grasp"]["phi_rad"]) for r in rows}
    assert len(keys) == len(rows) < sum(len(json.loads(f.read_text())) for f in (EVAL / "records").glob("*.json"))


def test_a_wrong_override_is_a_one_line_error(tmp_path, capsys):
    with pytest.raises(ValueError, match="max_gap: not a numeric TrialConfig field"):
        trial_config("fast", {"max_gap": 0.6})
    assert trial_config("fast", {"max_closed_gap_m": 0.6}).max_closed_gap_m == 0.6
    with pytest.raises(SystemExit) as e:
        main([str(_folder(tmp_path)), "--set", "max_gap=0.6", "--out", str(tmp_path / "x.json")])
    assert e.value.code == 2 and "--set max_gap" in capsys.readouterr().err
