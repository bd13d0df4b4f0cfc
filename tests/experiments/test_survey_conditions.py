"""The survey-conditions bench's record and summary, on hand-made scan records (no scans run)."""

import json

import pytest

from experiments.survey_conditions import SURVEY_CONDITIONS, read_survey_records
from experiments.survey_report import seed_ranges, survey_markdown, survey_summary

KEY = {"seed0": 10, "logs": [3, 7], "obstacles": [0, 3], "fit_revision": 11}


def _log(worst_cm, dia_cm, iou=0.9, sources=("scan", "fixed"), scan=("seen", "seen"), sigma_cm=(1.5, 1.5),
         contradicted=(False, False)):
    return {"worst_end_m": worst_cm / 100, "diameter_err_m": dia_cm / 100, "mask_iou": iou,
            "ends": [{"source": s, "scan": st, "sigma_m": sg / 100, "contradicted": c}
                     for s, st, sg, c in zip(sources, scan, sigma_cm, contradicted)]}


def _ok(*logs, missing=()):
    return {"wall_s": 2.0, "cpu_s": 1.5, "logs": list(logs), "unmatched_truth": list(missing),
            "unmatched_recon": [], "weak_ends": 1, "contradicted_points": 0}


def _scan(seed, conditions, key=KEY):
    return {"key": key, "seed": seed, "stereo_wall_s": 10.0, "stereo_cpu_s": 8.0, "load": 1.0, "cpus": 2,
            "processes": 1, "conditions": conditions}


def _write(out, rows):
    (out / "scans").mkdir(parents=True)
    for r in rows:
        (out / "scans" / f"{r['seed']}.json").write_text(json.dumps(r))


def test_summary_counts_failures_and_per_log_errors(tmp_path):
    rows = [_scan(10, {"default": _ok(_log(1, 0.5), _log(3, -2.0, sources=("float", "inferred"))),
                       "fixed": _ok(_log(1, 0.2)), "degraded": {"error": "FitError: log 1 ..."}}),
            _scan(11, {"default": _ok(_log(5, 1.0), missing=[2]), "fixed": _ok(_log(2, 0.4)),
                       "degraded": _ok(_log(20, 3.0))})]
    _write(tmp_path, rows)
    rec = read_survey_records(tmp_path)
    s = survey_summary(rec)
    assert set(s) == set(SURVEY_CONDITIONS)
    d = s["default"]
    assert (d["scans"], d["failures"], d["logs"], d["missing_logs"]) == (2, 0, 3, 1)
    assert abs(d["worst_end_m"]["median"] - 0.03) < 1e-12 and abs(d["worst_end_m"]["max"] - 0.05) < 1e-12
    assert abs(d["abs_diameter_m"]["max"] - 0.02) < 1e-12  # absolute: the -2 cm log
    assert d["sources"] == {"scan": 2, "fixed": 2, "float": 1, "inferred": 1}
    assert d["scan_wall_s"]["median"] == 12.0  # stereo + reconstruction
    g = s["degraded"]
    assert (g["scans"], g["failures"], g["logs"]) == (2, 1, 1)
    assert g["failure_messages"] == ["10: FitError: log 1 ..."]
    assert json.loads((tmp_path / "summary.json").read_text())["seeds"] == [10, 11]
    table = "\n".join(survey_markdown(rec))
    assert "| degraded | 2 | 1 (50.0 %) | 1 | 0 | 20.0 |" in table and "- degraded, seed 10: FitError" in table


def test_records_of_other_settings_are_left_out(tmp_path):
    other = {**KEY, "fit_revision": 10}
    _write(tmp_path, [_scan(10, {"default": _ok(_log(1, 0.1))}), _scan(11, {"default": _ok(_log(1, 0.1))}),
                      _scan(12, {"default": _ok(_log(9, 0.1))}, key=other)])
    rec = read_survey_records(tmp_path)  # the settings of most records
    assert [r["seed"] for r in rec["scans"]] == [10, 11] and rec["key"] == KEY
    assert [r["seed"] for r in read_survey_records(tmp_path, other)["scans"]] == [12]


