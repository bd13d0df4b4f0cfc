"""reconstruct.fitting.fuse and the pipeline under real survey conditions: float points, logs or ends not
surveyed, points the scan contradicts, and geometry the survey cannot settle. The scans are exact
top-view samples of hand-made piles (no stereo), so these run in seconds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruct.errors import GnssQualityError
from reconstruct.fitting.fit import sample_top_view_points
from reconstruct.fitting.fuse import (AmbiguousSurveyError, EndInterval, FuseConfig, ScanLog, absorb_pieces, fuse_end,
                                      match_survey, scan_end_interval, seen_end)
from reconstruct.config import ReconstructConfig
from reconstruct.pipeline import reconstruct
from reconstruct.scan.stereo import ScanCloud
from synth.geometry import geodesy
from synth.geometry.frames import make_T, rot_z
from synth.scene.pile import Georeference, LogSpec, PileSpec, TerrainSpec
from tests.reconstruct.fitting.fusion_helpers import ORIGIN, along_site, end_errors, scan_folder, scan_log, slanted_scan_log, survey_end, write_survey















def test_float_points_a_log_without_points_and_a_missing_end(pile, cloud, tmp_path):
    scan = scan_folder(tmp_path, pile)
    gnss = write_survey(pile, tmp_path / "survey.csv", {
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
    err = end_errors(pile, res.pile)
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
    scan = scan_folder(tmp_path, pile, pose_error=err_T)
    lateral = geodesy.pile_to_site(pile.georef, np.array([[0.0, 0.2, 0.0]]))[0] - \
        geodesy.pile_to_site(pile.georef, np.zeros((1, 3)))[0]
    gnss = write_survey(pile, tmp_path / "survey.csv", {
        (0, "a"): ("rtk_fixed", along_site(pile, 0, 0.25, "a"), 0.015, 0.025),  # 25 cm past a seen end
        (1, "b"): ("rtk_fixed", lateral, 0.015, 0.025),  # 20 cm beside its log: a wrong point
    })
    res = reconstruct(scan, gnss, tmp_path / "out", ReconstructConfig(), cloud=cloud)
    rep = res.report
    err = end_errors(pile, res.pile)
    assert max(err.values()) < 0.035, err  # placed where the scan shows them, the scan pose corrected
    outliers = {(o["log_id"], o["end"]) for o in rep["registration"]["outliers"]}
    assert ("log1", "b") in outliers
    assert rep["registration"]["weights"]["log1.b"] < 0.1
    bad = {(lf["log_id"], end) for lf in rep["logs"] for end, e in zip("ab", lf["ends"]) if e["contradicted"]}
    assert bad == {("log0", "a"), ("log1", "b")}
    assert len(rep["contradicted_points"]) == 2 and "log0 end a (rtk_fixed)" in rep["contradicted_points"][0]






def test_only_geometry_the_survey_cannot_settle_stops_and_names_the_log():
    # two short pieces of logs mostly hidden, 30 cm apart: a surveyed log with float ends between them
    # could be either, and the piles differ (the other piece is dropped: too short to stand alone)
    scan_logs = [scan_log(-0.3, 0.3, 0.0), scan_log(-0.3, 0.3, 0.3)]
    floating = {"log7": (survey_end(-1.0, 0.15), survey_end(1.0, 0.15))}
    with pytest.raises(AmbiguousSurveyError, match=r"log 'log7'.*Re-measure log 'log7'"):
        match_survey(floating, scan_logs)
    # fixed points settle it
    fixed = {"log7": (survey_end(-1.0, 0.0, fix="rtk_fixed"), survey_end(1.0, 0.01, fix="rtk_fixed"))}
    matches, unmatched = match_survey(fixed, scan_logs)
    assert matches["log7"].scan_index == 0 and unmatched == [1]
    # two whole logs either of which the float log could be: the same pile either way, no error
    two = [scan_log(-1.0, 1.0, 0.0), scan_log(-1.0, 1.0, 0.3)]
    matches, unmatched = match_survey(floating, two)
    assert matches["log7"].scan_index in (0, 1) and len(unmatched) == 1
    # one log seen in two short pieces (something lies over its middle), its ends fixed: either piece
    # is the same log, no error (twin scan 1100017 stopped here)
    pieces = [scan_log(-1.0, -0.4, 0.0), scan_log(0.7, 1.0, 0.005)]
    whole = {"log7": (survey_end(-1.0, 0.0, fix="rtk_fixed"), survey_end(1.0, 0.0, fix="rtk_fixed"))}
    matches, unmatched = match_survey(whole, pieces)
    assert matches["log7"].scan_index in (0, 1)
    assert absorb_pieces(matches, unmatched, pieces) == []


def test_a_sloped_ridge_on_a_logs_fixed_line_is_that_log_not_an_ambiguity():
    """Both ends RTK fixed; the scan shows a ridge on their line whose fitted height slopes through
    theirs (each point ~3.8 sigma off it): "hidden, and that ridge another log" is within the chi2
    margin, but it would put two logs in one place (twin scan 1100133 stopped here under all three
    surveys; with the match taken, every log of it lands within 3.3 cm). A ridge as far ABOVE the
    line all along may be a log lying on it: still an ambiguity."""
    fixed = {"log0": (survey_end(-1.0, 0.0, fix="rtk_fixed"), survey_end(1.0, 0.0, fix="rtk_fixed"))}
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
    near = survey_end(2.15, 0.1)  # float, 15 cm off along: consistent
    e = fuse_end(p0, u, seen, False, near, 0.005, cfg)
    assert e.source == "scan" and not e.contradicted and abs(e.position_m[0] - 2.00) < 0.005
    assert e.sigma_along_m < cfg.scan_end_sigma_m
    far = survey_end(2.20, 0.0, fix="rtk_fixed")  # fixed, 19 cm off: the scan contradicts it
    e = fuse_end(p0, u, seen, False, far, 0.005, cfg)
    assert e.contradicted and e.source == "scan" and abs(e.position_m[0] - 2.00) < 1e-9
    agree = survey_end(2.02, 0.0, fix="rtk_fixed")
    e = fuse_end(p0, u, seen, False, agree, 0.005, cfg)
    assert e.source == "fixed" and 2.00 < e.position_m[0] < 2.02
    under = EndInterval(2.00, 2.30, "occluded")  # a log lies over its end: somewhere in 2.0-2.3 m
    e = fuse_end(p0, u, under, False, survey_end(2.21, 0.0), 0.005, cfg)
    assert e.source == "float" and abs(e.position_m[0] - 2.21) < 1e-9 and e.sigma_along_m < 0.09
    e = fuse_end(p0, u, under, False, None, 0.005, cfg)
    assert e.source == "inferred" and abs(e.position_m[0] - 2.15) < 1e-9
    e = fuse_end(p0, u, EndInterval(2.0, None, "open"), False, None, 0.005, cfg)  # the scan stops
    assert e.source == "inferred" and e.weak(cfg)
    e = fuse_end(p0, u, EndInterval(0.02, 0.0, "seen"), True, None, 0.005, cfg)  # end a, toward -t
    assert e.source == "scan" and abs(e.position_m[0] - 0.02) < 1e-9
    # a log the scan shows only in part may run on under others past where its top seems to stop: a
    # fixed point beyond a seen end places it there; one short of it is still contradicted
    beyond = survey_end(2.60, 0.0, fix="rtk_fixed")
    e = fuse_end(p0, u, seen, False, beyond, 0.04, cfg, seen_whole=False)
    assert e.source == "fixed" and not e.contradicted and abs(e.position_m[0] - 2.60) < 1e-9
    assert fuse_end(p0, u, seen, False, beyond, 0.005, cfg).contradicted  # a log seen whole: the scan's end
    short = survey_end(1.60, 0.0, fix="rtk_fixed")
    assert fuse_end(p0, u, seen, False, short, 0.04, cfg, seen_whole=False).contradicted


def test_an_end_the_scan_shows_nothing_of_goes_to_its_point_by_their_accuracies():
    """Where the scan shows none of a log's top near an end, the survey point places it along the axis
    AND across it by the two accuracies, and is tested like any other (twin scan 1100133: a log seen
    over a third of its length, its fitted axis 9 deg off, came back with an end 40 cm above its RTK
    fixed point, the 'fixed' end left on the extrapolated axis and not reported)."""
    cfg = FuseConfig()
    p0, u = np.zeros(3), np.array([1.0, 0.0, 0.0])
    nothing = EndInterval(None, None, "none")
    below = survey_end(2.0, 0.0, z=-0.40, fix="rtk_fixed")  # 40 cm below the (partial) fit's axis
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
    scan = scan_folder(tmp_path, pile)
    bias = (0.08, 0.06, 0.0)
    floats = {(i, end): ("rtk_float", bias, 0.25, 0.40) for i, end in ((1, "b"), (2, "a"), (2, "b"), (3, "a"), (3, "b"))}
    exact = {(i, end): ("rtk_fixed", (0.0, 0.0, 0.0), 0.015, 0.025) for i, end in ((0, "a"), (0, "b"), (1, "a"))}
    gnss = write_survey(pile, tmp_path / "survey.csv", floats | exact)
    res = reconstruct(scan, gnss, tmp_path / "out", ReconstructConfig(allow_float=True), cloud=cloud)
    reg = res.report["registration"]
    assert reg["end_points_used"] == 8 and reg["end_points_precise"] == 3
    assert reg["correction_m"] < 0.004, reg
    assert max(end_errors(pile, res.pile).values()) < 0.03




def test_a_fixed_log_is_not_ambiguous_with_a_scrap_that_needs_one_of_its_points_wrong():
    # twin scan 1100039: the ridge of a log runs 0.5 m on past its end b over the touching neighbour's end,
    # so its fixed point b lies inside the ridge (chi2 ~13); a 15 cm scrap of ridge at b, across the log,
    # explains b and calls a wrong (gate + 1 = 17). The chi2 margin is for noise: no ambiguity, and the
    # log is the long one
    scan_logs = [scan_log(-1.0, 1.5, 0.0), slanted_scan_log((1.0, 0.01, 0.08), (1.2, 0.25, 0.08), seen=0.15)]
    survey = {"log4": (survey_end(-1.0, 0.0, fix="rtk_fixed"), survey_end(1.0, 0.0, fix="rtk_fixed"))}
    matches, unmatched = match_survey(survey, scan_logs)
    assert matches["log4"].scan_index == 0 and unmatched == [1]
    assert "scan log 1" in matches["log4"].alternative  # the scrap was the next best, within chi2 4
    assert float(matches["log4"].alternative.split("+")[1].rstrip(")")) < FuseConfig().ambiguity_chi2


def test_a_ridge_running_on_past_a_fixed_end_is_the_log_not_a_scrap_beside_that_end():
    """Twin scan 1100166, degraded survey: a log's ridge runs 0.76 m on past its fixed end b, onto a stump;
    a 35 cm scrap beside b (the stump's edge) explained b and let the float a lie on its line far off.
    The ridge, with b well inside it, is as costly as a wrong point but calls none wrong: the two are as
    good, and the ridge, which would otherwise stand as a log the survey missed, is the log's."""
    ridge = slanted_scan_log((-1.0, 0.0, 0.08), (1.8, 0.0, 0.08))
    scrap = slanted_scan_log((0.80, 0.17, 0.08), (1.15, 0.17, 0.08), seen=0.35)
    other = scan_log(-1.0, 1.0, 1.0)
    survey = {"log2": (survey_end(-1.05, 0.05), survey_end(1.0, 0.0, fix="rtk_fixed")),
              "log1": (survey_end(-1.0, 1.0, fix="rtk_fixed"), survey_end(1.0, 1.0, fix="rtk_fixed"))}
    matches, unmatched = match_survey(survey, [ridge, scrap, other])
    assert matches["log2"].scan_index == 0 and unmatched == [1]
    assert "scan log 1 (chi2 -" in matches["log2"].alternative  # the scrap alone explains the points better


def test_of_two_logs_side_by_side_the_one_with_a_float_point_takes_the_ridge():
    """Twin scans 700074, 700114: two surveyed logs side by side, the scan showing one ridge between them;
    either could be the hidden one, about equally well (chi2 2.1-2.3). Hidden, a log is placed from its
    points: the one with both RTK fixed is, and the one with a float point takes the ridge. Where both
    have a float point, which is hidden is still the ambiguity it was."""
    ridge = [scan_log(-1.0, 1.0, 0.10)]
    survey = {"logA": (survey_end(-1.0, 0.03, fix="rtk_fixed"), survey_end(1.0, 0.03, fix="rtk_fixed")),
              "logB": (survey_end(-1.0, 0.17), survey_end(1.0, 0.17, fix="rtk_fixed"))}
    matches, _ = match_survey(survey, ridge)
    assert matches["logB"].scan_index == 0 and matches["logA"].scan_index is None
    survey["logA"] = (survey_end(-1.0, 0.03), survey_end(1.0, 0.03, fix="rtk_fixed"))
    with pytest.raises(AmbiguousSurveyError):
        match_survey(survey, ridge)


def test_an_ambiguity_between_fixed_points_does_not_ask_for_a_fixed_solution():
    # two parallel pieces of logs 6 cm apart, each seen only in the middle; fixed points half-way
    # between: either piece, and the piles differ (the other one dropped). Measuring the points
    # RTK fixed again settles nothing: the message says to check them and survey the neighbours
    scan_logs = [scan_log(-0.35, 0.35, 0.0), scan_log(-0.3, 0.3, 0.06)]
    survey = {"log2": (survey_end(-1.0, 0.03, fix="rtk_fixed"), survey_end(1.0, 0.03, fix="rtk_fixed"))}
    with pytest.raises(AmbiguousSurveyError) as err:
        match_survey(survey, scan_logs)
    msg = str(err.value)
    assert "log 'log2'" in msg and "RTK fixed solution" not in msg
    assert "Check that log 'log2''s points were taken at its end centres" in msg
    # with one float point, that one point is named to re-measure
    survey = {"log2": (survey_end(-1.0, 0.03, fix="rtk_fixed"), survey_end(1.0, 0.03))}
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
    scan = scan_folder(tmp_path, pile)
    gnss = write_survey(pile, tmp_path / "survey.csv", {})
    res = reconstruct(scan, gnss, tmp_path / "out", ReconstructConfig(), cloud=cloud)
    err = end_errors(pile, res.pile)
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
    fixed = survey_end(2.10, 0.0, fix="rtk_fixed")
    e = fuse_end(p0, u, covered, False, fixed, 0.04, cfg, seen_whole=False)
    assert e.source == "fixed" and not e.contradicted and abs(e.position_m[0] - 2.10) < 0.005
    # and from inside an open end: the log's visible top there may be another's
    e = fuse_end(p0, u, EndInterval(2.40, None, "open"), False, fixed, 0.04, cfg, seen_whole=False)
    assert e.source == "fixed" and abs(e.position_m[0] - 2.10) < 0.005
    # a float point there is still held to the scan's bounds, and on a log seen whole the scan decides
    e = fuse_end(p0, u, covered, False, survey_end(2.10, 0.0), 0.04, cfg, seen_whole=False)
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
