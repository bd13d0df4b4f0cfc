"""Obstacles in the survey-conditions records: the summary's share of scans with a phantom obstacle, its column
in the compare table, and rescoring old records from the kept piles of their work folders."""

from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from experiments.survey_conditions import cloud_fingerprint, read_survey_records
from experiments.survey_report import compare_markdown, compare_summary, survey_markdown, survey_summary
from experiments.survey_rescore import RescoreError, rescore_obstacles
from synth.scene.pile import LogSpec, PileSpec, StumpSpec, TerrainSpec, write_pile

KEY = {"seed0": 10, "logs": [3, 7], "obstacles": [0, 3], "fit_revision": 22}


def _obstacles(phantom=(), missed=()):
    return {"gate_m": 0.3, "n_truth": 2, "n_recon": 2, "matched": [], "phantom_obstacles": list(phantom),
            "missed_obstacles": list(missed)}


def _entry(obstacles=None):
    e = {"wall_s": 2.0, "cpu_s": 1.5, "logs": [], "unmatched_truth": [], "unmatched_recon": [], "weak_ends": 0,
         "contradicted_points": 0}
    return e if obstacles is None else {**e, "obstacles": obstacles}


def _row(seed, conditions, cloud="x"):
    return {"key": KEY, "seed": seed, "stereo_wall_s": 10.0, "stereo_cpu_s": 8.0, "load": 1.0, "cpus": 2,
            "processes": 1, "cloud_sha256": cloud, "conditions": conditions}


def _write(out, rows):
    (out / "scans").mkdir(parents=True)
    for r in rows:
        (out / "scans" / f"{r['seed']}.json").write_text(json.dumps(r, indent=1))


def test_the_summary_gives_the_share_of_scans_with_a_phantom_obstacle(tmp_path):
    rows = [_row(10, {"fixed": _entry(_obstacles(phantom=[0, 1], missed=[1]))}),
            _row(11, {"fixed": _entry(_obstacles())}),
            _row(12, {"fixed": {"error": "SeparationError: ..."}}),  # refused: no pile, not counted
            _row(13, {"fixed": _entry()}),  # a 2.1 record: no comparison, not counted
            _row(14, {"fixed": _entry(_obstacles(missed=[0]))})]
    _write(tmp_path, rows)
    o = survey_summary(read_survey_records(tmp_path))["fixed"]["obstacles"]
    assert (o["scans"], o["scans_with_phantom"], o["phantom_obstacles"], o["missed_obstacles"]) == (3, 1, 2, 2)
    assert abs(o["phantom_share"] - 1 / 3) < 1e-12 and o["true_obstacles"] == 6
    assert "| fixed | 3 | 1 (33.3 %) | 2 | 2 / 6 |" in "\n".join(survey_markdown(read_survey_records(tmp_path)))


def test_the_compare_table_has_the_phantom_obstacle_column(tmp_path):
    _write(tmp_path / "a", [_row(10, {"fixed": _entry(_obstacles(phantom=[0]))}), _row(11, {"fixed": _entry(_obstacles())})])
    _write(tmp_path / "b", [_row(10, {"fixed": _entry()}), _row(11, {"fixed": _entry()})])
    recs = {"new": read_survey_records(tmp_path / "a", write=False), "old": read_survey_records(tmp_path / "b", write=False)}
    assert compare_summary(recs)["fixed"]["new"]["obstacles"]["scans_with_phantom"] == 1
    table = "\n".join(compare_markdown(recs))
    assert "scans with a phantom obstacle | phantom / missed obstacles |" in table
    assert "| 0 | 1 / 2 (50.0 %) | 1 / 0 | - |" in table  # phantom logs, then the two obstacle cells
    assert "| 0 | - | - | - |" in table  # the record without comparisons


# -- rescoring: a kept work folder with the true pile, a reconstruction and the stereo cloud --
def _pile(stumps):
    terrain = TerrainSpec(extent_m=5.0, resolution=32, amplitude_m=0.0,
                          heights_m=tuple(tuple(0.0 for _ in range(32)) for _ in range(32)))
    logs = (LogSpec.from_endpoints((-1.0, -0.4, 0.08), (1.0, -0.4, 0.08), 0.16),
            LogSpec.from_endpoints((-0.9, 0.5, 0.07), (1.1, 0.3, 0.07), 0.14))
    return PileSpec(terrain=terrain, logs=logs, stumps=tuple(
        StumpSpec(position_m=xy, height_m=0.4, bottom_radius_m=0.1, top_radius_m=0.1) for xy in stumps))