def test_seed_ranges_show_the_gaps():
    assert seed_ranges({"scans": [{"seed": s} for s in (5, 3, 4, 9, 11, 10)]}) == "3..5, 9..11"
    assert seed_ranges({"scans": []}) == "-"


def test_a_cloud_fingerprint_tells_two_scans_apart():
    from types import SimpleNamespace

    import numpy as np

    from experiments.survey_conditions import cloud_fingerprint

    pts = np.random.default_rng(0).normal(size=(100, 3))
    a, b = SimpleNamespace(points=pts), SimpleNamespace(points=pts.copy())
    assert cloud_fingerprint(a) == cloud_fingerprint(b) and len(cloud_fingerprint(a)) == 16
    b.points[7, 2] += 1e-9  # one coordinate of one point
    assert cloud_fingerprint(a) != cloud_fingerprint(b)


def test_the_tail_tells_blind_logs_from_silently_wrong_ones(tmp_path):
    """The worst-end tail split into what the survey cannot place better (a float end the scan does not
    see), the rest, and what the report did not warn about (the defects to chase)."""
    blind = _log(25, 0.5, sources=("scan", "float"), scan=("seen", "open"), sigma_cm=(1.5, 20))
    seen_float = _log(2, 0.5, sources=("scan", "float"), scan=("seen", "seen"))  # the scan sees it: not blind
    silent = _log(40, 0.5)  # two sure ends, 40 cm off: silently wrong
    warned = _log(30, 0.5, contradicted=(True, False))
    rows = [_scan(10, {"default": _ok(blind, seen_float, silent, warned, _log(1, 0.1))})]
    _write(tmp_path, rows)
    rec = read_survey_records(tmp_path)
    t = survey_summary(rec)["default"]["tail"]
    assert (t["blind_logs"], t["blind_over_far"], t["over_far"], t["silent_over_far"]) == (1, 1, 3, 1)
    assert abs(t["blind_share"] - 0.2) < 1e-12 and abs(t["other_worst_end_m"]["max"] - 0.40) < 1e-12
    assert "| default | 1 | 20.0 % | 25.0 | 25.0 | 1 |" in "\n".join(survey_markdown(rec))


def test_the_heldout_set_has_other_seeds_and_other_shapes():
    from experiments.survey_conditions import SURVEY_SETS, TUNING_SEED_RANGE, pile_shape, survey_set_key

    assert survey_set_key("tuning") == {}  # the tuning records from before the held-out set resume as they are
    key = {"seed0": SURVEY_SETS["heldout"]["seed0"]} | survey_set_key("heldout")
    assert key["set"] == "heldout" and not TUNING_SEED_RANGE[0] <= key["seed0"] < TUNING_SEED_RANGE[1]
    shapes = [pile_shape(key, key["seed0"] + i) for i in range(6)]
    assert shapes == ["packed", "loose", "dropped"] * 2
    assert pile_shape({"seed0": 1_100_000}, 1_100_007) == "dropped"  # a tuning record: one shape
    assert survey_set_key("heldout", estimator="joint")["estimator"] == "joint"
    # JointConfig options away from their defaults are the record's key too, and only the joint estimator's
    key = survey_set_key("heldout", estimator="joint", joint_options={"radius_states": True})
    assert key["joint_options"] == {"radius_states": True}
    assert "joint_options" not in survey_set_key("heldout", estimator="joint")
    with pytest.raises(ValueError, match="radius_states.*--survey-estimator joint"):
        survey_set_key("heldout", joint_options={"radius_states": True})
    with pytest.raises(ValueError, match="tuning set's seeds"):
        survey_set_key("heldout", 1_100_050)
    # the final set (the ship decision) has seeds of its own, and no other set may take them or the held-out's
    assert survey_set_key("final")["set"] == "final" and SURVEY_SETS["final"]["seed0"] == 5_500_000
    with pytest.raises(ValueError, match="heldout set's seeds"):
        survey_set_key("final", 3_300_005)
    with pytest.raises(ValueError, match="final set's seeds"):
        survey_set_key("heldout", 5_500_000)
    with pytest.raises(ValueError, match="--survey-set"):
        survey_set_key("other")


