"""reconstruct.fitting.coverage: an end point outside the scanned area is admitted when its log is seen (the axis
between its two surveyed points runs at least ``seen_log_min_length_m`` over the scan), and refused when
the scan sees none of its log (a wrong log id, a point of another pile, a wrong scan pose)."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruct.config import ReconstructConfig
from reconstruct.fitting.coverage import CoverageConfig, check_coverage, seen_length_m
from reconstruct.errors import RegistrationError
from reconstruct.fitting.fuse import SurveyEnd

# scan points over a 4 x 2.5 m patch (x in [-2, 2), y in [-1.25, 1.25)), 5 cm apart
PATCH = np.mgrid[-2:2:0.05, -1.25:1.25:0.05].reshape(2, -1).T


def fixed(x, y, z=0.2) -> SurveyEnd:
    return SurveyEnd(np.array([x, y, z]), 0.01, 0.02, "rtk_fixed")


def test_a_log_leaving_the_scan_keeps_its_far_end():
    """log1 runs from inside the patch 1.6 m past its edge along x: its b end lies 1.6 m from every scan point,
    its axis 1.5 m over the scan; the end is admitted and listed, with those distances."""
    ends = {"log0": (fixed(-1.5, 0.0), fixed(1.5, 0.0)), "log1": (fixed(0.5, 0.5), fixed(3.6, 0.5))}
    cov = check_coverage(PATCH, ends, 1.0)
    assert [(o.log_id, o.end) for o in cov.outside] == [("log1", "b")]
    assert cov.outside[0].distance_m == pytest.approx(1.65, abs=0.01)
    assert cov.outside[0].seen_length_m == pytest.approx(1.5, abs=0.1)
    assert "log1 end b lies 1.65 m outside the scanned area" in cov.outside[0].line()
    assert cov.distances_m["log0"][0] < 0.05 and cov.distances_m["log1"][1] > 1.6


def test_a_log_crossing_the_scan_keeps_both_ends():
    ends = {"log0": (fixed(-3.5, 0.0), fixed(3.5, 0.2))}
    cov = check_coverage(PATCH, ends, 1.0)
    assert {(o.log_id, o.end) for o in cov.outside} == {("log0", "a"), ("log0", "b")}


@pytest.mark.parametrize("ends, named", [
    # a log the scan does not see at all, 1.35-1.5 m past the patch (a wrong id, another log of the pile)
    ({"log0": (fixed(-1.5, 0.0), fixed(1.5, 0.0)), "log1": (fixed(-1.4, 2.6), fixed(1.4, 2.75))}, "log1"),
    # its axis touches the scan for 0.3 m only: less than seen_log_min_length_m
    ({"log0": (fixed(1.8, 0.0), fixed(4.8, 0.0))}, "log0"),
    # one surveyed end, far from the scan: no axis to see
    ({"log0": (fixed(-1.5, 0.0), fixed(1.5, 0.0)), "log1": (None, fixed(3.6, 0.5))}, "log1"),
    # the whole survey 8 m off (a wrong scan pose): nothing is seen
    ({"log0": (fixed(6.5, 0.0), fixed(9.5, 0.0))}, "log0"),
])
def test_an_end_whose_log_the_scan_does_not_see_is_refused(ends, named):
    with pytest.raises(RegistrationError, match=f"log {named!r} end '[ab]'.*outside the scanned area"):
        check_coverage(PATCH, ends, 1.0)


def test_an_end_within_the_limit_is_not_listed():
    ends = {"log0": (fixed(0.5, 0.5), fixed(2.8, 0.5))}  # 0.85 m past the edge: inside the 1 m limit
    assert check_coverage(PATCH, ends, 1.0).outside == ()


def test_the_seen_length_is_the_axis_over_the_scan():
    from scipy.spatial import cKDTree

    tree = cKDTree(PATCH)
    cfg = CoverageConfig()
    assert seen_length_m(tree, np.array([-1.0, 0.0]), np.array([1.0, 0.0]), cfg) == pytest.approx(2.0)
    assert seen_length_m(tree, np.array([1.0, 0.0]), np.array([5.0, 0.0]), cfg) == pytest.approx(1.0, abs=0.1)
    assert seen_length_m(tree, np.array([3.0, 0.0]), np.array([5.0, 0.0]), cfg) == 0.0
    # a hole wider than scan_gap_m is not over the scan
    holed = PATCH[np.abs(PATCH[:, 0]) > 0.5]
    assert seen_length_m(cKDTree(holed), np.array([-1.0, 0.0]), np.array([1.0, 0.0]), cfg) == pytest.approx(
        1.0, abs=0.15)


def test_the_config_is_checked():
    for bad in ({"seen_log_min_length_m": 0.0}, {"scan_gap_m": -0.1}):
        with pytest.raises(ValueError, match="CoverageConfig"):
            CoverageConfig(**bad)
    assert ReconstructConfig().coverage == CoverageConfig()


def test_each_log_knows_the_share_of_its_axis_over_the_scan():
    ends = {"log0": (fixed(-1.5, 0.0), fixed(1.5, 0.0)), "log1": (fixed(0.5, 0.5), fixed(3.6, 0.5)),
            "log2": (None, fixed(0.0, -0.5))}
    shares = check_coverage(PATCH, ends, 1.0).over_scan_share
    assert shares["log0"] == pytest.approx(1.0)
    assert shares["log1"] == pytest.approx(1.5 / 3.1, abs=0.04)
    assert "log2" not in shares  # one surveyed end: no axis


def test_a_log_running_out_of_the_scan_is_not_a_piece_of_a_hidden_log():
    """A scan log seen over 1.0 m of a 2.4 m survey axis, its far point 30 cm off the ridge's line: a piece of a
    log hidden under others when the whole axis lies over the scan (its survey points set its axis), but not when
    only 1.2 m of it does (the rest lies beyond the scan's edge: the ridge is what the scan could show, and it sets
    the axis, against which the far point is then judged)."""
    from reconstruct.fitting.fuse_config import FuseConfig
    from reconstruct.fitting.matching import a_piece_of_a_surveyed_log, prior_axis
    from reconstruct.fitting.scan_logs import ScanLog

    ridge = ScanLog(np.array([0.0, 0.0, 0.1]), np.array([1.0, 0.0, 0.1]), 0.08, 1.0, 10.0)
    ends = (fixed(0.0, 0.0, 0.1), fixed(2.4, 0.3, 0.1))
    cfg = FuseConfig()
    assert a_piece_of_a_surveyed_log(ends, ridge, cfg)
    assert not a_piece_of_a_surveyed_log(ends, ridge, cfg, over_scan_share=0.5)
    a, b, _ = prior_axis(ends, ridge, False, cfg, over_scan_share=0.5)
    assert abs(b[1]) < 1e-9  # on the ridge's line, not through the far point
    with pytest.raises(ValueError, match="over_scan_share"):
        a_piece_of_a_surveyed_log(ends, ridge, cfg, over_scan_share=1.5)
