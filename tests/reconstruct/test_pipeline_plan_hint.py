"""A survey point outside the scan (RegistrationError) names the scan plan that would cover it."""

from __future__ import annotations

import re

import numpy as np
import pytest

from reconstruct.errors import RegistrationError
from reconstruct.fitting.fuse import SurveyEnd
from reconstruct.fitting.coverage import check_coverage
from reconstruct.scan.plan import ScanPlan, ScanPlanConfig, covering_plan_hint


def fixed(x, y, z=100.2) -> SurveyEnd:
    return SurveyEnd(np.array([x, y, z]), 0.01, 0.02, "rtk_fixed")


def test_a_point_outside_the_scan_names_the_plan_that_covers_it():
    """Scan points over a 4 x 2.5 m patch; a log 1.35-1.5 m past it along y, the scan seeing none of it: the
    refusal stands and names a grid bigger than 2x2 whose footprint covers every surveyed end by the margin."""
    g = np.mgrid[-2:2:0.05, -1.25:1.25:0.05].reshape(2, -1).T
    ends = {"log0": (fixed(-1.5, 0.0), fixed(1.5, 0.0)), "log1": (fixed(-1.4, 2.6), fixed(1.4, 2.75))}
    with pytest.raises(RegistrationError) as exc:
        check_coverage(g, ends, 1.0)
    msg = str(exc.value)
    assert "'log1' end 'b'" in msg and "\n" not in msg
    m = re.search(r": (\d)x(\d) pairs .* centred at site E, N \((-?[\d.]+), (-?[\d.]+)\) m, "
                  r"along (-?\d+) deg covers", msg)
    assert m, msg
    grid = (int(m.group(1)), int(m.group(2)))
    assert grid[0] * grid[1] > 4
    plan = ScanPlan(grid, (float(m.group(3)), float(m.group(4))), np.radians(float(m.group(5))), (1.4, 1.0), 3.0, 0.3)
    pts = np.array([e.position_m for pair in ends.values() for e in pair])
    pts[:, 2] -= pts[:, 2].min()
    cfg = ScanPlanConfig()
    assert plan.slack_m(pts, cfg).min() >= cfg.margin_m - 0.01  # the printed centre and angle are rounded


def test_no_hint_where_no_plan_covers_the_survey():
    """A point 60 m off (a wrong log id): no grid covers it, the refusal says nothing of a plan."""
    assert covering_plan_hint({"log0": (fixed(0, 0), fixed(60.0, 0))}) == ""
    assert covering_plan_hint({"log0": (None, None)}) == ""
