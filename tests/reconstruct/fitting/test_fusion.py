"""reconstruct.fitting.fuse and the pipeline under real survey conditions: float points, logs or ends not
surveyed, points the scan contradicts, and geometry the survey cannot settle. The scans are exact
top-view samples of hand-made piles (no stereo), so these run in seconds."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from reconstruct.compare import compare_piles
from reconstruct.errors import GnssQualityError
from reconstruct.fitting.fit import sample_top_view_points
from reconstruct.fitting.fuse import (
    AmbiguousSurveyError, EndEstimate, EndInterval, FuseConfig, Match, ScanLog, SurveyEnd, a_piece_of_a_surveyed_log,
    absorb_pieces, after_pile_check, fuse_end, match_survey,
    scan_end_interval, seen_end,
)
from reconstruct.survey.gnss import GnssPoint, GnssSurvey, write_gnss_csv
from reconstruct.config import ReconstructConfig
from reconstruct.pipeline import reconstruct
from reconstruct.registration import ScanPose, write_scan_pose
from reconstruct.scan.stereo import ScanCloud
from synth.geometry import geodesy
from synth.geometry.frames import make_T, rot_z
from synth.scene.pile import Georeference, LogSpec, PileSpec, TerrainSpec

ORIGIN = (64.1, 20.0, 250.0)


@pytest.fixture(scope="module")
def pile() -> PileSpec:
    """Four logs on flat ground: two side by side, one across both, one apart."""
    terrain = TerrainSpec(extent_m=5.0, resolution=32, amplitude_m=0.0,
                          heights_m=tuple(tuple(0.0 for _ in range(32)) for _ in range(32)))
    logs = (
        LogSpec.from_endpoints((-1.0, -0.5, 0.08), (1.0, -0.5, 0.08), 0.16),
        LogSpec.from_endpoints((-0.9, 0.35, 0.07), (1.1, 0.2, 0.07), 0.14),
        LogSpec.from_endpoints((-0.55, -1.1, 0.23), (-0.35, 0.95, 0.21), 0.14),  # across both
        LogSpec.from_endpoints((0.2, 1.0, 0.075), (1.9, 1.45, 0.075), 0.15),
    )
    T = make_T(rot_z(math.radians(25.0)), (3.0, -2.0, 0.0))
    return PileSpec(terrain=terrain, logs=logs,
                    georef=Georeference(*ORIGIN, T_site_pile=tuple(tuple(float(v) for v in r) for r in T)))


@pytest.fixture(scope="module")
def cloud(pile) -> ScanCloud:
    pts = sample_top_view_points(pile, 500, 0.003, np.random.default_rng(1))
    return ScanCloud(pts, np.full((len(pts), 3), 0.5, np.float32), camera_positions=np.array([[0.0, 0.0, 3.0]]))


def _scan_folder(d: Path, pile: PileSpec, pose_error=None) -> Path:
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


def _survey(pile: PileSpec, path: Path, spec: dict) -> Path:
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


def _along_site(pile: PileSpec, i: int, metres: float, outward_end: str = "a") -> np.ndarray:
    """A site-frame offset of ``metres`` along log ``i``'s axis, out of its end ``outward_end``."""
    a, b = geodesy.pile_to_site(pile.georef, np.stack(pile.logs[i].endpoints_m()))
    u = (b - a) / np.linalg.norm(b - a)
    return (-u if outward_end == "a" else u) * metres


def _errors(truth: PileSpec, recon: PileSpec) -> dict[int, float]:
    c = compare_piles(truth, recon, render=False)
    assert not c["unmatched_truth"], c["unmatched_truth"]
    return {e["truth_index"]: e["endpoint_max_err_m"] for e in c["logs"]}


def test_float_points_a_log_without_points_and_a_missing_end(pile, cloud, tmp_path):
    scan = _scan_folder(tmp_path, pile)
    gnss = _survey(pile, tmp_path / "survey.csv", {
        (0, "b"): ("rtk_float", (0.20, -0.15, 0.35), 0.25, 0.40),  # seen by the scan: as good as fixed
        (1, "a"): None, (1, "b"): None,  # not surveyed at all
        (2, "b"): None,  # one end measured
        (3, "a"): ("rtk_float", (-0.18, 0.12, -0.30), 0.25, 0.40),
        (3, "b"): ("rtk_float", (0.15, 0.20, 0.25), 0.25, 0.40),
    })
    with pytest.raises(GnssQualityError, match="--allow-float"):  # float points stay an explicit choice
        reconstruct(scan, gnss, tmp_path / "refused", ReconstructConfig(), cloud=cloud)
    res = reconstruct(scan, gnss, tmp_path / "out", ReconstructConfig(allow_float=True), cloud=cloud)
    rep = res.report
    assert res.pile.n_logs == 4
    err = _errors(pile, res.pile)
    assert max(err.values()) < 0.04, err
    ends = {lf["log_id"]: lf["ends"] for lf in rep["logs"]}
    assert ends["log0"][1]["source"] == "scan" and ends["log0"][1]["gnss_fix"] == "rtk_float"
    assert ends["log0"][1]["sigma_m"] < 0.03  # a float point inside the scan: as good as a fixed one
    assert [e["source"] for e in ends["log3"]] == ["scan", "scan"]
    assert ends["log2"][1]["gnss_fix"] is None and ends["log2"][1]["source"] in ("scan", "inferred")
    assert list(rep["fusion"]["new_logs"]) == ["scan0"]  # log1, found in the scan alone
    assert [e["source"] for e in ends["scan0"]] == ["scan", "scan"]
    assert rep["weak_ends"] == [] and rep["contradicted_points"] == []
    assert any("one end measured" in w for w in rep["survey_warnings"])


def test_points_the_scan_contradicts_are_reported_and_do_not_drag_the_scan(pile, cloud, tmp_path):
    err_T = make_T(rot_z(math.radians(0.5)), (0.03, -0.02, 0.01))
    scan = _scan_folder(tmp_path, pile, pose_error=err_T)
    lateral = geodesy.pile_to_site(pile.georef, np.array([[0.0, 0.2, 0.0]]))[0] - \
        geodesy.pile_to_site(pile.georef, np.zeros((1, 3)))[0]
    gnss = _survey(pile, tmp_path / "survey.csv", {
        (0, "a"): ("rtk_fixed", _along_site(pile, 0, 0.25, "a"), 0.015, 0.025),  # 25 cm past a seen end
        (1, "b"): ("rtk_fixed", lateral, 0.015, 0.025),  # 20 cm beside its log: a wrong point
    })
    res = reconstruct(scan, gnss, tmp_path / "out", ReconstructConfig(), cloud=cloud)
    rep = res.report
    err = _errors(pile, res.pile)
    assert max(err.values()) < 0.035, err  # placed where the scan shows them, the scan pose corrected
    outliers = {(o["log_id"], o["end"]) for o in rep["registration"]["outliers"]}
    assert ("log1", "b") in outliers
    assert rep["registration"]["weights"]["log1.b"] < 0.1
    bad = {(lf["log_id"], end) for lf in rep["logs"] for end, e in zip("ab", lf["ends"]) if e["contradicted"]}
    assert bad == {("log0", "a"), ("log1", "b")}
    assert len(rep["contradicted_points"]) == 2 and "log0 end a (rtk_fixed)" in rep["contradicted_points"][0]


