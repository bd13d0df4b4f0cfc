"""Unposed scans: pair poses from pycolmap SfM, the scan placed in the site frame from the GNSS end
points alone (coarse yaw/shift search + the usual refinement); clear errors when that cannot work."""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from reconstruct.errors import CoarseRegistrationError, ReconstructError, SfmRegistrationError
from reconstruct.config import ReconstructConfig
from reconstruct.report import read_report
from reconstruct.pipeline import reconstruct
from reconstruct.scan.coarse_pose import CoarseConfig, coarse_scan_pose
from reconstruct.scan.sfm import SfmConfig
from synth.geometry.frames import apply_T, invert_T, make_T, rot_z
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec


# -- coarse georegistration on exact geometry -----------------------------------------------------
def _flat(extent: float = 5.0) -> TerrainSpec:
    return TerrainSpec(extent_m=extent, resolution=32, amplitude_m=0.0,
                       heights_m=tuple(tuple(0.0 for _ in range(32)) for _ in range(32)))


def _scan_of(pile: PileSpec, T_site_pile: np.ndarray, noise_m: float = 0.003):
    """Top-view points of ``pile`` in a camera-like scan frame (z down, turned, tilted 3 deg,
    shifted), the camera position there, and the GNSS ends in the site frame."""
    from reconstruct.fitting.fit import sample_top_view_points

    pts = sample_top_view_points(pile, 250, noise_m, np.random.default_rng(1))
    tilt = math.radians(3.0)
    R_tilt = np.array([[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]])
    T_pile_scan = make_T(rot_z(0.7) @ R_tilt @ np.diag([1.0, -1.0, -1.0]), (0.3, -0.2, 3.0))  # a camera at 3 m
    T_scan_pile = invert_T(T_pile_scan)
    ends = {f"log{i}": tuple(apply_T(T_site_pile, np.stack(log.endpoints_m()))) for i, log in enumerate(pile.logs)}
    return apply_T(T_scan_pile, pts), np.zeros((1, 3)), ends, T_pile_scan


def test_coarse_pose_from_gnss_ends():
    pile = PileSpec(terrain=_flat(), logs=(
        LogSpec.from_endpoints((-1.0, -0.4, 0.08), (1.0, -0.4, 0.08), 0.16),
        LogSpec.from_endpoints((-0.9, 0.5, 0.07), (1.1, 0.3, 0.07), 0.14),
        LogSpec.from_endpoints((-0.6, -1.0, 0.233), (-0.4, 1.0, 0.233), 0.14),
    ))
    T_site_pile = make_T(rot_z(math.radians(130.0)), (12.0, -4.0, 0.5))
    pts, cams, ends, T_pile_scan = _scan_of(pile, T_site_pile)
    T, rep = coarse_scan_pose(pts, cams, ends)
    probe = np.array([[1.0, 1.0, 0.0], [-1.0, -1.0, 0.2], [1.0, -1.0, 0.1]])
    err = np.linalg.norm(apply_T(T @ invert_T(T_pile_scan), probe) - apply_T(T_site_pile, probe), axis=1)
    assert err.max() < 0.08, (err, rep)  # the refinement takes it from here (limits 0.3 m / 5 deg)
    assert rep["support"] > 0.8 and rep["second_peak_support"] < 0.9 * rep["support"]


def test_symmetric_pile_is_an_error_not_a_guess():
    # two equal parallel logs: turned by 180 deg the pile looks the same from above
    pile = PileSpec(terrain=_flat(), logs=(
        LogSpec.from_endpoints((-1.0, -0.35, 0.08), (1.0, -0.35, 0.08), 0.16),
        LogSpec.from_endpoints((-1.0, 0.35, 0.08), (1.0, 0.35, 0.08), 0.16),
    ))
    pts, cams, ends, _ = _scan_of(pile, make_T(rot_z(0.3), (2.0, 1.0, 0.0)))
    with pytest.raises(CoarseRegistrationError, match="almost equally well.*symmetric"):
        coarse_scan_pose(pts, cams, ends)