@pytest.fixture()
def kept(tmp_path):
    """A work folder of scan 10 (truth: stumps at (2, 2) and (-2, 2); the kept revision 22 reconstruction of
    'fixed' has the first and a phantom at (2, -2), its second log 3 cm off) and its record."""
    from reconstruct.compare import compare_piles

    truth = _pile([(2.0, 2.0), (-2.0, 2.0)])
    recon = replace(_pile([(2.1, 2.0), (2.0, -2.0)]),
                    logs=(truth.logs[0], LogSpec.from_endpoints((-0.9, 0.53, 0.07), (1.1, 0.33, 0.07), 0.14)))
    root = tmp_path / "work" / "scan_10"
    write_pile(truth, root / "truth" / "pile.json")
    write_pile(recon, root / "recon_fixed" / "pile.json")
    (root / "recon_fixed" / "report.json").write_text(json.dumps({"estimator": None}))
    points = np.arange(30, dtype=float).reshape(10, 3)
    np.savez(root / "cloud.npz", points=points)
    end = {"source": "scan", "scan": "seen", "sigma_m": 0.015, "contradicted": False}
    logs = [{"truth_index": e["truth_index"], "worst_end_m": e["endpoint_max_err_m"],
             "diameter_err_m": e["diameter_err_m"], "mask_iou": None, "ends": [end, end]}
            for e in compare_piles(truth, recon, render=False)["logs"]]
    row = _row(10, {"fixed": {**_entry(), "logs": logs}, "degraded": {"error": "FitError: ..."}},
               cloud=cloud_fingerprint(SimpleNamespace(points=points)))
    _write(tmp_path / "rec", [row])
    return tmp_path / "rec", tmp_path / "work"


def test_rescoring_fills_the_obstacles_from_the_kept_pile_and_keeps_the_rest(kept):
    rec, work = kept
    before = json.loads((rec / "scans" / "10.json").read_text())
    got = rescore_obstacles(rec, work, progress=lambda s: None)
    assert got["counts"] == {"filled": 1, "refused": 1}
    after = json.loads((rec / "scans" / "10.json").read_text())
    o = after["conditions"]["fixed"].pop("obstacles")
    assert o["phantom_obstacles"] == [1] and o["missed_obstacles"] == [1] and len(o["matched"]) == 1
    assert after.pop("format_version") == "2.2" and after == before
    assert json.loads((rec / "summary.json").read_text())["summary"]["fixed"]["obstacles"]["scans_with_phantom"] == 1


def test_a_kept_pile_that_is_not_the_records_is_not_used(kept):
    rec, work = kept
    path = rec / "scans" / "10.json"
    row = json.loads(path.read_text())
    row["conditions"]["fixed"]["logs"][1]["worst_end_m"] += 0.01  # the record measured another reconstruction
    path.write_text(json.dumps(row, indent=1))
    assert rescore_obstacles(rec, work, progress=lambda s: None)["counts"] == {"another reconstruction": 1, "refused": 1}
    row["conditions"]["fixed"]["logs"][1]["worst_end_m"] -= 0.01
    row["key"] = {**KEY, "estimator": "joint", "estimator_revision": 10}  # a joint record: no recon_fixed_joint here
    path.write_text(json.dumps(row, indent=1))
    assert rescore_obstacles(rec, work, progress=lambda s: None)["counts"] == {"no kept pile": 1, "refused": 1}
    (work / "scan_10" / "recon_fixed").rename(work / "scan_10" / "recon_fixed_joint")  # kept, but revision 22's
    assert rescore_obstacles(rec, work, progress=lambda s: None)["counts"] == {"another estimator revision": 1, "refused": 1}
    row["key"] = KEY
    row["cloud_sha256"] = "another"
    (work / "scan_10" / "recon_fixed_joint").rename(work / "scan_10" / "recon_fixed")
    path.write_text(json.dumps(row, indent=1))
    assert rescore_obstacles(rec, work, progress=lambda s: None)["counts"] == {"another stereo cloud": 1, "refused": 1}
    assert "obstacles" not in json.loads(path.read_text())["conditions"]["fixed"]


def test_a_record_not_written_by_the_bench_is_refused(kept):
    rec, work = kept
    path = rec / "scans" / "10.json"
    path.write_text(json.dumps(json.loads(path.read_text())))  # another layout: rewriting would change every line
    with pytest.raises(RescoreError, match="not as the bench writes it"):
        rescore_obstacles(rec, work, progress=lambda s: None)