def _scan_log(x0, x1, y, z=0.08, r=0.08) -> ScanLog:
    return ScanLog(np.array([x0, y, z]), np.array([x1, y, z]), r, abs(x1 - x0), 20.0)


def _end(x, y, z=0.08, fix="rtk_float") -> SurveyEnd:
    s = (0.25, 0.40) if fix == "rtk_float" else (0.015, 0.025)
    return SurveyEnd(np.array([x, y, z]), s[0] / math.sqrt(2), s[1], fix)


def test_only_geometry_the_survey_cannot_settle_stops_and_names_the_log():
    # two short pieces of logs mostly hidden, 30 cm apart: a surveyed log with float ends between them
    # could be either, and the piles differ (the other piece is dropped: too short to stand alone)
    scan_logs = [_scan_log(-0.3, 0.3, 0.0), _scan_log(-0.3, 0.3, 0.3)]
    floating = {"log7": (_end(-1.0, 0.15), _end(1.0, 0.15))}
    with pytest.raises(AmbiguousSurveyError, match=r"log 'log7'.*Re-measure log 'log7'"):
        match_survey(floating, scan_logs)
    # fixed points settle it
    fixed = {"log7": (_end(-1.0, 0.0, fix="rtk_fixed"), _end(1.0, 0.01, fix="rtk_fixed"))}
    matches, unmatched = match_survey(fixed, scan_logs)
    assert matches["log7"].scan_index == 0 and unmatched == [1]
    # two whole logs either of which the float log could be: the same pile either way, no error
    two = [_scan_log(-1.0, 1.0, 0.0), _scan_log(-1.0, 1.0, 0.3)]
    matches, unmatched = match_survey(floating, two)
    assert matches["log7"].scan_index in (0, 1) and len(unmatched) == 1
    # one log seen in two short pieces (something lies over its middle), its ends fixed: either piece
    # is the same log, no error (twin scan 1100017 stopped here)
    pieces = [_scan_log(-1.0, -0.4, 0.0), _scan_log(0.7, 1.0, 0.005)]
    whole = {"log7": (_end(-1.0, 0.0, fix="rtk_fixed"), _end(1.0, 0.0, fix="rtk_fixed"))}
    matches, unmatched = match_survey(whole, pieces)
    assert matches["log7"].scan_index in (0, 1)
    assert absorb_pieces(matches, unmatched, pieces) == []


def test_a_sloped_ridge_on_a_logs_fixed_line_is_that_log_not_an_ambiguity():
    """Both ends RTK fixed; the scan shows a ridge on their line whose fitted height slopes through
    theirs (each point ~3.8 sigma off it): "hidden, and that ridge another log" is within the chi2
    margin, but it would put two logs in one place (twin scan 1100133 stopped here under all three
    surveys; with the match taken, every log of it lands within 3.3 cm). A ridge as far ABOVE the
    line all along may be a log lying on it: still an ambiguity."""
    fixed = {"log0": (_end(-1.0, 0.0, fix="rtk_fixed"), _end(1.0, 0.0, fix="rtk_fixed"))}
    sloped = ScanLog(np.array([-0.8, 0.0, -0.13]), np.array([0.8, 0.02, 0.29]), 0.08, 1.6, 20.0)
    matches, unmatched = match_survey(fixed, [sloped])
    assert matches["log0"].scan_index == 0 and unmatched == []
    above = ScanLog(np.array([-0.8, 0.0, 0.29]), np.array([0.8, 0.02, 0.29]), 0.08, 1.6, 20.0)
    with pytest.raises(AmbiguousSurveyError, match="being hidden"):
        match_survey(fixed, [above])


def test_an_end_is_placed_from_what_knows_it_best():
    cfg = FuseConfig()
    p0, u = np.zeros(3), np.array([1.0, 0.0, 0.0])
    seen = EndInterval(2.00, 2.02, "seen")  # the scan sees the end at 2.00 m (the last bin on its top)
    near = _end(2.15, 0.1)  # float, 15 cm off along: consistent
    e = fuse_end(p0, u, seen, False, near, 0.005, cfg)
    assert e.source == "scan" and not e.contradicted and abs(e.position_m[0] - 2.00) < 0.005
    assert e.sigma_along_m < cfg.scan_end_sigma_m
    far = _end(2.20, 0.0, fix="rtk_fixed")  # fixed, 19 cm off: the scan contradicts it
    e = fuse_end(p0, u, seen, False, far, 0.005, cfg)
    assert e.contradicted and e.source == "scan" and abs(e.position_m[0] - 2.00) < 1e-9
    agree = _end(2.02, 0.0, fix="rtk_fixed")
    e = fuse_end(p0, u, seen, False, agree, 0.005, cfg)
    assert e.source == "fixed" and 2.00 < e.position_m[0] < 2.02
    under = EndInterval(2.00, 2.30, "occluded")  # a log lies over its end: somewhere in 2.0-2.3 m
    e = fuse_end(p0, u, under, False, _end(2.21, 0.0), 0.005, cfg)
    assert e.source == "float" and abs(e.position_m[0] - 2.21) < 1e-9 and e.sigma_along_m < 0.09
    e = fuse_end(p0, u, under, False, None, 0.005, cfg)
    assert e.source == "inferred" and abs(e.position_m[0] - 2.15) < 1e-9
    e = fuse_end(p0, u, EndInterval(2.0, None, "open"), False, None, 0.005, cfg)  # the scan stops
    assert e.source == "inferred" and e.weak(cfg)
    e = fuse_end(p0, u, EndInterval(0.02, 0.0, "seen"), True, None, 0.005, cfg)  # end a, toward -t
    assert e.source == "scan" and abs(e.position_m[0] - 0.02) < 1e-9
    # a log the scan shows only in part may run on under others past where its top seems to stop: a
    # fixed point beyond a seen end places it there; one short of it is still contradicted
    beyond = _end(2.60, 0.0, fix="rtk_fixed")
    e = fuse_end(p0, u, seen, False, beyond, 0.04, cfg, seen_whole=False)
    assert e.source == "fixed" and not e.contradicted and abs(e.position_m[0] - 2.60) < 1e-9
    assert fuse_end(p0, u, seen, False, beyond, 0.005, cfg).contradicted  # a log seen whole: the scan's end
    short = _end(1.60, 0.0, fix="rtk_fixed")
    assert fuse_end(p0, u, seen, False, short, 0.04, cfg, seen_whole=False).contradicted


