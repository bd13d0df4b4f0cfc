"""A fixed point is evidence (issue 37): a log that leaves the scan keeps its correct RTK fixed end, and a wrong
point there is still named. A twin scan (`loggrasp synth scan`: rendered pairs, stereo matching, RTK noise) whose
cloud is cut 1.2 m short of one log's end, across that log, as where a scan's footprint stops on a pile wider
than it: the end lies more than ``max_endpoint_distance_m`` from every scan point, its log runs 1.2 m into the
scan. Each case runs with every estimator."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from reconstruct.compare import compare_piles
from reconstruct.config import ReconstructConfig
from reconstruct.fitting.coverage import CoverageConfig
from reconstruct.errors import RegistrationError
from reconstruct.pipeline import reconstruct
from reconstruct.scan.stereo import ScanCloud
from reconstruct.survey.gnss import GnssSurvey, read_gnss, write_gnss_csv
from synth.geometry import geodesy
from synth.scene.pile import read_pile

SEED = 3_390_017  # no bench's seed (tuning 1,100,000+, held-out 3,300,000..3,300,599, final 5,500,000+)
CUT_M = 1.2  # the cloud stops this far short of the cut log's end, along it [m]
LOG, END = 3, "a"  # the log whose end is cut off: the pile's outermost end along that log
MAX_END_ERR_M = 0.05  # every log within this of the truth [m]
ESTIMATORS = ("rules22", "joint")


@pytest.fixture(scope="module")
def cut_scan(tmp_path_factory):
    """The scan folder, its all-fixed survey, its cloud cut across log 3 1.2 m short of its end a, and the truth."""
    from reconstruct.scan.stereo import scan_cloud
    from reconstruct.scan.twin_scan import make_twin_scan, write_twin_survey

    root = make_twin_scan(tmp_path_factory.mktemp("outside") / "scan", SEED, logs=(4, 4), obstacles=(0, 0),
                          n_float=0)
    survey = read_gnss(write_twin_survey(root, root / "gnss_fixed.csv", n_float=0))
    truth = read_pile(root / "truth" / "pile.json")
    cloud = scan_cloud(root / "scan")
    a, b = (np.asarray(e) for e in truth.logs[LOG].endpoints_m())
    u = (a - b)[:2] / np.linalg.norm((a - b)[:2])
    keep = cloud.points[:, :2] @ u < a[:2] @ u - CUT_M  # the scan frame is the pile frame (to a few cm)
    cut = ScanCloud(cloud.points[keep], cloud.colours[keep], camera_positions=cloud.camera_positions)
    return root, survey, cut, truth


def _run(cut_scan, tmp_path, survey: GnssSurvey, estimator: str, **overrides):
    root, _, cloud, truth = cut_scan
    path = write_gnss_csv(survey, tmp_path / "survey.csv")
    cfg = ReconstructConfig(**({} if estimator == "rules22" else {"estimator": estimator}), **overrides)
    res = reconstruct(root / "scan", path, tmp_path / "out", cfg, cloud=cloud)
    named = {tuple(re.match(r"(\S+) end ([ab]) ", line).groups()) for line in res.report["contradicted_points"]}
    return res, compare_piles(truth, res.pile, render=False), named


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_a_correct_fixed_end_outside_the_scan_is_kept(cut_scan, tmp_path, estimator):
    res, cmp, named = _run(cut_scan, tmp_path, cut_scan[1], estimator)
    outside = {(o["log_id"], o["end"]): o for o in res.report["ends_outside_scan"]}
    assert (f"log{LOG}", END) in outside
    assert outside[(f"log{LOG}", END)]["distance_m"] > ReconstructConfig().max_endpoint_distance_m
    assert outside[(f"log{LOG}", END)]["seen_length_m"] >= CoverageConfig().seen_log_min_length_m
    assert any(w.startswith(f"log{LOG} end {END} lies ") for w in res.report["survey_warnings"])
    assert named == set()  # no correct fixed point called wrong
    assert not cmp["unmatched_truth"] and not cmp["unmatched_recon"]
    worst = {e["truth_index"]: round(e["endpoint_max_err_m"], 3) for e in cmp["logs"]}
    assert max(worst.values()) < MAX_END_ERR_M, worst


def test_without_the_seen_log_the_same_end_is_refused(cut_scan, tmp_path):
    """The check before: every end within the limit of the scan, whatever its log (no log is long enough)."""
    with pytest.raises(RegistrationError, match=f"log 'log{LOG}' end '{END}'.*outside the scanned area"):
        _run(cut_scan, tmp_path, cut_scan[1], "rules22", coverage=CoverageConfig(seen_log_min_length_m=100.0))


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_a_wrong_point_outside_the_scan_is_still_named(cut_scan, tmp_path, estimator):
    """The outside end measured 30 cm off across its log: named, every other log where it lies."""
    root, survey, cloud, truth = cut_scan
    a, b = (np.asarray(e) for e in truth.logs[LOG].endpoints_m())
    u = (a - b) / np.linalg.norm(a - b)
    across = np.array([-u[1], u[0], 0.0]) / np.hypot(u[0], u[1])

    def moved(p):
        x = geodesy.geodetic_to_pile(truth.georef, p.lat_deg, p.lon_deg, p.h_ell_m).reshape(3) + 0.30 * across
        lat, lon, h = geodesy.pile_to_geodetic(truth.georef, x[None, :])
        return replace(p, lat_deg=float(lat[0]), lon_deg=float(lon[0]), h_ell_m=float(h[0]))

    wrong = GnssSurvey(tuple(moved(p) if (p.log_id, p.end) == (f"log{LOG}", END) else p for p in survey.points))
    res, cmp, named = _run(cut_scan, tmp_path, wrong, estimator)
    assert named == {(f"log{LOG}", END)}
    worst = {e["truth_index"]: round(e["endpoint_max_err_m"], 3) for e in cmp["logs"] if e["truth_index"] != LOG}
    assert max(worst.values()) < MAX_END_ERR_M, worst
