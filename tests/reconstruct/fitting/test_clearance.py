"""reconstruct.fitting.clearance: a log the twin's pile check refuses has its uncertain ends moved
within their sigma (or a contradicted end put at its survey point) before the pile is given up."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruct.errors import SeparationError
from reconstruct.fitting.clearance import ClearanceConfig, clear_pile
from reconstruct.fitting.fit import FitConfig, separate_logs
from synth.scene.pile import LogSpec, PileSpec, StumpSpec, TerrainSpec

N = 32
FLAT = TerrainSpec(extent_m=5.0, resolution=N, amplitude_m=0.0, heights_m=tuple(tuple(0.0 for _ in range(N)) for _ in range(N)))


def _end(pos, source="fixed", sigma=0.012, contradicted=False, gnss=None, fix="rtk_fixed"):
    return {"position_m": list(pos), "sigma_m": sigma, "sigma_along_m": sigma, "source": source, "scan": "seen",
            "gnss_fix": fix, "contradicted": contradicted, "gnss_position_m": None if gnss is None else list(gnss),
            "gnss_sigma_m": None if gnss is None else 0.02, "gnss_residual_m": None}


def _check(pile):
    return separate_logs(pile, FitConfig())


def test_a_contradicted_end_that_puts_its_log_into_a_stump_goes_to_its_survey_point():
    """Twin scans 1100166 / 1100179: the scan's walk along a log ran on over a stump beside its end
    and was trusted over the end's RTK fixed point; the pile check refused the log in the stump."""
    stump = StumpSpec(position_m=(1.45, 0.0), height_m=0.4, bottom_radius_m=0.2, top_radius_m=0.18)
    log = LogSpec.from_endpoints((-1.0, 0.0, 0.07), (1.45, 0.0, 0.07), 0.14)  # its end b inside the stump
    pile = PileSpec(terrain=FLAT, logs=(log,), stumps=(stump,))
    ends = [[_end((-1.0, 0.0, 0.07)), _end((1.45, 0.0, 0.07), "scan", 0.015, True, gnss=(1.1, 0.01, 0.07))]]
    with pytest.raises(SeparationError):
        _check(pile)
    c = clear_pile(pile, ends, _check)
    out, notes, moved, at_survey = c.pile, c.end_moves, c.moved, c.at_survey
    butt, top = out.logs[0].endpoints_m()
    assert np.linalg.norm(top - np.array([1.1, 0.01, 0.07])) < 0.03, top
    assert np.linalg.norm(butt - np.array([-1.0, 0.0, 0.07])) < 0.03, butt
    e = at_survey[(0, 1)]
    assert e["source"] == "fixed" and not e["contradicted"] and e["sigma_m"] == 0.02
    assert "obstacle 0" in e["pile_check"], e
    assert any("end b placed at its survey point" in n for n in notes), notes
    assert moved[0] > 0.3, moved


def test_a_float_end_inside_a_neighbour_moves_within_its_sigma():
    """Twin scans 1100119 / 1100129: a log seen in part under others, its hidden end placed at an RTK
    float point (+-20 cm) that lies inside a neighbour: the end moves the least it must, in sigma."""
    ground = LogSpec.from_endpoints((-1.2, 0.0, 0.075), (1.2, 0.0, 0.075), 0.15)
    across = LogSpec.from_endpoints((-1.0, 0.8, 0.07), (0.9, -0.05, 0.07), 0.14)  # its end b inside `ground`
    pile = PileSpec(terrain=FLAT, logs=(ground, across))
    ends = [[_end((-1.2, 0, 0.075)), _end((1.2, 0, 0.075))],
            [_end((-1.0, 0.8, 0.07)), _end((0.9, -0.05, 0.07), "float", 0.2, fix="rtk_float", gnss=(0.9, -0.05, 0.07))]]
    with pytest.raises(SeparationError):
        _check(pile)
    c = clear_pile(pile, ends, _check)
    out, notes, moved, at_survey = c.pile, c.end_moves, c.moved, c.at_survey
    butt, top = out.logs[1].endpoints_m()
    assert np.linalg.norm(butt - np.array([-1.0, 0.8, 0.07])) < 0.03  # the sure end stays
    shift = float(np.linalg.norm(top - np.array([0.9, -0.05, 0.07])))
    assert 0.05 < shift < 2.5 * 0.2 * 1.5, (shift, notes)
    assert moved[1] >= shift - 0.03 and moved[0] < 0.03, moved
    assert any("log 1: end b (float, +-20 cm) moved" in n and "log 0" in n for n in notes), notes
    assert not at_survey


def test_a_log_of_sure_ends_that_the_check_refuses_stays_refused():
    ground = LogSpec.from_endpoints((-1.2, 0.0, 0.075), (1.2, 0.0, 0.075), 0.15)
    across = LogSpec.from_endpoints((-1.0, 0.8, 0.07), (0.9, -0.05, 0.07), 0.14)
    pile = PileSpec(terrain=FLAT, logs=(ground, across))
    ends = [[_end((-1.2, 0, 0.075)), _end((1.2, 0, 0.075))], [_end((-1.0, 0.8, 0.07)), _end((0.9, -0.05, 0.07))]]
    with pytest.raises(SeparationError, match="would have to move"):
        clear_pile(pile, ends, _check)
    with pytest.raises(SeparationError):  # nothing to move either without the ends' estimates
        clear_pile(pile, [[], []], _check)


def test_a_pile_the_check_accepts_is_left_as_it_is():
    ground = LogSpec.from_endpoints((-1.2, 0.0, 0.075), (1.2, 0.0, 0.075), 0.15)
    beside = LogSpec.from_endpoints((-1.2, 0.5, 0.075), (1.2, 0.5, 0.075), 0.15)
    pile = PileSpec(terrain=FLAT, logs=(ground, beside))
    ends = [[_end(p) for p in lg.endpoints_m()] for lg in pile.logs]
    ends[1][1].update(source="float", sigma_m=0.25, sigma_along_m=0.25)
    c = clear_pile(pile, ends, _check)
    out, notes, moved, at_survey = c.pile, c.end_moves, c.moved, c.at_survey
    assert out.logs == pile.logs and moved == [0.0, 0.0] and not at_survey and not notes


def test_clearance_config_is_validated():
    for bad in ({"max_sigma": 0}, {"min_sigma_m": -1}, {"residual_depth_m": -0.1}, {"max_rounds": -1}):
        with pytest.raises(ValueError):
            ClearanceConfig(**bad)