def test_an_end_the_scan_shows_nothing_of_goes_to_its_point_by_their_accuracies():
    """Where the scan shows none of a log's top near an end, the survey point places it along the axis
    AND across it by the two accuracies, and is tested like any other (twin scan 1100133: a log seen
    over a third of its length, its fitted axis 9 deg off, came back with an end 40 cm above its RTK
    fixed point, the 'fixed' end left on the extrapolated axis and not reported)."""
    cfg = FuseConfig()
    p0, u = np.zeros(3), np.array([1.0, 0.0, 0.0])
    nothing = EndInterval(None, None, "none")
    below = _end(2.0, 0.0, z=-0.40, fix="rtk_fixed")  # 40 cm below the (partial) fit's axis
    e = fuse_end(p0, u, nothing, False, below, 0.04, cfg, seen_whole=False)
    assert e.source == "fixed" and abs(e.position_m[2] + 0.40) < 0.05, e.position_m  # at the point, not on the axis
    assert not e.contradicted and e.gnss_residual_m < 0.05
    # an axis the scan fixes to millimetres is not pulled; a fixed point 40 cm off it is reported
    e = fuse_end(p0, u, nothing, False, below, 0.005, cfg)
    assert abs(e.position_m[2]) < 1e-9 and e.contradicted and e.weak(cfg)


def test_a_seen_end_is_where_the_log_ends_not_a_bin_past_it():
    """A log's top sampled densely up to its end face, the ground beyond it, the end at every offset
    within a walk bin: the seen end is unbiased (it was the last bin's outer edge: +1 cm on average)."""
    cfg = FuseConfig()
    rng = np.random.default_rng(5)
    r, errors = 0.08, []
    for end in np.linspace(2.0, 2.0 + cfg.end_bin_m, 11, endpoint=False):
        x = rng.uniform(0.0, 3.0, 40000)
        y = rng.uniform(-r, r, x.size)
        z = np.where(x <= end, r + np.sqrt(np.clip(r * r - y * y, 0, None)), 0.0)  # log top, then the ground
        P = np.column_stack([x, y, z + rng.normal(0, 0.002, x.size)])
        p0, p1 = np.array([0.0, 0.0, r]), np.array([end, 0.0, r])
        iv = scan_end_interval(P, p0, p1, r, toward_p1=True, reach_m=0.5, cfg=cfg)
        assert iv.state == "seen"
        errors.append(seen_end(iv) - end)
    assert abs(float(np.mean(errors))) < 0.003, errors
    assert max(abs(e) for e in errors) <= 0.5 * cfg.end_bin_m + 1e-9, errors


def test_float_points_count_by_their_accuracy_in_the_registration(pile, cloud, tmp_path):
    # the scan pose is right; five float points share a 10 cm error (well within their 25 cm), three
    # fixed points are right: weighted by accuracy, the float points do not move the scan (weighted as
    # fixed ones, they drag it about a centimetre)
    scan = _scan_folder(tmp_path, pile)
    bias = (0.08, 0.06, 0.0)
    floats = {(i, end): ("rtk_float", bias, 0.25, 0.40) for i, end in ((1, "b"), (2, "a"), (2, "b"), (3, "a"), (3, "b"))}
    exact = {(i, end): ("rtk_fixed", (0.0, 0.0, 0.0), 0.015, 0.025) for i, end in ((0, "a"), (0, "b"), (1, "a"))}
    gnss = _survey(pile, tmp_path / "survey.csv", floats | exact)
    res = reconstruct(scan, gnss, tmp_path / "out", ReconstructConfig(allow_float=True), cloud=cloud)
    reg = res.report["registration"]
    assert reg["end_points_used"] == 8 and reg["end_points_precise"] == 3
    assert reg["correction_m"] < 0.004, reg
    assert max(_errors(pile, res.pile).values()) < 0.03


def _slanted_scan_log(p0, p1, r=0.08, seen=None) -> ScanLog:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    return ScanLog(p0, p1, r, float(np.linalg.norm(p1[:2] - p0[:2])) if seen is None else seen, 20.0)


def test_a_fixed_log_is_not_ambiguous_with_a_scrap_that_needs_one_of_its_points_wrong():
    # twin scan 1100039: the ridge of a log runs 0.5 m on past its end b over the touching neighbour's end,
    # so its fixed point b lies inside the ridge (chi2 ~13); a 15 cm scrap of ridge at b, across the log,
    # explains b and calls a wrong (gate + 1 = 17). The chi2 margin is for noise: no ambiguity, and the
    # log is the long one
    scan_logs = [_scan_log(-1.0, 1.5, 0.0), _slanted_scan_log((1.0, 0.01, 0.08), (1.2, 0.25, 0.08), seen=0.15)]
    survey = {"log4": (_end(-1.0, 0.0, fix="rtk_fixed"), _end(1.0, 0.0, fix="rtk_fixed"))}
    matches, unmatched = match_survey(survey, scan_logs)
    assert matches["log4"].scan_index == 0 and unmatched == [1]
    assert "scan log 1" in matches["log4"].alternative  # the scrap was the next best, within chi2 4
    assert float(matches["log4"].alternative.split("+")[1].rstrip(")")) < FuseConfig().ambiguity_chi2


def test_a_ridge_running_on_past_a_fixed_end_is_the_log_not_a_scrap_beside_that_end():
    """Twin scan 1100166, degraded survey: a log's ridge runs 0.76 m on past its fixed end b, onto a stump;
    a 35 cm scrap beside b (the stump's edge) explained b and let the float a lie on its line far off.
    The ridge, with b well inside it, is as costly as a wrong point but calls none wrong: the two are as
    good, and the ridge, which would otherwise stand as a log the survey missed, is the log's."""
    ridge = _slanted_scan_log((-1.0, 0.0, 0.08), (1.8, 0.0, 0.08))
    scrap = _slanted_scan_log((0.80, 0.17, 0.08), (1.15, 0.17, 0.08), seen=0.35)
    other = _scan_log(-1.0, 1.0, 1.0)
    survey = {"log2": (_end(-1.05, 0.05), _end(1.0, 0.0, fix="rtk_fixed")),
              "log1": (_end(-1.0, 1.0, fix="rtk_fixed"), _end(1.0, 1.0, fix="rtk_fixed"))}
    matches, unmatched = match_survey(survey, [ridge, scrap, other])
    assert matches["log2"].scan_index == 0 and unmatched == [1]
    assert "scan log 1 (chi2 -" in matches["log2"].alternative  # the scrap alone explains the points better


def test_of_two_logs_side_by_side_the_one_with_a_float_point_takes_the_ridge():
    """Twin scans 700074, 700114: two surveyed logs side by side, the scan showing one ridge between them;
    either could be the hidden one, about equally well (chi2 2.1-2.3). Hidden, a log is placed from its
    points: the one with both RTK fixed is, and the one with a float point takes the ridge. Where both
    have a float point, which is hidden is still the ambiguity it was."""
    ridge = [_scan_log(-1.0, 1.0, 0.10)]
    survey = {"logA": (_end(-1.0, 0.03, fix="rtk_fixed"), _end(1.0, 0.03, fix="rtk_fixed")),
              "logB": (_end(-1.0, 0.17), _end(1.0, 0.17, fix="rtk_fixed"))}
    matches, _ = match_survey(survey, ridge)
    assert matches["logB"].scan_index == 0 and matches["logA"].scan_index is None
    survey["logA"] = (_end(-1.0, 0.03), _end(1.0, 0.03, fix="rtk_fixed"))
    with pytest.raises(AmbiguousSurveyError):
        match_survey(survey, ridge)


