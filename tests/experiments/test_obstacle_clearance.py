"""experiments.obstacle_clearance: what is tried, and the paired summary."""

from types import SimpleNamespace

import pytest

import experiments.obstacle_clearance as oc
from synth.geometry.grasp import RECT_WIDTH_M, Grasp

G1, G2 = Grasp(0.0, 0.0, 0.0, 0.8), Grasp(0.5, 0.0, 0.0, 0.8)


def test_only_choices_the_switch_changed_are_tried(monkeypatch):
    import planner.evaluate
    import synth.physics.trial

    tried = []
    monkeypatch.setattr(planner.evaluate, "eval_scene", lambda task, cfg: ("pile", "obs"))
    monkeypatch.setattr(synth.physics.trial, "run_trial", lambda pile, g, targets, cfg: tried.append(g.x_m) or
                        SimpleNamespace(outcome=SimpleNamespace(value="success" if g.x_m > 0 else "collision")))
    planners = {("f1", "as_is"): lambda o, p: (G1, (0,)), ("f1", "clear"): lambda o, p: (G1, (0,)),
                ("f3", "as_is"): lambda o, p: (G1, (0, 1)), ("f3", "clear"): lambda o, p: (G2, (0, 1))}
    rec = oc.pile_record((3, True, 0, 7), planners, SimpleNamespace(trial="fast"))
    assert not rec["f1"]["changed"] and "as_is_outcome" not in rec["f1"]
    assert rec["f3"]["changed"] and (rec["f3"]["as_is_outcome"], rec["f3"]["clear_outcome"]) == ("collision", "success")
    assert tried == [0.0, 0.5]


def _entry(changed, a=None, b=None, tau=2):
    c = {"grasp": G1.to_dict(), "targets": list(range(tau))}
    e = {"as_is": c, "clear": c, "changed": changed}
    if changed:
        e.update(as_is_outcome=a, clear_outcome=b)
    return e


def test_the_summary_pairs_the_changed_choices_over_all_piles():
    recs = [{"f1": _entry(False), "f3": _entry(True, "collision", "success", tau=4)},
            {"f1": _entry(True, "success", "collision"), "f3": _entry(True, "collision", "success", tau=2)},
            {"f1": _entry(False), "f3": _entry(False)}]
    s = oc.summarise(recs)
    assert (s["f3"]["piles"], s["f3"]["changed"], s["f3"]["as_is_successes"], s["f3"]["clear_successes"]) == (3, 2, 0, 2)
    assert s["f3"]["difference_pp"] == pytest.approx(200 / 3)
    assert s["f3"]["logs_per_success_changed"]["clear"] == 3.0
    assert s["f1"]["difference_pp"] == pytest.approx(-100 / 3)
    assert "| f3 | 3 | 2 | 0 / 2 |" in oc.markdown(s)


def test_a_missing_ranker_is_a_one_line_error(tmp_path, capsys):
    with pytest.raises(SystemExit):
        oc.main(["--out", str(tmp_path), "--ranker", str(tmp_path / "none.safetensors")])
    assert "--ranker: no file" in capsys.readouterr().err


def test_the_rows_are_the_products_constraints_and_the_claws_of_the_twins_grapple():
    from planner.constraints import Constraints
    from synth.physics.grapple import GrappleConfig

    assert oc.row_constraints("claws") == Constraints()  # the product's default
    assert oc.row_constraints("as_is") == Constraints(clear_obstacles=False)
    clear = oc.row_constraints("clear")
    assert (clear.claw_plate_m, clear.claw_width_m) == (0.0, RECT_WIDTH_M)
    claws = oc.row_constraints("claws")
    assert (claws.claw_plate_m, claws.claw_width_m) == (GrappleConfig().claw_thickness_m, GrappleConfig().claw_width_m)
    with pytest.raises(ValueError, match="unknown row"):
        oc.row_constraints("elsewhere")


def test_the_claws_comparison_names_its_rows():
    c = {"grasp": G1.to_dict(), "targets": [0, 1, 2]}
    recs = [{obj: {"clear": c, "claws": c, "changed": True, "clear_outcome": "collision", "claws_outcome": "success"}
             for obj in oc.OBJECTIVES}]
    rows = oc.COMPARISONS["claws"]
    s = oc.summarise(recs, rows)
    assert (s["f3"]["clear_successes"], s["f3"]["claws_successes"]) == (0, 1)
    assert s["f3"]["logs_per_success_changed"]["claws"] == 3.0
    assert "| f3 | 1 | 1 | 0 / 1 |" in oc.markdown(s, rows) and "clear / claws" in oc.markdown(s, rows)
