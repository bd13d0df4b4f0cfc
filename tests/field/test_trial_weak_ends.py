"""The operator's confirmation also warns about target logs with an end placed on a weak estimate
(a float point the scan does not see, a contradicted point, an inferred end)."""

from __future__ import annotations

from types import SimpleNamespace


def _end(source: str, sigma_m: float, contradicted: bool = False) -> dict:
    return {"source": source, "scan": "open" if sigma_m > 0.05 else "seen", "sigma_m": sigma_m,
            "contradicted": contradicted}


def test_targets_resting_on_a_weak_end_are_warned_about(tmp_path):
    from field.trial import PreparedTrial, weak_ends_by_log

    report = {"logs": [{"ends": [_end("scan", 0.015), _end("float", 0.23)]},
                       {"ends": [_end("fixed", 0.012), _end("scan", 0.016)]},
                       {"ends": [_end("scan", 0.015, contradicted=True), _end("fixed", 0.012)]}]}
    weak = weak_ends_by_log(report)
    assert weak[1] == [] and "end b (float, scan: open, +-23 cm)" in weak[0][0] and "contradicted" in weak[2][0]
    best = SimpleNamespace(targets=(0, 1), quality=0.9, graspability=0.95, balance=0.9)
    geo = SimpleNamespace(easting_m=1.0, northing_m=2.0, h_ell_m=3.0, heading_grid_deg=10.0, heading_true_deg=9.0,
                          width_m=1.2)
    trial = PreparedTrial(pile=SimpleNamespace(n_logs=3), plan=SimpleNamespace(best=best), geo=geo, command_fields={},
                          captured_utc_s=0.0, work_dir=tmp_path,
                          report={"log_fits": ["scan"] * 3, "log_weak_ends": weak})
    warn = [s for s in trial.summary_lines() if s.startswith("WARNING")]
    assert len(warn) == 1 and "target log 0" in warn[0] and "weak estimate" in warn[0] and "float" in warn[0]