def test_an_ambiguity_between_fixed_points_does_not_ask_for_a_fixed_solution():
    # two parallel pieces of logs 6 cm apart, each seen only in the middle; fixed points half-way
    # between: either piece, and the piles differ (the other one dropped). Measuring the points
    # RTK fixed again settles nothing: the message says to check them and survey the neighbours
    scan_logs = [_scan_log(-0.35, 0.35, 0.0), _scan_log(-0.3, 0.3, 0.06)]
    survey = {"log2": (_end(-1.0, 0.03, fix="rtk_fixed"), _end(1.0, 0.03, fix="rtk_fixed"))}
    with pytest.raises(AmbiguousSurveyError) as err:
        match_survey(survey, scan_logs)
    msg = str(err.value)
    assert "log 'log2'" in msg and "RTK fixed solution" not in msg
    assert "Check that log 'log2''s points were taken at its end centres" in msg
    # with one float point, that one point is named to re-measure
    survey = {"log2": (_end(-1.0, 0.03, fix="rtk_fixed"), _end(1.0, 0.03))}
    with pytest.raises(AmbiguousSurveyError, match=r"Re-measure log 'log2''s end b with an RTK fixed solution"):
        match_survey(survey, scan_logs)


def test_a_neighbours_top_against_a_logs_end_is_not_that_log(tmp_path):
    # log 0 ends against the side of log 1, a thinner one lying across it; stereo smears log 1's top
    # 2.5 cm up there, to log 0's top height. Those points lie farther from log 1's fitted surface than
    # the fit's own 1.5 cm band: walked as log 0's, they ran its end on over log 1 and against its fixed
    # point (twin scan 1100021: 0.5 m past its end, the pile then failed its check)
    terrain = TerrainSpec(extent_m=5.0, resolution=32, amplitude_m=0.0,
                          heights_m=tuple(tuple(0.0 for _ in range(32)) for _ in range(32)))
    r1 = 0.0675
    x1 = 0.5 + r1 + 0.01
    logs = (LogSpec.from_endpoints((-1.0, 0.0, 0.08), (0.5, 0.0, 0.08), 0.16),
            LogSpec.from_endpoints((x1, -0.8, r1), (x1, 0.8, r1), 2 * r1),
            LogSpec.from_endpoints((-1.0, 0.6, 0.075), (0.3, 0.9, 0.075), 0.15))
    pile = PileSpec(terrain=terrain, logs=logs, georef=Georeference(
        *ORIGIN, T_site_pile=tuple(tuple(float(v) for v in r) for r in make_T(rot_z(0.4), (1.0, 2.0, 0.0)))))
    pts = sample_top_view_points(pile, 500, 0.003, np.random.default_rng(3))
    gx, gy = np.meshgrid(np.arange(x1 - 0.045, x1 + 0.046, 0.01), np.arange(-0.06, 0.061, 0.01))
    smear = np.column_stack([gx.ravel(), gy.ravel(), r1 + np.sqrt(r1 ** 2 - (gx.ravel() - x1) ** 2) + 0.025])
    pts = np.vstack([pts, smear])
    cloud = ScanCloud(pts, np.full((len(pts), 3), 0.5, np.float32), camera_positions=np.array([[0.0, 0.0, 3.0]]))
    scan = _scan_folder(tmp_path, pile)
    gnss = _survey(pile, tmp_path / "survey.csv", {})
    res = reconstruct(scan, gnss, tmp_path / "out", ReconstructConfig(), cloud=cloud)
    err = _errors(pile, res.pile)
    assert err[0] < 0.03, err
    end_b = next(lf for lf in res.report["logs"] if lf["log_id"] == "log0")["ends"][1]
    assert not end_b["contradicted"] and end_b["source"] in ("fixed", "scan"), end_b


def test_on_a_log_seen_in_part_a_fixed_point_beyond_a_covered_end_stands():
    # twin scan 1100028: on logs seen only in part (axis from the survey, radius from a piece of top, 5 cm
    # too large), the scan seemed to see below the top past a covered end; the RTK fixed points 41-48 cm
    # farther out were called contradicted and the ends put in the interval's middle
    cfg = FuseConfig()
    p0, u = np.zeros(3), np.array([1.0, 0.0, 0.0])
    covered = EndInterval(1.50, 1.70, "occluded")
    fixed = _end(2.10, 0.0, fix="rtk_fixed")
    e = fuse_end(p0, u, covered, False, fixed, 0.04, cfg, seen_whole=False)
    assert e.source == "fixed" and not e.contradicted and abs(e.position_m[0] - 2.10) < 0.005
    # and from inside an open end: the log's visible top there may be another's
    e = fuse_end(p0, u, EndInterval(2.40, None, "open"), False, fixed, 0.04, cfg, seen_whole=False)
    assert e.source == "fixed" and abs(e.position_m[0] - 2.10) < 0.005
    # a float point there is still held to the scan's bounds, and on a log seen whole the scan decides
    e = fuse_end(p0, u, covered, False, _end(2.10, 0.0), 0.04, cfg, seen_whole=False)
    assert e.source == "float" and 1.5 <= e.position_m[0] <= 1.7
    e = fuse_end(p0, u, covered, False, fixed, 0.005, cfg, seen_whole=True)
    assert e.contradicted and e.source == "inferred"


def test_a_neighbours_points_show_where_a_log_is_not_but_never_its_top():
    # a log (axis z 0, r 8 cm) along x in [0, 1]; past its end a touching neighbour's surface, either 8 cm
    # lower (the scan sees below this log's top: its end is seen) or at its top's height (not this log's
    # top: the end does not run on over it). The neighbour's points are marked not to show the top. At
    # fitting revision 8 they were dropped from the walk: the end where a log touched a lower neighbour
    # was no longer seen (twin scans 1100001, 1100009 degraded: 10.8 and 15.5 cm off)
    rng = np.random.default_rng(0)
    x = rng.uniform(0.0, 1.0, 3000)
    own = np.column_stack([x, rng.uniform(-0.03, 0.03, x.size), np.full(x.size, 0.08)])
    xn = rng.uniform(1.0, 1.3, 900)
    for z_nb, state in ((0.0, "seen"), (0.08, "open")):
        nb = np.column_stack([xn, rng.uniform(-0.03, 0.03, xn.size), np.full(xn.size, z_nb)])
        pts = np.vstack([own, nb])
        mask = np.r_[np.ones(len(own), bool), np.zeros(len(nb), bool)]
        iv = scan_end_interval(pts, np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.08, True, 0.6, on_mask=mask)
        assert iv.state == state and abs(iv.last_on_m - 1.0) < 0.03, (z_nb, iv)
        if state == "seen":
            assert abs(iv.first_off_m - 1.0) < 0.03
        # without the mask the neighbour at the top's height would pass for the log
        if z_nb == 0.08:
            iv = scan_end_interval(pts, np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.08, True, 0.6)
            assert iv.last_on_m > 1.2
    # fit_pile hands place_ends the neighbours' points too, marked
    got = {}

    def place_ends(log_id, spec, how, points, swapped, on_mask):
        got[log_id] = (len(points), int((~on_mask).sum()))
        return spec, ({"source": "scan"}, {"source": "scan"})

    from reconstruct.fitting.fit import FitConfig, fit_pile
    terrain = TerrainSpec(extent_m=5.0, resolution=32, amplitude_m=0.0,
                          heights_m=tuple(tuple(0.0 for _ in range(32)) for _ in range(32)))
    logs = (LogSpec.from_endpoints((-1.0, 0.0, 0.08), (0.5, 0.0, 0.08), 0.16),
            LogSpec.from_endpoints((0.63, -0.8, 0.0675), (0.63, 0.8, 0.0675), 0.135))
    pts = sample_top_view_points(PileSpec(terrain=terrain, logs=logs), 400, 0.01, np.random.default_rng(2))
    survey = {f"log{i}": tuple(np.asarray(p) for p in lg.endpoints_m()) for i, lg in enumerate(logs)}
    fit_pile(pts, survey, 5.0, FitConfig(validate=False), place_ends=place_ends)
    assert got["log0"][1] > 0  # points 1.5-3 cm from log1's surface: passed, not as log0's top


