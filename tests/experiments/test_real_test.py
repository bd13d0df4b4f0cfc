"""experiments.real_test: grasps across pile frames, the summary's arithmetic, the record, and one real
twin scan end to end (scan, reconstruction, two plans, two trials on the truth)."""

from __future__ import annotations

import math
import shutil
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from field.errors import FieldError
from experiments.real_test import (REAL_TEST_FORMAT, RealTestConfig, grasp_to_truth_frame, read_real_test, real_test_pile,
                             run_real_test, summarize, write_real_test)
from planner.model import UNetConfig
from synth.geometry.frames import make_T, rot_z
from synth.geometry.grasp import Grasp
from synth.scene.pile import Georeference, LogSpec, PileSpec, TerrainSpec


def _pile(T_site_pile: np.ndarray, origin=(64.1, 20.0, 250.0)) -> PileSpec:
    return PileSpec(terrain=TerrainSpec(seed=1, extent_m=5.0, resolution=16, amplitude_m=0.0),
                    logs=(LogSpec.from_endpoints((-1.0, 0.0, 0.1), (1.0, 0.0, 0.1), 0.2),), georef=Georeference(*origin, T_site_pile=tuple(tuple(float(v) for v in r) for r in T_site_pile)))


def test_grasp_goes_through_the_site_frame():
    truth = _pile(make_T(rot_z(math.radians(30.0)), (2.0, -1.0, 0.0)))
    recon = _pile(make_T(rot_z(math.radians(-60.0)), (1.0, 0.5, 0.0)))
    g = Grasp(0.4, -0.2, 0.3, 0.8)
    out = grasp_to_truth_frame(g, recon, truth)
    # by hand: recon -> site -> truth; the frames differ by -90 deg of yaw
    p_site = recon.georef.matrix() @ np.array([0.4, -0.2, 0.0, 1.0])
    p_truth = np.linalg.inv(truth.georef.matrix()) @ p_site
    assert out.x_m == pytest.approx(p_truth[0], abs=1e-9) and out.y_m == pytest.approx(p_truth[1], abs=1e-9)
    expected_phi = (0.3 - math.pi / 2 + math.pi / 2) % math.pi - math.pi / 2
    assert out.phi_rad == pytest.approx(expected_phi, abs=1e-9)
    assert out.width_m == g.width_m
    # the same reconstructed frame under another site origin (100 m north): through geodetic
    # coordinates, the same grasp to a millimetre
    from synth.geometry import geodesy

    origin2 = tuple(float(v[0]) for v in geodesy.site_to_geodetic((64.1, 20.0, 250.0), np.array([[0.0, 100.0, 0.0]])))
    ends = geodesy.geodetic_to_site(origin2, *geodesy.site_to_geodetic(
        (64.1, 20.0, 250.0), (recon.georef.matrix() @ np.array([[0, 0, 0, 1], [1, 0, 0, 1.0]]).T).T[:, :3]))
    ends = np.asarray(ends, dtype=float).reshape(2, 3)
    yaw = math.atan2(*(ends[1] - ends[0])[1::-1])
    recon2 = _pile(make_T(rot_z(yaw), ends[0]), origin=origin2)
    out2 = grasp_to_truth_frame(g, recon2, truth)
    assert math.hypot(out2.x_m - out.x_m, out2.y_m - out.y_m) < 1e-3
    assert abs(out2.phi_rad - out.phi_rad) < 1e-3
    no_georef = replace(recon, georef=None)
    with pytest.raises(FieldError, match="georeference"):
        grasp_to_truth_frame(g, no_georef, truth)


def _row(seed, truth_ok, recon_ok, same=True):
    g = {"x_m": 0.0, "y_m": 0.0, "phi_rad": 0.0, "width_m": 1.0}
    return {"seed": seed, "objective": "f1", "recon_error": None,
            "truth": {"grasp": g, "targets": [0], "success": truth_ok},
            "recon": {"grasp": g, "targets": [0 if same else 1], "success": recon_ok},
            "diff": {"position_m": 0.1, "angle_deg": 5.0, "width_m": 0.02, "same_targets": same}}


def test_summary_counts_and_paired_uncertainty():
    rows = [_row(0, True, True), _row(1, True, False), _row(2, False, False), _row(3, False, True),
            _row(4, True, True, same=False)]
    s = summarize(rows)
    assert s["n_piles"] == 5
    assert s["success_truth"] == pytest.approx(0.6) and s["success_recon"] == pytest.approx(0.6)
    assert s["difference_pp"] == pytest.approx(0.0)
    assert (s["both_succeed"], s["only_truth"], s["only_recon"], s["neither"]) == (2, 1, 1, 1)
    # discordant 1 + 1, each plus a half: sqrt(3) / 5
    assert s["difference_se_pp"] == pytest.approx(100 * math.sqrt(3) / 5)
    assert s["outcome_agreement"] == pytest.approx(0.6) and s["same_targets"] == pytest.approx(0.8)
    assert "not resolved" in s["verdict"]
    # all agreeing on few piles is no proof of anything
    assert "not resolved" in summarize([_row(k, True, True) for k in range(3)])["verdict"]