def test_symmetric_top_view_is_told_apart_by_the_heights():
    # the same two logs seen from above, but both rise towards +x: turned by 180 deg the top view
    # is the same, the survey's heights are not
    pile = PileSpec(terrain=_flat(), logs=(
        LogSpec.from_endpoints((-1.0, -0.35, 0.08), (1.0, -0.35, 0.45), 0.16),
        LogSpec.from_endpoints((-1.0, 0.35, 0.08), (1.0, 0.35, 0.45), 0.16),
    ))
    T_site_pile = make_T(rot_z(0.3), (2.0, 1.0, 0.0))
    pts, cams, ends, T_pile_scan = _scan_of(pile, T_site_pile)
    T, rep = coarse_scan_pose(pts, cams, ends)
    assert rep["resolved_by"] == "heights" and len(rep["height_spread_m"]) >= 2, rep
    probe = np.array([[1.0, 1.0, 0.0], [-1.0, -1.0, 0.2], [1.0, -1.0, 0.1]])
    err = apply_T(T @ invert_T(T_pile_scan), probe) - apply_T(T_site_pile, probe)
    # right way round (turned by 180 deg the probes would be metres off); the height of a pile of
    # raised logs is the refinement's to fix (the coarse height assumes the lowest log on the ground)
    assert np.linalg.norm(err[:, :2], axis=1).max() < 0.15 and np.abs(err[:, 2]).max() < 0.2, (err, rep)


def test_survey_of_another_pile_is_named():
    pile = PileSpec(terrain=_flat(), logs=(LogSpec.from_endpoints((-1.0, 0.0, 0.08), (1.0, 0.0, 0.08), 0.16),))
    pts, cams, _, _ = _scan_of(pile, np.eye(4))
    star = {f"s{k}": (np.array([0.0, 0.0, 0.1]), np.array([1.5 * math.cos(a), 1.5 * math.sin(a), 0.1]))
            for k, a in enumerate((0.0, 2.1, 4.2))}
    with pytest.raises(CoarseRegistrationError, match="no yaw puts the surveyed logs on the scan"):
        coarse_scan_pose(pts, cams, star)
    with pytest.raises(CoarseRegistrationError, match="no dominant ground plane"):
        rng = np.random.default_rng(0)
        coarse_scan_pose(rng.uniform(-2, 2, (5000, 3)), cams, star)
    with pytest.raises(ValueError):
        CoarseConfig(ambiguity_ratio=1.5)
    with pytest.raises(ValueError):
        ReconstructConfig(pair_poses="gps")


# -- an unposed twin scan end to end ------------------------------------------------------------
SEED = 7
# SIFT on 640 px images (the default 1280), 1,024 features each (4,096): a third of the SfM time, and on
# this scan as close to the truth as at 960 px / 2,048 (poses 2-5 cm, 0.4-0.8 deg; log ends <= 2.4 cm)
FAST = ReconstructConfig(sfm=SfmConfig(max_image_size_px=640, max_features=1024))


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """The same handheld scan twice: unposed (made through the CLI) and with its poses."""
    from typer.testing import CliRunner

    from field.cli import app
    from reconstruct.scan.twin_scan import make_twin_scan

    d = tmp_path_factory.mktemp("unposed")
    res = CliRunner().invoke(app, ["synth", "scan", "--out", str(d / "u"), "--seed", str(SEED), "--logs", "3-3",
                                   "--obstacles", "0-0", "--float-fixes", "0", "--unposed"])
    assert res.exit_code == 0, res.output
    posed = make_twin_scan(d / "p", SEED, logs=(3, 3), obstacles=(0, 0), n_float=0, handheld=True)
    return d / "u", posed, d


def test_unposed_scan_files(scans):
    from reconstruct.scan.sfm import pair_has_pose

    u, p, _ = scans
    assert not (u / "scan" / "scan_pose.json").exists() and (p / "scan" / "scan_pose.json").exists()
    for k in range(4):
        assert not pair_has_pose(u / "scan" / f"pair_{k:03d}" / "calibration.yaml")
        assert pair_has_pose(p / "scan" / f"pair_{k:03d}" / "calibration.yaml")
        assert (u / "scan" / f"pair_{k:03d}" / "left.png").read_bytes() == \
            (p / "scan" / f"pair_{k:03d}" / "left.png").read_bytes()
        assert "T_pile_cam" not in (u / "scan" / f"pair_{k:03d}" / "zed.conf").read_text()
    poses = json.loads((u / "truth" / "poses.json").read_text())["T_pile_cam"]
    heights = [T[2][3] for T in poses.values()]
    assert len(poses) == 4 and np.ptp(heights) > 0.01  # the rig moved between pairs


