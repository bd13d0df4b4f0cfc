"""A fixed point is evidence, not a suggestion (issue 37, step 4): wrong survey points injected into the
all-fixed survey of a twin scan (`loggrasp synth scan`: rendered stereo pairs, stereo matching, RTK noise).
The reconstruction must name exactly the injected points (each end's ``contradicted`` flag and the
report's ``contradicted_points``), keep every correct RTK fixed point (none called wrong) and still put
every log where it lies.

Cases: two logs' end points exchanged (each recorded under the other log), a point 30 cm off its end, a
point measured on one log recorded under another's id, and a log whose ends a and b are exchanged (the
butt recorded as the top: on these cylindrical logs the same segment, so nothing is wrong with the pile
and nothing may be called wrong).

Each case runs with every estimator of ``ReconstructConfig.estimator``. Revision 22 (``rules22``) fails one
(:data:`KNOWN_FAILURES`, ``xfail(strict=True)`` with the reason); the joint estimator passes it. Where the
survey's ids make two sets of points equally wrong (two logs' ends exchanged; two one-point logs on one log in
the scan), either set is right: the test takes both.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from reconstruct.compare import compare_piles
from reconstruct.config import ReconstructConfig
from reconstruct.pipeline import reconstruct
from reconstruct.survey.gnss import GnssSurvey, read_gnss, write_gnss_csv
from synth.geometry import geodesy
from synth.scene.pile import PileSpec, read_pile

SEED = 3_390_017  # no bench's seed (tuning 1,100,000+, held-out 3,300,000..3,300,599)
MAX_END_ERR_M = 0.05  # every log within this of the truth, the wrong points notwithstanding [m]


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    """A 4-log twin scan without obstacles, its all-fixed survey, its stereo cloud and its true pile."""
    from reconstruct.scan.stereo import scan_cloud
    from reconstruct.scan.twin_scan import make_twin_scan, write_twin_survey

    root = make_twin_scan(tmp_path_factory.mktemp("wrong-points") / "scan", SEED, logs=(4, 4), obstacles=(0, 0),
                          n_float=0)
    gnss = write_twin_survey(root, root / "gnss_fixed.csv", n_float=0)
    return root, read_gnss(gnss), scan_cloud(root / "scan"), read_pile(root / "truth" / "pile.json")


def _move(truth: PileSpec, p, offset_pile_m) -> object:
    """Survey point ``p`` moved by ``offset_pile_m`` (pile frame) [m]."""
    x = geodesy.geodetic_to_pile(truth.georef, p.lat_deg, p.lon_deg, p.h_ell_m).reshape(3) + np.asarray(offset_pile_m)
    lat, lon, h = geodesy.pile_to_geodetic(truth.georef, x[None, :])
    return replace(p, lat_deg=float(lat[0]), lon_deg=float(lon[0]), h_ell_m=float(h[0]))


def _at(survey: GnssSurvey, log_id: str, end: str):
    return next(p for p in survey.points if p.log_id == log_id and p.end == end)


def _exchange(survey: GnssSurvey, one: tuple[str, str], other: tuple[str, str]) -> GnssSurvey:
    """The positions of two survey points exchanged (each recorded under the other's log and end)."""
    p, q = _at(survey, *one), _at(survey, *other)
    pos = {one: (q.lat_deg, q.lon_deg, q.h_ell_m), other: (p.lat_deg, p.lon_deg, p.h_ell_m)}
    return GnssSurvey(tuple(replace(x, lat_deg=pos[k][0], lon_deg=pos[k][1], h_ell_m=pos[k][2])
                            if (k := (x.log_id, x.end)) in pos else x for x in survey.points))


def _far_pair(truth: PileSpec) -> tuple[int, int]:
    """Two logs whose b ends lie more than 1 m apart (an exchange of those points is a gross error)."""
    b = np.array([lg.endpoints_m()[1] for lg in truth.logs])
    d = np.linalg.norm(b[:, None, :2] - b[None, :, :2], axis=-1)
    i, j = np.unravel_index(int(np.argmax(d)), d.shape)
    assert d[i, j] > 1.0
    return int(i), int(j)


def _swapped_between_logs(survey, truth):
    i, j = _far_pair(truth)
    # the survey's log ids are names: "log i is the log of a_i, its b point wrong" and "log i is the log of
    # b_j, its a point wrong" (the two logs' names exchanged) explain the survey equally well
    return _exchange(survey, (f"log{i}", "b"), (f"log{j}", "b")), [{(f"log{i}", "b"), (f"log{j}", "b")},
                                                                    {(f"log{i}", "a"), (f"log{j}", "a")}]


def _thirty_cm_off(survey, truth):
    a, b = (np.asarray(e) for e in truth.logs[1].endpoints_m())
    u = (b - a) / np.linalg.norm(b - a)
    across = np.array([-u[1], u[0], 0.0]) / np.hypot(u[0], u[1])
    pts = tuple(_move(truth, p, 0.30 * across) if (p.log_id, p.end) == ("log1", "a") else p for p in survey.points)
    return GnssSurvey(pts), {("log1", "a")}


def _thirty_cm_along(survey, truth):
    """log0's end b measured 30 cm out past its end, along the log (the scan sees the end)."""
    a, b = (np.asarray(e) for e in truth.logs[0].endpoints_m())
    u = (b - a) / np.linalg.norm(b - a)
    pts = tuple(_move(truth, p, 0.30 * u) if (p.log_id, p.end) == ("log0", "b") else p for p in survey.points)
    return GnssSurvey(pts), {("log0", "b")}


def _unknown_log_id(survey, truth):
    """log3's end b recorded under a log id no other point has ('log9'): log3 measured at one end only. Two logs
    of one point each, both on one log in the scan: either id may be the wrong one."""
    pts = tuple(replace(p, log_id="log9") if (p.log_id, p.end) == ("log3", "b") else p for p in survey.points)
    return GnssSurvey(pts), [{("log9", "b")}, {("log3", "a")}]


def _wrong_log_id(survey, truth):
    """log i's end a measured again but recorded as log j's end a (j's own point lost)."""
    i, j = _far_pair(truth)
    src = _at(survey, f"log{i}", "a")
    pts = tuple(replace(p, lat_deg=src.lat_deg, lon_deg=src.lon_deg, h_ell_m=src.h_ell_m)
                if (p.log_id, p.end) == (f"log{j}", "a") else p for p in survey.points)
    return GnssSurvey(pts), {(f"log{j}", "a")}


def _ends_of_one_log_exchanged(survey, truth):
    return _exchange(survey, ("log2", "a"), ("log2", "b")), set()


ESTIMATORS = ("rules22", "joint")


def _run(twin, tmp_path: Path, survey: GnssSurvey, estimator: str):
    root, _, cloud, truth = twin
    path = write_gnss_csv(survey, tmp_path / "survey.csv")
    cfg = ReconstructConfig(allow_float=True, **({} if estimator == "rules22" else {"estimator": estimator}))
    res = reconstruct(root / "scan", path, tmp_path / "out", cfg, cloud=cloud)
    cmp = compare_piles(truth, res.pile, render=False)
    flagged = {(lf["log_id"], end) for lf in res.report["logs"] for end, e in zip("ab", lf["ends"]) if e["contradicted"]}
    named = {tuple(re.match(r"(\S+) end ([ab]) ", line).groups()) for line in res.report["contradicted_points"]}
    assert flagged <= named, (flagged, named)  # every end flagged is named; a point of a log left out only named
    return res, cmp, named


def _check(res, cmp, flagged, expected):
    """``expected``: the injected points, or a list of the sets of points that explain the survey equally well."""
    alternatives = expected if isinstance(expected, list) else [expected]
    assert flagged in alternatives, f"flagged {sorted(flagged)}, injected {[sorted(e) for e in alternatives]}"
    assert len(res.report["contradicted_points"]) == len(flagged)  # one line per point
    assert not cmp["unmatched_truth"] and not cmp["unmatched_recon"]  # every log, and no phantom one
    worst = {e["truth_index"]: round(e["endpoint_max_err_m"], 3) for e in cmp["logs"]}
    assert max(worst.values()) < MAX_END_ERR_M, worst


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_the_clean_survey_reconstructs_with_nothing_called_wrong(twin, tmp_path, estimator):
    res, cmp, flagged = _run(twin, tmp_path, twin[1], estimator)
    _check(res, cmp, flagged, set())


CASES = {
    "swapped-between-logs": _swapped_between_logs,
    "30cm-off": _thirty_cm_off,
    "30cm-along": _thirty_cm_along,
    "wrong-log-id": _wrong_log_id,
    "unknown-log-id": _unknown_log_id,
    "ends-of-one-log-exchanged": _ends_of_one_log_exchanged,
}
#: (estimator, case) -> why revision 22 fails it (the joint estimator is meant to flip these)
KNOWN_FAILURES: dict[tuple[str, str], str] = {
    ("rules22", "unknown-log-id"): "revision 22 stops the whole scan with AmbiguousSurveyError ('log9' fits the "
                                   "scan's log 'almost equally well' as 'being hidden under other logs') instead of "
                                   "reconstructing it and naming the one point that fits no log of its own",
}


@pytest.mark.parametrize("estimator", ESTIMATORS)
@pytest.mark.parametrize("case", list(CASES))
def test_injected_wrong_points_are_named_and_correct_fixed_points_kept(twin, tmp_path, case, estimator, request):
    if (estimator, case) in KNOWN_FAILURES:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN_FAILURES[(estimator, case)]))
    survey, expected = CASES[case](twin[1], twin[3])
    _check(*_run(twin, tmp_path, survey, estimator), expected)
