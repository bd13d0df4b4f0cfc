"""The verification bench's summary, on hand-made rows (no twin run): success, the paired
differences against the network alone and the truth-planned reference, failures, config checks."""

import math

import numpy as np
import pytest

from experiments.measure import paired_se
from experiments.verification import VerifyBenchConfig, markdown, summarise


def _v(ok, logs=3, beta_deg=10.0, plan_s=1.0, outcome="success"):
    return {"success": ok, "grasped": list(range(logs)) if ok else [],
            "cos_beta": math.cos(math.radians(beta_deg)), "plan_s": plan_s, "plan_cpu_s": plan_s,
            "outcome": outcome if ok else "collision", "trials": 4}


def _rows():
    net, ver, truth = [1, 0, 0, 1], [1, 1, 0, 1], [1, 1, 1, 1]
    return [{"seed": 700 + i, "objective": "f3", "n_logs": 4 + i,
             "variants": {"truth-planned": _v(bool(truth[i])), "network": _v(bool(net[i])),
                          "verify K=4": _v(bool(ver[i]), logs=4, beta_deg=6.0, plan_s=3.0)}}
            for i in range(4)]


def test_summary_pairs_each_planner_with_the_network_and_the_truth():
    rec = {"config": {"objectives": ["f3"], "seed": 700, "logs": [3, 6], "obstacles": [0, 2], "ks": [4],
                      "copies": 0, "model_sha256": "ab" * 32}, "rows": _rows(), "loads": []}
    t = summarise(rec)["f3"]
    assert t["network"]["success"] == 0.5 and t["verify K=4"]["success"] == 0.75
    d, lo, hi = t["verify K=4"]["vs_network_pp"]
    se = paired_se(np.array([1, 0, 0, 1.0]), np.array([1, 1, 0, 1.0]))
    assert d == 25.0 and math.isclose(hi - d, 196 * se) and math.isclose(d - lo, 196 * se)
    assert t["verify K=4"]["vs_truth_pp"][0] == -25.0
    assert t["verify K=4"]["logs_per_success"] == 4.0 and math.isclose(t["verify K=4"]["beta_deg"], 6.0)
    assert t["network"]["failures"] == {"collision": 2} and t["verify K=4"]["failures"] == {"collision": 1}
    assert t["verify K=4"]["plan_s_median"] == 3.0 and t["verify K=4"]["plan_s_median_6logs"] == 3.0
    assert "| verify K=4 | 4 | 75.0 % | +25.0 [" in markdown(rec, "python bench/bench_verify.py")


def test_rows_without_the_truth_reference_are_left_out():
    rows = _rows() + [{"seed": 800, "objective": "f3", "n_logs": 4, "variants": {}}]
    rec = {"config": {"objectives": ["f3"]}, "rows": rows}
    assert summarise(rec)["f3"]["network"]["piles"] == 4


@pytest.mark.parametrize("bad", [{"ks": ()}, {"ks": (0, 4)}, {"piles": 0}, {"workers": 0}, {"copies": -1}])
def test_config_refuses_what_cannot_be_measured(bad):
    with pytest.raises(ValueError):
        VerifyBenchConfig(**bad)


def test_a_record_made_by_other_fitting_or_trial_code_is_not_resumed(tmp_path, monkeypatch):
    """A resumed record must hold one measurement: rows of piles reconstructed (or grasps tried) by
    another revision of the code would mix silently. The run refuses before it measures anything."""
    import json

    from experiments.verification import run
    from reconstruct.fitting.fit import FIT_REVISION
    from synth.physics.trial_spec import TRIAL_REVISION

    measured = []

    def no_twin(fn, tasks, keep, workers=1):  # each pile "measured" (an empty row): the record is written
        for seed in tasks:
            measured.append(seed)
            keep(seed, [{"seed": seed, "objective": "f1", "variants": {}}])

    monkeypatch.setattr("synth.common.runner.run_tasks", no_twin)
    out, cfg = tmp_path / "record.json", VerifyBenchConfig(piles=2)
    run(cfg, tmp_path / "work", out, progress=lambda m: None)
    config = json.loads(out.read_text())["config"]
    assert (config["fit_revision"], config["trial_revision"]) == (FIT_REVISION, TRIAL_REVISION) and len(measured) == 2
    run(cfg, tmp_path / "work", out, progress=lambda m: None)  # the same code resumes it: nothing left to do
    assert len(measured) == 2
    for key in ("fit_revision", "trial_revision"):
        out.write_text(json.dumps({"config": dict(config, **{key: config[key] - 1}), "rows": [], "loads": []}))
        with pytest.raises(ValueError, match="another measurement"):
            run(cfg, tmp_path / "work", out, progress=lambda m: None)
    assert len(measured) == 2


def test_the_report_sets_apart_the_piles_whose_reconstruction_was_refused():
    rows = _rows()
    rows[1]["recon_error"] = "SeparationError: log 2 would have to move 12 cm"
    rec = {"config": {"objectives": ["f3"], "seed": 700, "logs": [3, 6], "obstacles": [0, 2], "ks": [4],
                      "copies": 0, "model_sha256": "ab" * 32, "fit_revision": 18, "trial_revision": 3},
           "rows": rows, "loads": []}
    md = markdown(rec, "python bench/bench_verify.py")
    assert "(fitting revision 18, trial revision 3)" in md
    assert "## On the piles reconstructed (3 of 4; 1 refused: 25.0 %)" in md
    assert "| f3 | verify K=4 | 3 | 66.7 % |" in md  # piles 700, 702, 703: verified 1, 0, 1
