import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from experiments.choice_geometry import (GRAPPLE_CLOSED_AREA_M2, binned, bundle_fill, clearance_m, main, mean_section_m2,
                                         measure)
from synth.geometry.frames import OrthoGrid

GRASP = {"x_m": 0.0, "y_m": 0.0, "phi_rad": 0.0, "width_m": 1.0}  # its rectangle: x in [-0.5, 0.5], y in [-0.1, 0.1]


def _observation(obstacle_x_m: tuple[float, float] | None, size_px: int = 128, extent_m: float = 5.0):
    grid = OrthoGrid(size_px, extent_m)
    x, y = grid.pixel_to_pile(*np.mgrid[0:size_px, 0:size_px])
    inst = np.zeros((size_px, size_px), np.int32)
    if obstacle_x_m:
        inst[(x >= obstacle_x_m[0]) & (x <= obstacle_x_m[1]) & (np.abs(y) <= 0.2)] = 1000
    return SimpleNamespace(intensity=np.zeros((size_px, size_px), np.float32), depth=np.full((size_px, size_px), 5.0, np.float32),
                           instance=inst, extent_m=extent_m, camera_height_m=5.0)


def test_a_cylinders_section_and_a_frustums_lies_between_its_ends():
    assert mean_section_m2(0.2, None) == pytest.approx(math.pi * 0.01)
    a = mean_section_m2(0.3, 0.1)
    assert math.pi / 4 * 0.01 < a < math.pi / 4 * 0.09


def test_fill_sums_the_targets_sections_over_the_closed_area():
    logs = [SimpleNamespace(diameter_m=0.2, top_diameter_m=None), SimpleNamespace(diameter_m=0.4, top_diameter_m=0.4),
            SimpleNamespace(diameter_m=1.0, top_diameter_m=None)]
    pile = SimpleNamespace(logs=logs)
    assert bundle_fill(pile, [0, 1]) == pytest.approx(math.pi * (0.01 + 0.04) / GRAPPLE_CLOSED_AREA_M2)


def test_clearance_is_the_gap_from_the_rectangle_to_the_obstacle():
    d = clearance_m(_observation((0.9, 1.1)), GRASP)
    assert d == pytest.approx(0.4, abs=2 * 5.0 / 128)
    assert clearance_m(_observation((0.45, 0.6)), GRASP) == 0.0  # overlapping
    assert clearance_m(_observation(None), GRASP) is None


def test_bins_count_successes_and_failure_kinds():
    rows = [{"v": 0.1, "o": "success"}, {"v": 0.15, "o": "not_closed"}, {"v": 0.5, "o": "success"},
            {"v": None, "o": "success"}]
    b = binned(rows, "v", (0.0, 0.2, 1.0), "o")
    assert [(x["n"], x["success"], x["failures"]) for x in b] == [(2, 0.5, {"not_closed": 1}), (1, 1.0, {})]


def test_measure_regenerates_the_evaluated_pile(tmp_path):
    from planner.evaluate import EvalConfig, eval_pile

    task = (2, True, 0, 123)
    pile = eval_pile(task, EvalConfig(seed_base=100))
    rec = {"planner": "unet-f3", "n_logs": 2, "obstacles": True, "k": 0, "seed": 123, "targets": [0, 1],
           "grasp": GRASP, "outcome": "not_closed", "field": {"grasp": GRASP, "outcome": "success"}}
    (tmp_path / "records").mkdir()
    (tmp_path / "records" / "123.json").write_text(json.dumps([rec]))
    rows = measure(tmp_path, seed_base=100)
    assert len(rows) == 1
    assert rows[0]["fill"] == pytest.approx(bundle_fill(pile, [0, 1]))
    assert rows[0]["outcome"] == "not_closed" and rows[0]["field_outcome"] == "success"
    main([str(tmp_path), "--seed-base", "100", "--out", str(tmp_path / "rows.json")])
    assert json.loads((tmp_path / "rows.json").read_text())[0]["tau"] == 2


def test_a_folder_without_records_is_named(tmp_path, capsys):
    with pytest.raises(SystemExit, match="no records/ folder"):
        main([str(tmp_path)])
