"""Radius states as the rescue of a refused pile (reconstruct.fitting.joint_rescue, JointConfig.radius_rescue,
joint revision 20): the pile is settled with its fitted radii, and only a refusal with each radius a state; the
rescue stands only when the pile it makes has every end sure and its survey points kept. Hand-made logs on flat
ground, each end on an RTK fixed point, through the joint settler."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from reconstruct.errors import SeparationError
from reconstruct.fitting.fit_config import LogFit
from reconstruct.fitting.joint_config import JOINT_REVISION, JointConfig
from reconstruct.fitting.joint_rescue import rescue_doubts
from reconstruct.fitting.joint_settle import JointSettler
from reconstruct.fitting.survey_points import SurveyEnd
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec

CFG = JointConfig()  # revision 20: radius states on, as a rescue
FIXED_RADII = JointConfig(radius_states=False)  # revision 18
EVERYWHERE = JointConfig(radius_rescue=False)  # the tried revision 19: radius states on every pile
R = 0.1  # the logs' true radius [m]
GAP_M = 0.165  # the logs' axes apart: the true prisms clear at their best roll [m]
THICK_M = 0.03  # log 0 fitted this much too thick in radius: into the ground past what its points allow [m]
FIXED_H_M, FIXED_V_M = 0.0075, 0.015  # an RTK fixed point's sigma per horizontal axis and vertical [m]
SURE_M = 0.015  # an end placed on its fixed point: its sigma [m]
TOL = 0.01  # the twin's tolerance [m]
FLAT = TerrainSpec(extent_m=4.0, resolution=16, heights_m=tuple(tuple(0.0 for _ in range(16)) for _ in range(16)))


def _log(y: float, r: float) -> LogSpec:
    """A 2 m log along x whose top is at 2 R (where the scan sees it), of radius ``r``."""
    return LogSpec.from_endpoints((-1.0, y, 2 * R - r), (1.0, y, 2 * R - r), 2 * r)


def _pile(thick_m: float) -> PileSpec:
    """Log 0 fitted ``thick_m`` too thick in radius beside log 1, both where the scan sees their tops."""
    return PileSpec(terrain=FLAT, logs=(_log(0.0, R + thick_m), _log(GAP_M, R)))


def _surveyed(pile: PileSpec, weak: tuple[int, int] | None = None, wrong: tuple[int, int] | None = None
              ) -> tuple[list[LogFit], dict]:
    """Each log's fit report (its ends on its fixed points, ``SURE_M``; the end ``weak`` (log, end) at 20 cm,
    the end ``wrong`` with its point called wrong) and its survey points, at its ends."""
    fits, survey = [], {}
    for k, log in enumerate(pile.logs):
        butt, top = log.endpoints_m()
        ends = [{"position_m": [float(v) for v in p], "sigma_m": 0.20 if (k, j) == weak else SURE_M,
                 "contradicted": (k, j) == wrong, "source": "fixed", "scan": "seen"}
                for j, p in enumerate((butt, top))]
        fits.append(LogFit(f"log{k}", k, tuple(butt), tuple(top), log.length_m, log.diameter_m, None, 100, 0.005,
                           1.0, 0.0, 0.0, 0.0, False, ends=ends, fit="scan"))
        survey[f"log{k}"] = tuple(SurveyEnd(np.asarray(p, dtype=float), FIXED_H_M, FIXED_V_M, "rtk_fixed")
                                  for p in (butt, top))
    return fits, survey


def _settler(survey: dict, cfg: JointConfig) -> JointSettler:
    return JointSettler(survey, {}, cfg, TOL, 12)


def _thinned_m(before: PileSpec, after: PileSpec, k: int) -> float:
    return (before.logs[k].diameter_m - after.logs[k].diameter_m) / 2


def test_a_pile_its_fitted_radii_cannot_clear_is_rescued_by_thinning_and_says_so():
    pile = _pile(THICK_M)
    fits, survey = _surveyed(pile)
    with pytest.raises(SeparationError, match="would have to move"):
        _settler(survey, FIXED_RADII)(pile, fits)
    out = _settler(survey, CFG)(pile, fits)
    assert _thinned_m(pile, out.pile, 0) > 0.005
    assert out.notes[0].startswith("the fitted radii could not be met (log 0 would have to move")
    assert any(n.startswith("log 0 thinned") for n in out.notes)


def test_a_pile_its_fitted_radii_clear_is_settled_with_them_as_revision_18_does():
    pile = _pile(0.008)  # a few mm too thick: the fitted radii clear it by moving the logs within their sigmas
    fits, survey = _surveyed(pile)
    out = _settler(survey, CFG)(pile, fits)
    assert out.pile == _settler(survey, FIXED_RADII)(pile, fits).pile
    assert not any("thinned" in n or "fitted radii" in n for n in out.notes)
    everywhere = _settler(survey, EVERYWHERE)(pile, fits)  # revision 19 thins it even here
    assert _thinned_m(pile, everywhere.pile, 0) > 0.001


@pytest.mark.parametrize("doubt, says", [({"wrong": (1, 0)}, "log1 end a's survey point called wrong"),
                                         ({"weak": (0, 1)}, "log0 end b +-20 cm")])
def test_a_rescue_whose_pile_doubts_its_survey_or_an_end_is_refused_as_the_fitted_radii_refused_it(doubt, says):
    pile = _pile(THICK_M)
    fits, survey = _surveyed(pile, **doubt)
    with pytest.raises(SeparationError, match=f"would have to move.*the refusal stands") as err:
        _settler(survey, CFG)(pile, fits)
    assert says in str(err.value) and err.value.logs[0] in (0, 1)
    assert isinstance(err.value.__cause__, SeparationError)  # the fitted radii's refusal, chained
    _settler(survey, EVERYWHERE)(pile, fits)  # revision 19 kept it


def test_an_end_the_pile_check_moved_is_a_doubt_by_its_sigma_grown_by_the_move():
    pile = _pile(0.0)
    fits, survey = _surveyed(pile)
    settled = _settler(survey, FIXED_RADII)(pile, fits)
    assert rescue_doubts(settled, fits, survey, CFG) == []
    raised = LogSpec.from_endpoints((-1.0, 0.0, R + 0.3), (1.0, 0.0, R + 0.3), 2 * R)  # 30 cm over its points
    shifted = replace(settled, pile=pile.with_logs((raised, pile.logs[1])))
    assert rescue_doubts(shifted, fits, survey, CFG) == ["log0 end a +-30 cm", "log0 end b +-30 cm"]  # grown by it


def test_a_rescue_that_still_moves_a_log_past_its_ends_sigma_is_refused():
    pile = _pile(0.05)  # 10 cm too thick: thinned to its floor, then moved 6 cm, its ends no surer than that
    fits, survey = _surveyed(pile)
    with pytest.raises(SeparationError, match=r"log0 end a \+-\d+ cm; log0 end b .*the refusal stands"):
        _settler(survey, CFG)(pile, fits)


def test_revision_20_rescues_with_radius_states_and_the_switches_are_checked():
    assert JOINT_REVISION == 20
    assert CFG.radius_states and CFG.radius_rescue and not CFG.view_test
    for name in ("radius_states", "radius_rescue"):
        with pytest.raises(ValueError, match=name):
            JointConfig(**{name: 1})