# -- the ends after the pile check ----------------------------------------------------------------
def _placed(pos, sigma=0.005, fix="rtk_fixed", residual=0.0) -> dict:
    return {"position_m": list(pos), "sigma_m": sigma, "sigma_along_m": sigma, "source": "scan", "scan": "seen",
            "gnss_fix": fix, "gnss_residual_m": residual, "gnss_residual_sigma": 0.0, "contradicted": False,
            "gnss_axis_distance_m": 0.0}


def _fixed_point(pos) -> SurveyEnd:
    return SurveyEnd(np.asarray(pos, dtype=float), 0.01, 0.015, "rtk_fixed")


def test_an_end_the_pile_check_left_alone_is_unchanged():
    ends = [_placed((-1.0, 0.0, 0.1)), _placed((1.0, 0.0, 0.1))]
    out = after_pile_check(ends, (np.array([-1.0, 0.0, 0.1]), np.array([1.0, 0.0, 0.1])),
                           (_fixed_point((-1.0, 0.0, 0.1)), None))
    assert out == ends


def test_an_end_moved_by_the_pile_check_is_where_the_log_is_and_as_unsure_as_the_move():
    ends = [_placed((-1.0, 0.0, 0.1)), _placed((1.0, 0.0, 0.1))]
    lifted = (np.array([1.0, 0.0, 0.16]), np.array([-1.0, 0.0, 0.16]))  # 6 cm up, butt/top either way round
    out = after_pile_check(ends, lifted, (_fixed_point((-1.0, 0.0, 0.1)), None))
    assert out[0]["position_m"] == [-1.0, 0.0, 0.16] and out[1]["position_m"] == [1.0, 0.0, 0.16]
    assert abs(out[0]["sigma_m"] - math.hypot(0.005, 0.06)) < 1e-9 and out[0]["check_shift_m"] == pytest.approx(0.06)
    assert EndEstimate(np.zeros(3), out[1]["sigma_m"], 0.0, "scan", "seen").weak()  # a 6 cm push: a weak end
    assert out[0]["gnss_residual_m"] == pytest.approx(0.06) and out[0]["gnss_axis_distance_m"] == pytest.approx(0.06)
    assert not out[0]["contradicted"]  # 6 cm from a fixed point: 2.8 sigma


def test_a_check_that_pushes_an_end_off_its_fixed_point_contradicts_it():
    """An end placed 6 cm from its RTK fixed point (2.8 sigma: it stands) that the check pushes 6 cm
    farther is 12 cm off (5.7 sigma, with the estimate's own sigma): reported, never silent (twin scan
    1100133: a log seen in part, lifted past its fixed points by the check, came back 40 cm off)."""
    ends = [_placed((-1.0, 0.0, 0.1), residual=0.06), _placed((1.0, 0.0, 0.1))]
    point = _fixed_point((-1.0, 0.0, 0.04))
    out = after_pile_check(ends, (np.array([-1.0, 0.0, 0.16]), np.array([1.0, 0.0, 0.16])), (point, None))
    assert out[0]["contradicted"] and out[0]["gnss_residual_m"] == pytest.approx(0.12)
    float_point = SurveyEnd(np.array([-1.0, 0.0, 0.04]), 0.18, 0.4, "rtk_float")  # as far, but float: it stands
    assert not after_pile_check(ends, (np.array([-1.0, 0.0, 0.16]), np.array([1.0, 0.0, 0.16])),
                                (float_point, None))[0]["contradicted"]


def test_a_log_the_pile_check_pushes_far_is_reported_weak_where_it_lies(pile, cloud, tmp_path, monkeypatch):
    """The reconstruction's report shows each end where the checked pile has it, and names a log the
    check had to move 7 cm as resting on weak estimates (here the check's move is planted: the wiring is
    what is tested; the move rules are in test_fit.py)."""
    import reconstruct.fitting.fit as fit_mod

    real = fit_mod.separate_logs

    def lift_log2(p, cfg=None, thinnable=None):
        p, notes, moved = real(p, cfg, thinnable)
        logs = list(p.logs)
        logs[2] = LogSpec(centre_m=tuple(np.asarray(logs[2].centre_m) + [0.0, 0.0, 0.07]),
                          orientation=logs[2].orientation, length_m=logs[2].length_m,
                          diameter_m=logs[2].diameter_m, top_diameter_m=logs[2].top_diameter_m)
        return p.with_logs(tuple(logs)), notes + ["log 2 lifted 70 mm (planted)"], [*moved[:2], 0.07, *moved[3:]]

    monkeypatch.setattr(fit_mod, "separate_logs", lift_log2)
    scan = _scan_folder(tmp_path, pile)
    res = reconstruct(scan, _survey(pile, tmp_path / "survey.csv", {}), tmp_path / "out", ReconstructConfig(),
                      cloud=cloud)
    rep = res.report
    lf = next(lf for lf in rep["logs"] if lf["log_id"] == "log2")
    final = [np.asarray(p) for p in res.pile.logs[lf["index"]].endpoints_m()]
    for e in lf["ends"]:
        assert min(np.linalg.norm(np.asarray(e["position_m"]) - q) for q in final) < 1e-9
        assert e["sigma_m"] >= 0.07 and e["check_shift_m"] == pytest.approx(0.07, abs=1e-6)
    assert sum(w.startswith("log2 end") for w in rep["weak_ends"]) == 2, rep["weak_ends"]
    assert not any(w.startswith(("log0", "log1", "log3")) for w in rep["weak_ends"]), rep["weak_ends"]