def test_a_heldout_record_says_so(tmp_path):
    from experiments.survey_conditions import survey_set_key

    key = {**KEY, "seed0": 3_300_000} | survey_set_key("heldout")
    _write(tmp_path, [{**_scan(3_300_000 + i, {"fixed": _ok(_log(1, 0.1))}, key=key), "shape": s}
                      for i, s in enumerate(("packed", "loose"))])
    rec = read_survey_records(tmp_path)
    assert rec["set"] == "heldout"
    text = "\n".join(survey_markdown(rec))
    assert "the heldout set" in text and "packed 1, loose 1 piles" in text
    assert "estimator" not in text
    options = {"radius_states": True}
    key = {**KEY, "seed0": 3_300_000} | survey_set_key("heldout", estimator="joint", joint_options=options)
    _write(tmp_path / "joint", [_scan(3_300_000, {"fixed": _ok(_log(1, 0.1))}, key=key)])
    text = "\n".join(survey_markdown(read_survey_records(tmp_path / "joint")))
    assert "estimator joint, radius_states True)" in text


def test_a_loose_shape_scatters_the_pile():
    """The held-out set's 'loose' shape reaches the pile generator: the same seed's logs lie farther apart."""
    import numpy as np

    from experiments.survey_conditions import PILE_SHAPES
    from synth.scene.generate import GenerationConfig, generate_pile

    def spread(**kw):
        pile, _ = generate_pile(3_300_001, GenerationConfig(n_logs=5, **kw))
        c = np.array([lg.centre_m[:2] for lg in pile.logs])
        return float(np.linalg.norm(c - c.mean(axis=0), axis=1).mean())

    assert spread(**PILE_SHAPES["loose"]) > 1.3 * spread()


def test_estimators_are_compared_on_the_scans_they_share(tmp_path):
    from experiments.survey_report import compare_markdown, compare_summary

    blind = _log(30, 0.5, sources=("float", "scan"), scan=("open", "seen"), sigma_cm=(20, 1.5))
    a = [{**_scan(10, {"fixed": _ok(_log(1, 0.2)), "degraded": _ok(blind)}), "cloud_sha256": "x"},
         {**_scan(11, {"fixed": {"error": "SeparationError: ..."}}), "cloud_sha256": "y"}]
    b = [{**_scan(10, {"fixed": {**_ok(_log(12, 0.3, contradicted=(True, False))), "contradicted_points": 1}, "degraded": _ok(_log(2, 0.1))}),
          "cloud_sha256": "x"},
         {**_scan(11, {"fixed": _ok(_log(1, 0.1))}), "cloud_sha256": "other"},  # another scan of seed 11
         {**_scan(12, {"fixed": _ok(_log(1, 0.1))}), "cloud_sha256": "z"}]
    _write(tmp_path / "a", a)
    _write(tmp_path / "b", b)
    recs = {"rules22": read_survey_records(tmp_path / "a", write=False),
            "joint": read_survey_records(tmp_path / "b", write=False)}
    assert not (tmp_path / "a" / "summary.json").exists()
    s = compare_summary(recs)
    assert s["fixed"]["rules22"]["scans"] == s["fixed"]["joint"]["scans"] == 1  # seed 10 only
    assert s["fixed"]["joint"]["over_8cm"] == 1 and s["fixed"]["joint"]["points_called_wrong"] == 1
    assert s["fixed"]["joint"]["silent_over_8cm"] == 0  # its end is weak: warned about
    assert s["degraded"]["rules22"]["blind_logs"] == 1 and s["degraded"]["rules22"]["blind_within_2sigma"] == 1
    assert "| degraded | rules22 | 1 | 0 (0.0 %) | 30.0 |" in "\n".join(compare_markdown(recs))


def test_survey_pairs_key():
    """2x2 adds nothing to a record's key (the records before planned scans resume); auto names the plan's
    config, equal to itself after a JSON round trip (a resumed run finds its records); anything else is refused."""
    import json

    from experiments.survey_conditions import survey_pairs_key

    assert survey_pairs_key("2x2") == {}
    key = survey_pairs_key("auto")
    assert key["pairs"] == "auto" and key["plan"]["margin_m"] > 0 and json.loads(json.dumps(key)) == key
    with pytest.raises(ValueError, match="--survey-pairs"):
        survey_pairs_key("3x3")