def test_record_round_trip_and_version_check(tmp_path):
    rec = {"format": REAL_TEST_FORMAT, "format_version": "1.0", "rows": [], "summary": {}}
    p = write_real_test(rec, tmp_path / "r.json")
    assert read_real_test(p) == rec
    write_real_test({**rec, "format_version": "2.0"}, tmp_path / "new.json")
    with pytest.raises(FieldError, match="not supported"):
        read_real_test(tmp_path / "new.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(FieldError, match="not valid JSON"):
        read_real_test(tmp_path / "bad.json")


def test_config_validation():
    with pytest.raises(ValueError):
        RealTestConfig(objectives=("f4",))
    with pytest.raises(ValueError):
        RealTestConfig(logs=(5, 3))


def test_one_twin_scan_end_to_end(tmp_path, monkeypatch):
    cfg = RealTestConfig(n_piles=1, seed=700000, logs=(3, 3), obstacles=(0, 0), objectives=("f1",))
    rec = run_real_test(cfg, work_dir=tmp_path / "work", record_path=tmp_path / "real.json")
    assert rec["failures"] == [] and rec["piles_done"] == 1
    (row,) = rec["rows"]
    assert row["n_logs"] == 3 and row["n_matched_logs"] == 3 and row["recon_error"] is None
    for side in ("truth", "recon"):
        assert isinstance(row[side]["success"], bool) and row[side]["outcome"]
        assert all(0 <= t < 3 for t in row[side]["targets"])
    # the angle difference is the one between the two grasps (pi-periodic), not just any value <= 90 deg
    d = (row["truth"]["grasp"]["phi_rad"] - row["recon"]["grasp"]["phi_rad"]) % math.pi
    assert row["diff"]["angle_deg"] == pytest.approx(math.degrees(min(d, math.pi - d)), abs=1e-9)
    assert rec["summary"]["f1"]["n_piles"] == 1
    # the record on disk is the one returned; running again resumes it (nothing left to run)
    assert read_real_test(tmp_path / "real.json")["rows"] == rec["rows"]
    again = run_real_test(cfg, work_dir=tmp_path / "work2", record_path=tmp_path / "real.json")
    assert again["rows"] == rec["rows"] and not (tmp_path / "work2" / "scan_700000").exists()
    # a new record on the same work folder reuses the scan and its reconstruction: same rows,
    # no new scan, no new reconstruction
    import reconstruct.pipeline
    import reconstruct.scan.twin_scan

    def refuse(*a, **k):
        raise AssertionError("the kept scan should have been reused")

    monkeypatch.setattr(reconstruct.scan.twin_scan, "make_twin_scan", refuse)
    monkeypatch.setattr(reconstruct.pipeline, "reconstruct", refuse)
    reused = run_real_test(cfg, work_dir=tmp_path / "work", record_path=tmp_path / "real2.json")
    def strip(x):  # CPU times differ from run to run
        if isinstance(x, dict):
            return {k: strip(v) for k, v in x.items() if not k.endswith("cpu_s")}
        return [strip(v) for v in x] if isinstance(x, list) else x

    assert strip(reused["rows"]) == strip(rec["rows"])
    # another pile frame (site axes, not the default 45 deg): the scan is reused, the reconstruction made again
    def reconstructed_again(*a, **k):
        raise AssertionError("reconstructed again")

    monkeypatch.setattr(reconstruct.pipeline, "reconstruct", reconstructed_again)
    with pytest.raises(AssertionError, match="reconstructed again"):
        real_test_pile(700000, tmp_path / "work", SimpleNamespace(config=UNetConfig()),
                       RealTestConfig(logs=(3, 3), obstacles=(0, 0), log_direction_deg=None))
    # a later fitting revision makes kept reconstructions again, and does not resume older records
    import experiments.real_test as rt

    monkeypatch.setattr(rt, "FIT_REVISION", rt.FIT_REVISION + 1)
    with pytest.raises(AssertionError, match="reconstructed again"):
        real_test_pile(700000, tmp_path / "work", SimpleNamespace(config=UNetConfig()), cfg)
    assert not rt._same_test(rec, cfg, rec["model"]["sha256"])
    monkeypatch.undo()
    monkeypatch.setattr(reconstruct.scan.twin_scan, "make_twin_scan", refuse)
    monkeypatch.setattr(reconstruct.pipeline, "reconstruct", reconstructed_again)
    # a folder that kept only the truth of a scan makes the scan again
    shutil.rmtree(tmp_path / "work" / "scan_700000" / "scan")
    with pytest.raises(AssertionError, match="reused"):
        real_test_pile(700000, tmp_path / "work", SimpleNamespace(config=UNetConfig()), replace(cfg, log_direction_deg=None))
    # other scan settings are another scan: not reused
    with pytest.raises(AssertionError, match="reused"):
        real_test_pile(700000, tmp_path / "work", SimpleNamespace(config=UNetConfig()), RealTestConfig(logs=(3, 3), obstacles=(0, 0), grid=(1, 1)))