def test_a_scrap_on_one_points_line_does_not_take_a_log_by_calling_its_other_point_wrong():
    """Both ends RTK fixed, 2 m apart; the scan shows only a 0.4 m scrap of ridge crossing their line at
    right angles, whose line passes through end b 0.8 m past the scrap. Matching it calls end a wrong
    (one outlier, cheaper than "hidden") and the prior then projects both points onto the scrap, 0 cm
    apart: twin scan 1100084 failed so under all three surveys. A match that calls one of two points
    wrong needs its other point within reach of the scan log (end_search_m)."""
    fixed = {"log0": (_end(-1.0, 0.0, fix="rtk_fixed"), _end(1.0, 0.0, fix="rtk_fixed"))}
    scrap = ScanLog(np.array([1.0, -1.2, 0.08]), np.array([1.0, -0.8, 0.08]), 0.08, 0.4, 20.0)
    matches, unmatched = match_survey(fixed, [scrap])
    assert matches["log0"].scan_index is None and unmatched == [0]
    # a wrong point beside a log the scan shows, its other point at that log's end: still matched,
    # the wrong point called wrong (what the outlier term is for)
    seen = _scan_log(-1.0, 1.0, 0.0)
    wrong = {"log0": (_end(-1.0, 0.0, fix="rtk_fixed"), _end(1.0, 0.6, fix="rtk_fixed"))}
    matches, _ = match_survey(wrong, [seen])
    assert matches["log0"].scan_index == 0


def test_a_tip_in_the_air_only_bounds_the_end_for_a_precise_point_beyond_it():
    """A log held 0.4 m over the ground by others: past its end the cameras see the ground under it from
    the side, and stereo loses its thin tip, so its top seems to stop short (twin scan 1100085: 15 cm
    short of the truth and of its fixed point under all three surveys). There a fixed point beyond the
    seen end places it; on the ground (no gap under the log) the scan's end still wins, and a point
    short of the end, or one farther than the walk reaches where the scan still covers the line is
    contradicted as before; past the scan's cover, a float point stands too."""
    cfg = FuseConfig()
    p0, u = np.zeros(3), np.array([1.0, 0.0, 0.0])
    tip = EndInterval(2.00, 2.02, "seen", gap_under_m=0.30, covered_to_m=2.70)
    beyond = _end(2.15, 0.0, fix="rtk_fixed")
    e = fuse_end(p0, u, tip, False, beyond, 0.005, cfg)
    assert e.source == "fixed" and not e.contradicted and abs(e.position_m[0] - 2.15) < 1e-9
    on_ground = EndInterval(2.00, 2.02, "seen", gap_under_m=0.0)
    assert fuse_end(p0, u, on_ground, False, beyond, 0.005, cfg).contradicted
    assert fuse_end(p0, u, EndInterval(2.00, 2.02, "seen"), False, beyond, 0.005, cfg).contradicted
    assert fuse_end(p0, u, tip, False, _end(1.85, 0.0, fix="rtk_fixed"), 0.005, cfg).contradicted  # short of it
    assert fuse_end(p0, u, tip, False, _end(2.55, 0.0, fix="rtk_fixed"), 0.005, cfg).source == "fixed"
    assert fuse_end(p0, u, tip, False, _end(2.65, 0.0, fix="rtk_fixed"), 0.005, cfg).contradicted  # 0.65 m on, seen
    # past what the scan covers at all (twin scans 1100032, 1100089: points end 18 cm past the seen end, the
    # fixed point and the truth 75 cm), nothing says the tip is not there
    e = fuse_end(p0, u, tip, False, _end(2.75, 0.0, fix="rtk_fixed"), 0.005, cfg)
    assert e.source == "fixed" and not e.contradicted and abs(e.position_m[0] - 2.75) < 1e-9
    e = fuse_end(p0, u, tip, False, _end(2.75, 0.0), 0.005, cfg)  # a float point there too (twin default surveys)
    assert e.source == "float" and not e.contradicted
    assert fuse_end(p0, u, tip, False, _end(2.45, 0.0), 0.005, cfg).source == "scan"  # float, within the cover


def test_a_precise_point_on_the_axis_past_all_the_scan_covers_extends_a_log_on_the_ground():
    """Twin scan 1100189 log 2: its top seen 1.55 m long, two bins 3 cm under its underside past that, then
    no points at all; its fixed point 97 cm on and 3 cm off the axis line, where the truth's end was.
    Nothing in the scan says the log is not there: the point places the end. Off the axis line, within
    the scan's cover, or only float, the point is contradicted as before."""
    cfg = FuseConfig()
    p0, u = np.zeros(3), np.array([1.0, 0.0, 0.0])
    short = EndInterval(1.55, 1.57, "seen", gap_under_m=0.03, covered_to_m=1.63)
    e = fuse_end(p0, u, short, False, _end(2.52, 0.03, fix="rtk_fixed"), 0.005, cfg)
    assert e.source == "fixed" and not e.contradicted and abs(e.position_m[0] - 2.52) < 1e-9
    off = fuse_end(p0, u, short, False, _end(2.52, 0.40, fix="rtk_fixed"), 0.005, cfg)  # off the line
    assert off.contradicted and off.source == "scan" and abs(off.position_m[0] - 1.55) < 0.01
    assert fuse_end(p0, u, short, False, _end(2.52, 0.03), 0.005, cfg).contradicted  # float
    covered = EndInterval(1.55, 1.57, "seen", gap_under_m=0.03, covered_to_m=2.80)
    assert fuse_end(p0, u, covered, False, _end(2.52, 0.03, fix="rtk_fixed"), 0.005, cfg).contradicted


def test_a_few_points_at_the_tops_height_past_a_hidden_stretch_are_not_the_logs_end():
    """Twin scan 1100052 log 2: its end hidden under a crossing log, then nothing seen for 30 cm, then six
    points at the height of its top (a neighbour's flank) just before the ground: the walk called the end
    seen there, 31 cm past its fixed point and the truth. Such an island is not the log: the end lies
    somewhere between its top's end and the ground (occluded). A run of the top longer than the island
    limit, or one right after the rest of the top, is the end as before."""
    rng = np.random.default_rng(5)
    r, z = 0.08, 0.08  # axis height: a log on the ground

    def strip(t0, t1, height, n):
        t = rng.uniform(t0, t1, n)
        s = rng.uniform(-0.03, 0.03, n)
        return np.c_[t, s, np.full(n, height) + (np.sqrt(r * r - s * s) if height == z else 0.0)]

    top = strip(0.0, 1.50, z, 3000)
    over = strip(1.50, 1.70, 0.35, 300)  # a crossing log's top over it
    island = strip(2.00, 2.035, z, 12)  # points at its top's height, 30 cm past the crossing
    ground = strip(2.04, 2.40, 0.0, 300)
    p0, p1 = np.array([0.0, 0.0, z]), np.array([1.5, 0.0, z])
    iv = scan_end_interval(np.r_[top, over, island, ground], p0, p1, r, True, 1.0)
    assert iv.state == "occluded" and iv.last_on_m < 1.52 and abs(iv.first_off_m - 2.04) < 0.03
    # the same top running on to 2.04 without the gap: its end, seen
    whole = strip(0.0, 2.035, z, 4000)
    iv = scan_end_interval(np.r_[whole, ground], p0, p1, r, True, 1.0)
    assert iv.state == "seen" and abs(iv.last_on_m - 2.03) < 0.02
    # a longer piece past the gap (a log seen on both sides of a crossing one) is the log's
    piece = strip(1.90, 2.035, z, 150)
    iv = scan_end_interval(np.r_[top, over, piece, ground], p0, p1, r, True, 1.0)
    assert iv.state == "seen" and abs(iv.last_on_m - 2.03) < 0.02


