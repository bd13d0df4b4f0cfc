"""The joint estimator's pile check (reconstruct.fitting.joint_settle, joint_contact): every log's pose
correction weighed against its evidence and the other bodies in one least-squares estimate; the refusal is a
log the bodies move farther than its evidence allows. Hand-made logs on flat ground; the twin checks each."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruct.errors import SeparationError
from reconstruct.fitting.fit_config import LogFit
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_contact import ROLL_SHARE
from reconstruct.fitting.joint_settle import JointSettler, LogEvidence, settle_pile, survey_pull
from reconstruct.fitting.survey_points import SurveyEnd
from synth.scene.pile import LogSpec, PileSpec, RockSpec, StumpSpec, TerrainSpec

CFG = JointConfig()
R = 0.1  # the logs' radius [m]
TOL = 0.01  # the twin's tolerance [m]
FIXED_SIGMA_M = 0.0106  # an RTK fixed point's sigma per axis with the scan pose's [m]
FLAT = TerrainSpec(extent_m=4.0, resolution=16, heights_m=tuple(tuple(0.0 for _ in range(16)) for _ in range(16)))


def _log(y: float, z: float = R) -> LogSpec:
    return LogSpec.from_endpoints((-1.0, y, z), (1.0, y, z), 2 * R)


def _pinned(log: LogSpec) -> LogEvidence:
    """A scan-placed log with an RTK fixed point on each end, on its axis."""
    return LogEvidence(CFG.settle_scan_sigma_m, CFG.settle_scan_sigma_m,
                       tuple(survey_pull(log, p, FIXED_SIGMA_M, FIXED_SIGMA_M) for p in log.endpoints_m()))


def _free() -> LogEvidence:
    return LogEvidence(CFG.settle_scan_sigma_m, CFG.settle_scan_sigma_m)


def _axis_y(log: LogSpec) -> float:
    return float(np.mean([p[1] for p in log.endpoints_m()]))


def _twin_accepts(pile: PileSpec) -> bool:
    from synth.physics.world import World

    with World(pile, visuals=False) as world:
        return not world.penetrations(TOL)


def test_two_interpenetrating_logs_are_pushed_apart_by_the_least_move_their_evidence_allows():
    # round surfaces 8 cm into each other (axes 12 cm apart, 20 cm thick): the prism's roll takes 3.8 cm of it
    a, b = _log(-0.06), _log(0.06)
    out, free = settle_pile(PileSpec(terrain=FLAT, logs=(a, b)), [_free(), _free()], CFG, TOL, 12)
    ya, yb = (_axis_y(lg) for lg in out.pile.logs)
    assert yb - ya == pytest.approx(2 * R * (1 - ROLL_SHARE), abs=1e-3)  # apart just as far as the prisms need
    assert -ya == pytest.approx(yb, abs=1e-3)  # the same evidence: each half the way
    assert out.moved == pytest.approx([0.021, 0.021], abs=1e-3) and len(out.notes) == 2
    assert [_axis_y(lg) for lg in out.pile.logs] != [_axis_y(a), _axis_y(b)]
    assert np.allclose([p for ends in free for p in ends], [p for lg in (a, b) for p in lg.endpoints_m()])
    assert _twin_accepts(out.pile)


def test_a_log_held_by_fixed_points_moves_less_than_its_free_neighbour():
    a, b = _log(-0.06), _log(0.06)
    out, _ = settle_pile(PileSpec(terrain=FLAT, logs=(a, b)), [_free(), _pinned(b)], CFG, TOL, 12)
    move_a, move_b = out.moved
    assert move_b < 0.5 * move_a  # the one its points hold gives way least
    assert move_a + move_b == pytest.approx(2 * R * (1 - ROLL_SHARE) - 0.12, abs=2e-3)  # together, the least
    assert _twin_accepts(out.pile)


def test_a_log_its_evidence_pins_inside_another_is_refused_with_one_line_naming_it():
    # axes 8 cm apart, both on RTK fixed points: clearing takes ~4 cm each, ~4 sigma of points 1 cm sure
    a, b = _log(-0.04), _log(0.04)
    with pytest.raises(SeparationError) as err:
        settle_pile(PileSpec(terrain=FLAT, logs=(a, b)), [_pinned(a), _pinned(b)], CFG, TOL, 12)
    msg = str(err.value)
    assert "\n" not in msg and "would have to move" in msg and "sigma" in msg
    assert sorted(err.value.logs) == [0, 1] and f"log {err.value.logs[0]} " in msg
    assert f"clear log {err.value.logs[1]}," in msg


def test_a_log_sunk_into_the_ground_is_lifted_and_one_in_a_stump_pushed_off_it():
    sunk = _log(0.0, z=R - 0.05)  # 5 cm under flat ground
    out, _ = settle_pile(PileSpec(terrain=FLAT, logs=(sunk,)), [_free()], CFG, TOL, 12)
    lifted = out.pile.logs[0]
    assert lifted.centre_m[2] - sunk.centre_m[2] == pytest.approx(0.05 - R * ROLL_SHARE, abs=2e-3)
    stump = StumpSpec(position_m=(0.0, 0.25), height_m=0.5, bottom_radius_m=0.2, top_radius_m=0.2)
    pile = PileSpec(terrain=FLAT, logs=(_log(0.0),), stumps=(stump,))  # 5 cm into the stump's side
    out, _ = settle_pile(pile, [_free()], CFG, TOL, 12)
    assert _axis_y(out.pile.logs[0]) == pytest.approx(-(0.05 - R * ROLL_SHARE), abs=3e-3)
    assert _twin_accepts(out.pile)


def test_a_log_through_a_rock_face_is_pushed_off_it():
    # a 80 x 80 x 40 cm block whose face cuts 5 cm into the log, none of its corners, edges' or faces' middles
    # within the log: only the face's plane shows it
    box = tuple((x, y, z) for x in (-0.4, 0.4) for y in (-0.4, 0.4) for z in (-0.2, 0.2))
    rock = RockSpec(position_m=(0.0, 0.45, 0.2), orientation=(0.0, 0.0, 0.0, 1.0), vertices_m=box)
    out, _ = settle_pile(PileSpec(terrain=FLAT, logs=(_log(0.0),), rocks=(rock,)), [_free()], CFG, TOL, 12)
    assert _axis_y(out.pile.logs[0]) == pytest.approx(-(0.05 - R * ROLL_SHARE), abs=3e-3)
    assert _twin_accepts(out.pile)


def _fit(log_id: str, index: int, log: LogSpec, contradicted: bool) -> LogFit:
    butt, top = log.endpoints_m()
    ends = [{"position_m": list(map(float, p)), "contradicted": contradicted} for p in (butt, top)]
    return LogFit(log_id, index, tuple(butt), tuple(top), log.length_m, log.diameter_m, None, 100, 0.005, 1.0,
                  0.0, 0.0, 0.0, False, ends=ends, fit="scan")


def test_the_settler_pulls_a_log_to_its_kept_points_and_lets_a_contradicted_one_go():
    log = _log(0.0)
    pts = tuple(SurveyEnd(p + np.array([0.0, 0.005, 0.0]), 0.01, 0.018, "rtk_fixed") for p in log.endpoints_m())
    pile = PileSpec(terrain=FLAT, logs=(log,))
    kept = JointSettler({"log1": pts}, {"log1": 0.02}, CFG, TOL, 12)(pile, [_fit("log1", 0, log, False)])
    y_kept = np.mean([e["position_m"][1] for e in kept.at_survey.values()])
    s_pt2 = 0.01 ** 2 + CFG.pose_sigma_m ** 2
    assert y_kept == pytest.approx(0.005 * CFG.settle_scan_sigma_m ** 2 / (CFG.settle_scan_sigma_m ** 2 + s_pt2), abs=2e-4)
    assert kept.moved[0] < 1e-6  # the points' pull is the estimate, not a move by the bodies
    dropped = JointSettler({"log1": pts}, {"log1": 0.02}, CFG, TOL, 12)(pile, [_fit("log1", 0, log, True)])
    assert all(abs(e["position_m"][1]) < 1e-6 for e in dropped.at_survey.values())


def test_the_pile_parameters_are_checked():
    for name in ("settle_scan_sigma_m", "survey_loss_sigmas", "contact_sigma_m", "contact_reach_m", "refuse_sigma",
                 "twin_rounds", "run_on_inside_m", "run_below_inside_m", "run_outside_m", "run_on_outside_m"):
        with pytest.raises(ValueError, match=name):
            JointConfig(**{name: 0})