@pytest.mark.slow
def test_unposed_scan_reconstructs_like_the_posed_one(scans):
    from reconstruct.compare import compare_piles
    from synth.scene.pile import read_pile

    u, p, d = scans
    truth = read_pile(u / "truth" / "pile.json")
    res_u = reconstruct(u / "scan", u / "gnss.csv", d / "out_u", FAST)
    rep = read_report(d / "out_u")
    assert rep["scan_pose_source"] == "gnss-coarse" and rep["pair_poses_source"] == "sfm"
    assert rep["registration"]["residual_rms_after_m"] < 0.03
    assert rep["sfm"]["scale_spread"] < 0.05
    # SfM poses against the truth (relative to the first pair); SfM alone is off by 10-20 cm / 2-3 deg
    true = {k: np.asarray(v) for k, v in json.loads((u / "truth" / "poses.json").read_text())["T_pile_cam"].items()}
    for k, T in rep["sfm"]["T_scan_cam"].items():
        T_true = invert_T(true["pair_000"]) @ true[k]
        dR = T_true[:3, :3].T @ np.asarray(T)[:3, :3]
        pos_err = float(np.linalg.norm(np.asarray(T)[:3, 3] - T_true[:3, 3]))
        rot_err = math.degrees(math.acos(min(1.0, (np.trace(dR) - 1) / 2)))
        assert pos_err < 0.08 and rot_err < 2.0, (k, pos_err, rot_err)  # measured 2-5 cm, 0.4-0.8 deg
    res_p = reconstruct(p / "scan", p / "gnss.csv", d / "out_p")
    assert res_p.report["scan_pose_source"].endswith("scan_pose.json")
    cu, cp = compare_piles(truth, res_u.pile), compare_piles(truth, res_p.pile)
    assert cu["summary"]["n_matched"] == 3
    assert cu["summary"]["endpoint_err_m"]["max"] < 0.06, cu["logs"]
    assert cu["summary"]["endpoint_err_m"]["median"] < 0.04, cu["logs"]
    dia_u = {e["truth_index"]: e["diameter_err_m"] for e in cu["logs"]}
    dia_p = {e["truth_index"]: e["diameter_err_m"] for e in cp["logs"]}
    assert all(abs(dia_u[i] - dia_p[i]) < 0.01 for i in dia_p), (dia_u, dia_p)


def test_a_pair_that_overlaps_nothing_is_named(scans, tmp_path):
    from reconstruct.scan.twin_scan import make_twin_scan

    u, _, _ = scans
    bad = tmp_path / "bad"
    shutil.copytree(u / "scan", bad)
    other = make_twin_scan(tmp_path / "other", SEED + 50, logs=(3, 3), obstacles=(0, 0), n_float=0,
                           grid=(1, 1), unposed=True)
    shutil.rmtree(bad / "pair_003")
    shutil.copytree(other / "scan" / "pair_000", bad / "pair_003")
    with pytest.raises(SfmRegistrationError, match="pair_003") as info:
        reconstruct(bad, u / "gnss.csv", tmp_path / "o", FAST)
    assert isinstance(info.value, ReconstructError)
    # a posed-only request on an unposed scan says what to do
    with pytest.raises(ReconstructError, match="pair_poses='sfm'|no T_pile_cam"):
        reconstruct(u / "scan", u / "gnss.csv", tmp_path / "o2", ReconstructConfig(pair_poses="calibration"))
    with pytest.raises(ReconstructError, match="no scan_pose.json"):
        reconstruct(u / "scan", u / "gnss.csv", tmp_path / "o3", replace(ReconstructConfig(), georegister="scan-pose"))


def test_pairs_tied_only_among_themselves_are_an_error():
    from types import SimpleNamespace

    from reconstruct.scan.sfm import _check_linked

    pairs = [SimpleNamespace(folder=Path(f"scan/pair_00{k}")) for k in range(4)]
    labels = [p.folder.name for p in pairs]
    # tracks 0-19 seen by pairs 0 and 1, 100-119 by 2 and 3, track 50 by 1 and 3 only
    tracks = np.r_[np.arange(20), np.arange(20), np.arange(100, 120), np.arange(100, 120), 50, 50]
    who = np.r_[np.zeros(20), np.ones(20), np.full(20, 2), np.full(20, 3), 1, 3].astype(int)
    with pytest.raises(SfmRegistrationError, match=r"pair_002, scan/pair_003 share fewer than 10"):
        _check_linked(tracks, who, labels, pairs, SfmConfig())
    # one more pair that sees both groups ties them
    tracks = np.r_[tracks, np.arange(10), np.arange(100, 110)]
    who = np.r_[who, np.full(20, 2)]
    _check_linked(tracks, who, labels, pairs, SfmConfig())