def test_the_walk_measures_the_gap_under_a_log_past_its_end():
    rng = np.random.default_rng(3)
    r, z_axis = 0.1, 0.5
    t = rng.uniform(0.0, 2.0, 3000)
    s = rng.uniform(-0.04, 0.04, t.size)
    top = np.c_[t, s, z_axis + np.sqrt(r * r - s * s)]
    ground = np.c_[rng.uniform(2.0, 2.4, 400), rng.uniform(-0.04, 0.04, 400), np.zeros(400)]
    p0, p1 = np.array([0.0, 0.0, z_axis]), np.array([2.0, 0.0, z_axis])
    iv = scan_end_interval(np.r_[top, ground], p0, p1, r, True, 0.4)
    assert iv.state == "seen" and abs(iv.last_on_m - 2.0) < 0.03
    assert abs(iv.gap_under_m - (z_axis - r)) < 0.01  # the ground 0.4 m under the underside
    assert abs(iv.covered_to_m - 2.4) < 0.03  # the ground's points end at 2.4 m
    on_ground = np.r_[top - [0, 0, z_axis - r], ground]
    iv = scan_end_interval(on_ground, p0 - [0, 0, z_axis - r], p1 - [0, 0, z_axis - r], r, True, 0.4)
    assert iv.state == "seen" and abs(iv.gap_under_m) < 0.01


def test_a_tip_a_hand_high_in_the_air_is_a_tip_in_the_air():
    """A log whose end is held 9 cm over the ground: stereo loses the last 7 cm of its top and past
    that the scan sees the ground 9 cm under its underside (twin scan 1100051 log 5, end a: clearance
    12 cm, gap measured 9.0-10.2 cm, top 6-8 cm short of the truth and of its fixed point; its end b, on
    another render of the same pile, 8.4 cm and 27 cm). The walk's gap reads the clearance or less, and
    ends resting on the ground read at most 1.6 cm (202 seen ground ends of 16 twin scans), so such a gap
    is a tip in the air: the fixed point beyond it places the end. A log resting on the ground (the
    ground 1 cm under its underside) keeps the scan's end."""
    cfg = FuseConfig()
    rng = np.random.default_rng(11)
    r, end, seen_to = 0.075, 2.0, 1.93  # the log ends at 2.00 m, its top is seen to 1.93 m
    for clearance, fixed_wins in ((0.09, True), (0.01, False)):
        z_axis = r + clearance
        t = rng.uniform(0.0, seen_to, 6000)
        s = rng.uniform(-0.04, 0.04, t.size)
        top = np.c_[t, s, z_axis + np.sqrt(r * r - s * s) + rng.normal(0, 0.002, t.size)]
        tg = rng.uniform(seen_to + 0.005, 2.3, 600)  # past where the top is seen: the ground, under the tip
        ground = np.c_[tg, rng.uniform(-0.04, 0.04, tg.size), rng.normal(0, 0.003, tg.size)]
        p0, p1 = np.array([0.0, 0.0, z_axis]), np.array([end, 0.0, z_axis])
        iv = scan_end_interval(np.r_[top, ground], p0, p1, r, True, 0.5, cfg)
        assert iv.state == "seen" and abs(seen_end(iv) - seen_to) < 0.02, iv
        assert abs(iv.gap_under_m - clearance) < 0.015, iv
        point = _end(end, 0.0, z_axis, fix="rtk_fixed")  # the truth, 7 cm past the seen end (> 3 sigma)
        e = fuse_end(p0, np.array([1.0, 0.0, 0.0]), iv, False, point, 0.005, cfg)
        if fixed_wins:
            assert e.source == "fixed" and not e.contradicted and abs(e.position_m[0] - end) < 1e-9, e
        else:
            assert e.source == "scan" and e.contradicted and abs(e.position_m[0] - seen_end(iv)) < 1e-9, e


def test_a_long_ridge_no_surveyed_log_takes_is_no_tie_with_a_scrap():
    """A log seen whole, and 30 cm beside it a short piece of one mostly hidden: a surveyed log with
    float ends between them fits both about as well, but taking the piece would leave the 2 m ridge a
    log the survey missed — the exception, not a tie (twin scans 1100182, 1100193: a fixed end fitted a
    0.4-0.8 m scrap as well as its own 3 m ridge, and the bench stopped as ambiguous)."""
    scan_logs = [_scan_log(-1.0, 1.0, 0.0), _scan_log(-0.3, 0.3, 0.3)]
    floating = {"log7": (_end(-1.0, 0.15), _end(1.0, 0.15))}
    for order in (1, -1):  # whichever the chi2 puts first
        logs = scan_logs[::order]
        matches, unmatched = match_survey(floating, logs)
        assert logs[matches["log7"].scan_index] is scan_logs[0] and len(unmatched) == 1
    # with the two logs both whole, either choice leaves a 2 m ridge unsurveyed: the same pile
    both = [_scan_log(-1.0, 1.0, 0.0), _scan_log(-1.0, 1.0, 0.3)]
    assert match_survey(floating, both)[0]["log7"].scan_index in (0, 1)


def test_a_fixed_point_well_across_a_scan_fitted_axis_is_reported_not_followed():
    """Twin scan 700085: a log fitted on a ridge 9-14 cm off both its RTK fixed points; the 3-D point test
    (~15 cm for a fixed point) called neither wrong, and only the pile check stopped the pile. Across a
    scan-fitted axis a fixed point 10 cm off is contradicted (the end stays on the axis: a fitted axis is
    the better of the two); 5 cm off, the usual spread, is not; a log whose axis is the survey's is placed
    by its point as before."""
    cfg = FuseConfig()
    p0, u = np.zeros(3), np.array([1.0, 0.0, 0.0])
    seen = EndInterval(2.00, 2.02, "seen", gap_under_m=0.0, covered_to_m=2.4)
    far = fuse_end(p0, u, seen, False, _end(2.01, 0.10, 0.0, fix="rtk_fixed"), 0.005, cfg)
    assert far.contradicted and abs(far.position_m[1]) < 1e-9
    assert not fuse_end(p0, u, seen, False, _end(2.01, 0.05, 0.0, fix="rtk_fixed"), 0.005, cfg).contradicted
    partial = fuse_end(p0, u, seen, False, _end(2.01, 0.10, 0.0, fix="rtk_fixed"), 0.04, cfg, seen_whole=False)
    assert not partial.contradicted and partial.position_m[1] > 0.05


