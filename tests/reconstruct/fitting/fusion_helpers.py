"""What the fusion tests share: hand-made piles sampled top-down (no stereo), their scan folders and
surveys, and small scan logs and survey ends."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from reconstruct.compare import compare_piles
from reconstruct.fitting.fuse import ScanLog, SurveyEnd
from reconstruct.survey.gnss import GnssPoint, GnssSurvey, write_gnss_csv
from reconstruct.registration import ScanPose, write_scan_pose
from synth.geometry import geodesy
from synth.scene.pile import PileSpec

ORIGIN = (64.1, 20.0, 250.0)


def scan_folder(d: Path, pile: PileSpec, pose_error=None) -> Path:
    """A scan folder holding what reconstruct() reads besides the cloud: one pair (its calibration
    carries a pose) and scan_pose.json (the scan frame is the pile frame, ``pose_error`` applied)."""
    import cv2

    from synth.geometry.calibration import write_calibration_yaml

    from synth.render.stereo import StereoRigConfig

    pair = d / "scan" / "pair_000"
    pair.mkdir(parents=True)
    for name in ("left.png", "right.png"):
        cv2.imwrite(str(pair / name), np.zeros((4, 4, 3), np.uint8))
    write_calibration_yaml(StereoRigConfig().calibration(), pair / "calibration.yaml")
    T = pile.georef.matrix() if pose_error is None else pose_error @ pile.georef.matrix()
    write_scan_pose(ScanPose(*ORIGIN, tuple(tuple(float(v) for v in r) for r in T)), d / "scan")
    return d / "scan"


def write_survey(pile: PileSpec, path: Path, spec: dict) -> Path:
    """A survey CSV of the pile's log ends: ``spec[(i, end)] = (fix, offset_site_m (3,), h_acc, v_acc)``;
    an end not in ``spec`` is RTK fixed with a small fixed offset; ``None`` leaves it out."""
    rng = np.random.default_rng(7)
    points = []
    for i, log in enumerate(pile.logs):
        for end, p in zip("ab", log.endpoints_m()):
            s = spec.get((i, end), ("rtk_fixed", rng.normal(0, [0.007, 0.007, 0.012]), 0.015, 0.025))
            if s is None:
                continue
            fix, offset, h_acc, v_acc = s
            site = geodesy.pile_to_site(pile.georef, p[None, :])[0] + np.asarray(offset, dtype=float)
            lat, lon, h = geodesy.site_to_geodetic(ORIGIN, site[None, :])
            points.append(GnssPoint(f"log{i}", end, float(lat[0]), float(lon[0]), float(h[0]), fix, h_acc, v_acc))
    return write_gnss_csv(GnssSurvey(tuple(points)), path)


def along_site(pile: PileSpec, i: int, metres: float, outward_end: str = "a") -> np.ndarray:
    """A site-frame offset of ``metres`` along log ``i``'s axis, out of its end ``outward_end``."""
    a, b = geodesy.pile_to_site(pile.georef, np.stack(pile.logs[i].endpoints_m()))
    u = (b - a) / np.linalg.norm(b - a)
    return (-u if outward_end == "a" else u) * metres


def end_errors(truth: PileSpec, recon: PileSpec) -> dict[int, float]:
    c = compare_piles(truth, recon, render=False)
    assert not c["unmatched_truth"], c["unmatched_truth"]
    return {e["truth_index"]: e["endpoint_max_err_m"] for e in c["logs"]}


def scan_log(x0, x1, y, z=0.08, r=0.08) -> ScanLog:
    return ScanLog(np.array([x0, y, z]), np.array([x1, y, z]), r, abs(x1 - x0), 20.0)


def survey_end(x, y, z=0.08, fix="rtk_float") -> SurveyEnd:
    s = (0.25, 0.40) if fix == "rtk_float" else (0.015, 0.025)
    return SurveyEnd(np.array([x, y, z]), s[0] / math.sqrt(2), s[1], fix)


def slanted_scan_log(p0, p1, r=0.08, seen=None) -> ScanLog:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    return ScanLog(p0, p1, r, float(np.linalg.norm(p1[:2] - p0[:2])) if seen is None else seen, 20.0)
