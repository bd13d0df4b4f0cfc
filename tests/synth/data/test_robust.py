"""Robust labels: repeats under the field's positioning error decide and are stored."""

from types import SimpleNamespace

import pytest

from synth.data.candidates import reduce_candidates
from synth.data.dataset import DatasetJob, DatasetJobError
from synth.data.datastore import build_store, chunk_path
from synth.data.robust import RobustLabels, confirmer, repeat_rows
from synth.geometry.grasp import Grasp
from synth.physics.perturb import PositioningError


def _result(ok: bool):
    return SimpleNamespace(success=ok, cos_beta=1.0, grasped=(), outcome=SimpleNamespace(value="success" if ok else "dropped"))


def _within(radius_m: float, centre=(0.0, 0.0)):
    """A stand-in trial: succeeds when the grasp lands within ``radius_m`` of ``centre``."""
    calls = []

    def simulate(g):
        calls.append(g)
        return _result((g.x_m - centre[0]) ** 2 + (g.y_m - centre[1]) ** 2 <= radius_m ** 2)
    return simulate, calls


def test_a_grasp_with_margin_is_accepted_with_its_repeats():
    simulate, calls = _within(0.5)
    c = confirmer(RobustLabels(), simulate, 0, "pile")(Grasp(0.0, 0.0, 0.0, 0.6))
    assert c.accepted and c.successes == 3 and len(c.repeats) == 3  # decided after three successes
    assert len(calls) == 3 and all(g != Grasp(0.0, 0.0, 0.0, 0.6) for g in calls)  # moved, not the exact grasp
    rows = repeat_rows(c)
    assert [r[4] for r in rows] == ["success"] * 3 and rows[0][:4] == [calls[0].x_m, calls[0].y_m, calls[0].phi_rad, 0.6]


def test_a_knife_edge_grasp_is_refused_after_two_failures():
    simulate, calls = _within(0.001)  # only the exact spot works
    c = confirmer(RobustLabels(), simulate, 0, "pile")(Grasp(0.0, 0.0, 0.0, 0.6))
    assert not c.accepted and len(c.repeats) == 2 and c.fraction == 0.0


def test_repeats_are_the_same_in_every_run_and_differ_per_key():
    a = confirmer(RobustLabels(), _within(0.5)[0], 7, "pile", (0, 1))(Grasp(0.0, 0.0, 0.0, 0.6))
    b = confirmer(RobustLabels(), _within(0.5)[0], 7, "pile", (0, 1))(Grasp(0.0, 0.0, 0.0, 0.6))
    c = confirmer(RobustLabels(), _within(0.5)[0], 7, "pile", (0, 2))(Grasp(0.0, 0.0, 0.0, 0.6))
    assert repeat_rows(a) == repeat_rows(b) != repeat_rows(c)


def test_algorithm_1_skips_a_fragile_success_and_accepts_the_robust_one():
    fragile, robust = Grasp(1.0, 0.0, 0.0, 0.5), Grasp(0.0, 0.0, 0.0, 0.6)

    def simulate(g):  # the fragile spot works only exactly; around the robust one, 30 cm of margin
        if (g.x_m, g.y_m) == (1.0, 0.0):
            return _result(True)
        return _result(abs(g.x_m) < 0.3 and abs(g.y_m) < 0.3)

    labels = RobustLabels()
    res = reduce_candidates([fragile, robust], simulate, confirm=confirmer(labels, simulate, 0, "p"), dw_range_m=(0.0, 0.0))
    assert [g for g, _ in res.accepted] == [Grasp(0.0, 0.0, 0.0, 0.6)]
    assert res.unconfirmed >= 1
    verdicts = {res.trials[i][0].x_m: c.accepted for i, c in res.confirmations.items()}
    assert verdicts == {1.0: False, 0.0: True}
    plain = reduce_candidates([fragile, robust], simulate, dw_range_m=(0.0, 0.0))
    assert plain.accepted[0][0] == fragile  # the paper's labels take the lottery ticket


@pytest.mark.parametrize("kw, match", [(dict(label_sigma_xy_m=0.0), "sigma_xy_m"), (dict(label_sigma_xy_m=-0.01), "sigma_xy_m"),
                                       (dict(label_sigma_phi_deg=0.0), "sigma_phi_deg"), (dict(label_repeats=-1), "repeats"),
                                       (dict(label_min_fraction=1.5), "min_fraction")])
def test_nonsense_label_settings_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        DatasetJob(n_piles=1, **kw)


TINY = dict(n_logs=2, obstacles_fraction=0.0, seed=3, size_px=32, n_renders=2, max_trials_per_subset=3)


def _factory(pile, targets):
    return lambda g: _result(g.width_m < 0.75)


def test_a_store_keeps_every_repeat_and_refuses_a_resume_with_another_error(tmp_path):
    import gzip
    import json

    build_store(tmp_path, DatasetJob(n_piles=1, **TINY), simulate_factory=_factory)
    d = json.loads(gzip.decompress(chunk_path(tmp_path, 0).read_bytes()))
    confirmed = [t for p in d["piles"] for s in p["subsets"] for t in s["trials"] if "r" in t]
    accepted = sum(len(s["accepted"]) for p in d["piles"] for s in p["subsets"])
    assert accepted and len(confirmed) == accepted and all(len(t["r"]) >= 3 for t in confirmed)
    assert d["stats"]["repeats"] == sum(len(t["r"]) for t in confirmed)
    with pytest.raises(DatasetJobError, match="label_sigma_xy_m"):
        build_store(tmp_path, DatasetJob(n_piles=2, label_sigma_xy_m=0.03, **TINY), simulate_factory=_factory)


@pytest.mark.parametrize("flags, word", [(["--label-error", "0,2"], "sigma_xy_m"), (["--label-error", "2cm"], "SIGMA_XY_M"),
                                         (["--label-error", "0.02,-1"], "sigma_phi_deg")])
def test_a_bad_positioning_error_on_the_command_line(tmp_path, capsys, flags, word):
    from field.cli import run

    code = run(["synth", "dataset", "--piles", "1", "--out", str(tmp_path / "d"), *flags])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error:")]
    assert code == 2 and len(err) == 1 and word in err[0] and "--label-error" in err[0]
    assert not (tmp_path / "d").exists()