def test_a_short_piece_does_not_set_the_axis_of_a_log_with_two_precise_points():
    """Real-test scan 700414: a log under others, 35 cm of it seen by its butt, the piece's ridge 9 deg off
    the line of its two RTK-fixed points 2.7 m apart; on that ridge's axis the log came out 41 cm off its
    other fixed point. Two precise points set the line better than a piece of a quarter of the log: they
    are its prior axis. A float point, a piece in line with the points (within ``piece_off_m``) or a ridge
    seen over most of the log leaves the scan's axis."""
    from reconstruct.fitting.fuse import prior_axis

    cfg = FuseConfig()
    a, b = _end(0.0, 0.0, fix="rtk_fixed"), _end(2.7, 0.0, fix="rtk_fixed")
    piece = _slanted_scan_log((0.05, 0.0, 0.08), (0.40, 0.055, 0.08))  # 0.35 m, 9 deg off
    pa, pb, lateral = prior_axis((a, b), piece, False, cfg)
    assert np.allclose(pa, a.position_m) and np.allclose(pb, b.position_m) and lateral < 0.05
    def across(log, p):  # the distance of p from the scan log's line, in plan [m]
        d, q = log.direction[:2] / np.linalg.norm(log.direction[:2]), p[:2] - log.start_m[:2]
        return abs(d[0] * q[1] - d[1] * q[0])

    on_the_piece = lambda p: across(piece, p) < 1e-6  # noqa: E731
    pa, pb, _ = prior_axis((a, _end(2.7, 0.0)), piece, False, cfg)  # end b float: the scan's axis
    assert on_the_piece(pa) and on_the_piece(pb)
    aligned = _slanted_scan_log((0.05, 0.0, 0.08), (0.40, 0.004, 0.08))  # a piece in line with the points
    pa, pb, _ = prior_axis((a, b), aligned, False, cfg)
    assert across(aligned, pa) < 1e-6 and across(aligned, pb) < 1e-6
    long = _slanted_scan_log((0.05, 0.0, 0.08), (2.0, 0.31, 0.08))  # most of the log
    pa, pb, _ = prior_axis((a, b), long, False, cfg)
    assert across(long, pa) < 1e-6 and across(long, pb) < 1e-6


def test_level_ground_past_the_end_of_a_log_running_down_is_not_its_top():
    """Real-test scan 700414 log 2: a log running down to the ground (13 deg), its end on an RTK-fixed
    point; past it the scan sees nothing for 34 cm (the log's shadow), the ground one bin lower than the
    log's top would be, then level ground where the log's top, extended into the ground, would be: ten
    bins 'on the log' outweighed the one below, and the end was placed 59 cm out, the fixed point called
    wrong. Level ground on both sides of the top is not a top: the end is before it. A log that really
    runs on down (its top curved across) still does, and a level log's walk is as before."""
    rng = np.random.default_rng(11)
    r, slope = 0.08, 0.239
    u = np.array([1.0, 0.0, -slope]) / math.hypot(1.0, slope)
    p0 = np.array([0.0, 0.0, 0.06]) - 2.0 * u  # end b at x = 2.0 (axis), 6 cm over the ground's 1.3 cm
    p1 = np.array([0.0, 0.0, 0.06])
    L = 2.0

    def top_points(t0, t1, n):
        t = rng.uniform(t0, t1, n)
        s = rng.uniform(-0.07, 0.07, n)
        up = np.array([0.0, 0.0, 1.0]) - u[2] * u
        up /= np.linalg.norm(up)
        return p0 + np.outer(t, u) + np.outer(s, [0.0, 1.0, 0.0]) + np.outer(np.sqrt(r * r - s * s), up)

    def ground(t0, t1, n, z=0.013):
        x = p1[0] + rng.uniform(t0, t1, n) * u[0]
        return np.c_[x, rng.uniform(-0.15, 0.15, n), np.full(n, z)]

    scan = np.r_[top_points(0.0, L, 4000), ground(0.34, 0.62, 1200)]
    iv = scan_end_interval(scan, p0, p1, r, True, 0.6)
    assert iv.last_on_m < L + 0.03 and iv.state in ("seen", "occluded"), iv
    # the log really runs on 40 cm down past the point (its curved top), the ground after it
    longer = np.r_[top_points(0.0, L + 0.40, 4800), ground(0.55, 0.62, 300, z=-0.05)]
    iv = scan_end_interval(longer, p0, p1, r, True, 0.6)
    assert abs(iv.last_on_m - (L + 0.40)) < 0.03, iv


def test_one_bin_seen_through_under_a_crossing_log_does_not_end_the_log():
    """Twin scan 1100028 (fixed survey): a log under a crossing one for 80 cm to its fixed point, one bin
    seen through to the ground 19 cm into that stretch, the ground seen right past the point. That one
    bin was where the scan 'saw below' the log first, contradicting the point, and the end went 72 cm
    short. A single bin among others over the log is a gap seen through: the first of two bins in a row
    below the top is where the scan shows the log is not; with no such run, a single one still counts."""
    rng = np.random.default_rng(4)
    r, z = 0.08, 0.08

    def strip(t0, t1, height, n, on_top=False):
        t = rng.uniform(t0, t1, n)
        s = rng.uniform(-0.03, 0.03, n)
        return np.c_[t, s, np.full(n, height) + (np.sqrt(r * r - s * s) if on_top else 0.0)]

    top = strip(0.0, 1.50, z, 3000, on_top=True)
    over = np.r_[strip(1.50, 1.701, 0.40, 300), strip(1.719, 2.30, 0.40, 900)]  # a crossing log over it
    gap = strip(1.703, 1.717, 0.0, 12)  # one 2 cm bin seen through to the ground
    ground = strip(2.30, 2.60, 0.0, 400)
    p0, p1 = np.array([0.0, 0.0, z]), np.array([1.5, 0.0, z])
    iv = scan_end_interval(np.r_[top, over, gap, ground], p0, p1, r, True, 1.2)
    assert iv.state == "occluded" and abs(iv.first_off_m - 2.30) < 0.03, iv
    iv = scan_end_interval(np.r_[top, over[:300], gap], p0, p1, r, True, 1.2)  # the gap alone: it ends it
    assert abs(iv.first_off_m - 1.70) < 0.03, iv


@pytest.mark.parametrize("yaw_deg", [0.0, 37.0, 128.0, -71.0])
def test_pieces_are_told_by_their_top_view_distance_from_a_line_at_any_heading(yaw_deg):
    """The top-view distance from a scan log's line decides both piece rules; at any heading (a sign
    slip in the distance hides on logs along x or y) a piece 3 cm off the line is on it, 9 cm off is not,
    and a survey point 15 cm off a short ridge makes the ridge a piece of its surveyed log, 5 cm not."""
    R = rot_z(math.radians(yaw_deg))[:3, :3]
    at = lambda x, y, z=0.08: R @ np.array([x, y, z])  # noqa: E731
    log = ScanLog(at(-1.5, 0.0), at(1.5, 0.0), 0.08, 3.0, 20.0)
    for side in (1, -1):
        near = ScanLog(at(1.8, 0.03 * side), at(2.4, 0.03 * side), 0.08, 0.6, 20.0)
        far = ScanLog(at(1.8, 0.09 * side), at(2.4, 0.09 * side), 0.08, 0.6, 20.0)
        assert absorb_pieces({"a": Match("a", 0)}, [1], [log, near]) == []
        assert absorb_pieces({"a": Match("a", 0)}, [1], [log, far]) == [1]
        ridge = ScanLog(at(-1.5, 0.0), at(-0.9, 0.0), 0.08, 0.6, 20.0)
        for off, piece in ((0.15, True), (0.05, False)):
            ends = (SurveyEnd(at(-1.5, 0.0), 0.01, 0.02, "rtk_fixed"),
                    SurveyEnd(at(1.5, off * side), 0.01, 0.02, "rtk_fixed"))
            assert a_piece_of_a_surveyed_log(ends, ridge, FuseConfig()) is piece
