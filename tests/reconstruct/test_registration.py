"""reconstruct.registration: the scan pose sidecar and the refinement against the survey (the coarse
placement from the GNSS alone: tests/reconstruct/scan/test_unposed_scan.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from reconstruct.errors import RegistrationError
from reconstruct.fitting.fit import sample_top_view_points
from reconstruct.config import ReconstructConfig
from reconstruct.registration import ScanPose, read_scan_pose, refine_registration, write_scan_pose
from synth.geometry.frames import apply_T, make_T, rot_z


def test_scan_pose_round_trip(tmp_path):
    T = make_T(rot_z(0.3), (1.0, 2.0, 3.0))
    pose = ScanPose(64.1, 20.0, 250.0, tuple(tuple(float(v) for v in r) for r in T))
    write_scan_pose(pose, tmp_path)
    back = read_scan_pose(tmp_path)
    assert back == pose
    d = json.loads((tmp_path / "scan_pose.json").read_text())
    d["format_version"] = "2.0"
    (tmp_path / "scan_pose.json").write_text(json.dumps(d))
    with pytest.raises(RegistrationError, match="not supported"):
        read_scan_pose(tmp_path)
    (tmp_path / "scan_pose.json").write_text('{"format": "loggrasp.scan-pose", "format_')  # truncated
    with pytest.raises(RegistrationError, match="scan pose .* is not valid JSON.*--georegister gnss"):
        read_scan_pose(tmp_path)
    with pytest.raises(ValueError):
        ScanPose(164.1, 20.0, 250.0, pose.T_site_scan)


def test_refinement_recovers_a_small_pose_error(crossed):
    pts = sample_top_view_points(crossed, 300, 0.002, np.random.default_rng(0))
    ends = {f"log{i}": log.endpoints_m() for i, log in enumerate(crossed.logs)}
    wrong = make_T(rot_z(math.radians(1.0)), (0.03, -0.02, 0.015))
    T, rep, fitted = refine_registration(apply_T(wrong, pts), ends, ReconstructConfig())
    assert sorted(fitted) == ["log0", "log1", "log2"]
    assert rep["mode"] == "4dof"
    assert rep["residual_rms_after_m"] < rep["residual_rms_before_m"]
    assert rep["residual_rms_after_m"] < 0.01
    probe = np.array([[1.0, 1.0, 0.1], [-1.0, -1.0, 0.1]])
    err = np.linalg.norm(apply_T(T @ wrong, probe) - probe, axis=1)
    assert err.max() < 0.01, err
    with pytest.raises(RegistrationError, match="correction"):
        refine_registration(apply_T(wrong, pts), ends, ReconstructConfig(max_correction_m=0.01))


def test_a_log_the_scan_shows_less_of_than_the_shortest_log_is_not_registered_to(crossed, monkeypatch):
    """A fit shorter than any log (0.15 m of a log the scan hardly shows) is no axis to register to and no
    log spec: it is reported among the logs not fitted, and the others register, instead of a crash."""
    import reconstruct.registration as registration

    pts = sample_top_view_points(crossed, 300, 0.002, np.random.default_rng(0))
    ends = {f"log{i}": log.endpoints_m() for i, log in enumerate(crossed.logs)}
    real = registration.fit_log

    def a_scrap_of_log1(points, a, b, cfg, log_id=None, **kw):
        f = real(points, a, b, cfg, log_id=log_id, **kw)
        if log_id != "log1":
            return f
        u = (f.ends[1] - f.ends[0]) / np.linalg.norm(f.ends[1] - f.ends[0])
        return f.with_ends(np.stack([f.centre - 0.075 * u, f.centre + 0.075 * u]))

    monkeypatch.setattr(registration, "fit_log", a_scrap_of_log1)
    T, rep, fitted = refine_registration(pts, ends, ReconstructConfig())
    assert sorted(fitted) == ["log0", "log2"] and rep["logs_used"] == ["log0", "log2"]
    assert "shows 0.15 m of it, less than the shortest log" in rep["logs_not_fitted"]["log1"]


# -- the ground plane ---------------------------------------------------------------------------
def _ground_and_clutter(seed: int = 0):
    rng = np.random.default_rng(seed)
    n = np.array([0.05, -0.03, 1.0])
    n /= np.linalg.norm(n)
    xy = rng.uniform(-2.0, 2.0, (3000, 2))
    ground = np.c_[xy, -(n[0] * xy[:, 0] + n[1] * xy[:, 1] + 0.4) / n[2]] + rng.normal(0, 0.005, (3000, 1)) * n
    clutter = np.c_[rng.uniform(-2.0, 2.0, (2000, 2)), rng.uniform(-0.3, 0.3, 2000)]  # logs, stumps over it
    return np.r_[ground, clutter], n, 0.4


def test_ransac_plane_finds_the_ground_under_clutter():
    from reconstruct.scan.coarse_pose import ransac_plane

    P, n, d = _ground_and_clutter()
    plane, inl = ransac_plane(P, 0.02, 500, np.random.default_rng(0))
    sign = np.sign(plane[:3] @ n)
    assert math.degrees(math.acos(min(1.0, abs(plane[:3] @ n)))) < 0.5
    assert abs(sign * plane[3] - d) < 0.005
    assert np.isin(np.arange(3000), inl).mean() > 0.99  # the ground points
    assert (inl >= 3000).sum() < 0.1 * 2000  # few clutter points (those lying within 2 cm of it)


def test_ransac_plane_is_deterministic():
    from reconstruct.scan.coarse_pose import ransac_plane

    P, _, _ = _ground_and_clutter(1)
    runs = [ransac_plane(P, 0.04, 60, np.random.default_rng(3)) for _ in range(3)]
    for plane, inl in runs[1:]:
        assert plane.tobytes() == runs[0][0].tobytes() and np.array_equal(inl, runs[0][1])
