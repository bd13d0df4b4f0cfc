"""Recorded planner choices and their comparison (experiments.plan_choices): what counts as the same
chosen grasp, and the record's versioned file."""

import json
import math

import pytest

from experiments.plan_choices import compare_choices, read_choices, write_choices


def _grasp(targets, pixel, phi, u=0.9, width=0.8):
    return {"targets": list(targets), "pixel": list(pixel), "x_m": 0.0, "y_m": 0.0, "phi_rad": phi,
            "width_m": width, "q": u, "u": u, "b": 1.0}


def _record(grasps):
    return {"precision": "bf16", "batch_size": 16, "piles": [
        {"seed": 1, "logs": 2, "obstacles": False, "objective": "f1", "subsets": len(grasps), "grasps": grasps}]}


def test_same_choice_within_a_pixel_and_angle_modulo_pi():
    before = _record([_grasp((0, 1), (10, 10), math.pi / 2 - 1e-4), _grasp((0,), (3, 3), 0.1, u=0.5)])
    after = _record([_grasp((0, 1), (10, 11), -math.pi / 2 + 1e-4), _grasp((0,), (3, 3), 0.1, u=0.5 + 1e-7)])
    cmp = compare_choices(before, after)
    row = cmp["rows"][0]
    assert cmp["same"] == 1 and row["same_targets"] and row["d_phi_rad"] == pytest.approx(2e-4)
    assert row["max_du"] == pytest.approx(1e-7) and row["subsets_moved"] == 0
    assert compare_choices(after, before)["rows"][0]["d_phi_rad"] == pytest.approx(2e-4)  # either way round


@pytest.mark.parametrize("change", ["subset", "pixel", "angle", "width"])
def test_a_different_choice_is_reported(change):
    g = {"subset": _grasp((1,), (10, 10), 0.3), "pixel": _grasp((0, 1), (10, 12), 0.3),
         "angle": _grasp((0, 1), (10, 10), 0.32), "width": _grasp((0, 1), (10, 10), 0.3, width=0.82)}[change]
    before = _record([_grasp((0, 1), (10, 10), 0.3), _grasp((1,), (10, 10), 0.3, u=0.5)])
    after = _record([g, _grasp((0, 1) if change == "subset" else (1,), (10, 10), 0.3, u=0.5)])
    cmp = compare_choices(before, after)
    assert cmp["same"] == 0
    assert cmp["rows"][0]["same_targets"] == (change != "subset")


def test_record_file_round_trip_and_version(tmp_path):
    rec = _record([_grasp((0,), (1, 2), 0.0)])
    write_choices(tmp_path / "c.json", rec)
    assert read_choices(tmp_path / "c.json")["piles"] == rec["piles"]
    doc = json.loads((tmp_path / "c.json").read_text())
    (tmp_path / "v2.json").write_text(json.dumps({**doc, "format_version": "2.0"}))
    with pytest.raises(ValueError, match="version"):
        read_choices(tmp_path / "v2.json")
    with pytest.raises(ValueError, match="not in the earlier record"):
        compare_choices(_record([]) | {"piles": []}, rec)
