"""The joint estimator's pile check (reconstruct.fitting.joint_settle, joint_contact): every log's pose
correction weighed against its evidence and the other bodies in one least-squares estimate; the refusal is a
log the bodies move farther than its evidence allows. Hand-made logs on flat ground; the twin checks each."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from reconstruct.errors import SeparationError
from reconstruct.fitting.fit_config import LogFit
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_contact import ROLL_SHARE
from reconstruct.fitting.joint_settle import (AlongPrior, JointSettler, LogEvidence, _Problem, along_priors,
                                              settle_pile, survey_pull)
from reconstruct.fitting.survey_points import SurveyEnd
from synth.scene.pile import LogSpec, PileSpec, RockSpec, StumpSpec, TerrainSpec

CFG = JointConfig(radius_states=False)  # the pose settle with fixed radii (radius states: test_joint_radius)
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


# -- each end's place along its log in the estimate (JointConfig.along_ends) --
PLACED_IN_PART_M = 0.05  # a log placed in part on its survey axis: known across to ~5 cm [m]


def _t_into_a_crossing_log(top_along: AlongPrior) -> tuple[PileSpec, list[LogEvidence]]:
    """Log 0 along x, its top end (x = 1 m) 14 cm into log 1, which lies across it (along y, its axis 6 cm past
    that end): log 0 is held across by its scan (1 cm), its butt along by a seen end (1 cm); its top along
    by ``top_along``; log 1, placed in part, is held 5 cm every way."""
    a = _log(0.0)
    b = LogSpec.from_endpoints((1.06, -1.0, R), (1.06, 1.0, R), 2 * R)
    seen = AlongPrior(0.01, 0.01)
    ev_a = LogEvidence(0.01, 0.01, (), (seen, top_along))
    ev_b = LogEvidence(PLACED_IN_PART_M, PLACED_IN_PART_M, (), (AlongPrior(PLACED_IN_PART_M, PLACED_IN_PART_M),) * 2)
    return PileSpec(terrain=FLAT, logs=(a, b)), [ev_a, ev_b]


def _top_x(log: LogSpec) -> float:
    return float(max(p[0] for p in log.endpoints_m()))


WEAK_INWARD = AlongPrior(0.10, 0.01)  # an end whose top the scan does not see inside (under another log), the
#                                       ground seen past it: free toward the log's middle, held outward


def test_a_weakly_seen_end_pressed_into_a_neighbour_is_moved_back_along_its_axis():
    pile, ev = _t_into_a_crossing_log(WEAK_INWARD)
    out, _ = settle_pile(pile, ev, CFG, TOL, 12)
    a, b = out.pile.logs
    assert _top_x(a) < 1.0 - 0.06  # shortened at its weak end by most of what clearing takes
    assert abs(_axis_y(a)) < 0.005 and abs(min(p[0] for p in a.endpoints_m()) + 1.0) < 0.005  # not across, not its butt
    assert abs(float(np.mean([p[0] for p in b.endpoints_m()])) - 1.06) < 0.02  # the neighbour hardly gives way
    assert _twin_accepts(out.pile)
    assert "in along it" in " ".join(out.notes)
    # without the ends along in the estimate the same pile moves the neighbour instead, at 2 sigma of its evidence
    out4, _ = settle_pile(pile, [replace(e, along=None) for e in ev], CFG, TOL, 12)
    assert _top_x(out4.pile.logs[0]) == pytest.approx(1.0, abs=1e-6)


def test_an_rtk_fixed_end_pressed_into_a_neighbour_is_not_moved_along_its_axis():
    # the same pile with the top end on an RTK fixed point: the neighbour, placed in part, gives way instead
    pile, ev = _t_into_a_crossing_log(AlongPrior(FIXED_SIGMA_M, FIXED_SIGMA_M))
    out, _ = settle_pile(pile, ev, CFG, TOL, 12)
    a, b = out.pile.logs
    assert _top_x(a) > 1.0 - 0.01
    assert float(np.mean([p[0] for p in b.endpoints_m()])) - 1.06 > 0.06
    assert _twin_accepts(out.pile)


def test_an_end_pinned_along_at_both_logs_is_refused_naming_its_sigma_along():
    pile, ev = _t_into_a_crossing_log(AlongPrior(FIXED_SIGMA_M, FIXED_SIGMA_M))
    ev[1] = _pinned_across(pile.logs[1])
    with pytest.raises(SeparationError) as err:
        settle_pile(pile, ev, CFG, TOL, 12)
    assert "along toward its middle" in str(err.value) and "\n" not in str(err.value)


def _pinned_across(log: LogSpec) -> LogEvidence:
    """``_pinned`` with its ends' places along held as surely as its points hold them."""
    return replace(_pinned(log), along=(AlongPrior(FIXED_SIGMA_M, FIXED_SIGMA_M),) * 2)


def _crossing_fits(pile: PileSpec, top_along: tuple[float, float]) -> list[LogFit]:
    """The fits of :func:`_t_into_a_crossing_log`'s logs as the joint end placer leaves them: log 0's butt seen,
    its top's along sigmas ``top_along`` (inward, outward); log 1 placed in part."""
    fits = [_fit("log0", 0, pile.logs[0], False), _fit("log1", 1, pile.logs[1], False)]
    for e, (s_in, s_out) in zip(fits[0].ends, ((0.01, 0.01), top_along)):
        e.update(sigma_along_in_m=s_in, sigma_along_out_m=s_out)
    for e in fits[1].ends:
        e.update(sigma_along_in_m=PLACED_IN_PART_M, sigma_along_out_m=PLACED_IN_PART_M)
    fits[1].fit = "partial"
    return fits


def test_the_settler_shortens_a_log_by_its_ends_own_along_sigmas_and_not_with_along_ends_off():
    pile, _ = _t_into_a_crossing_log(WEAK_INWARD)
    lateral = {"log0": 0.01, "log1": PLACED_IN_PART_M}
    on = JointConfig(along_ends=True)  # off by default (docs/reconstruction.md, "Joint revision 12")
    weak = JointSettler({}, lateral, on, TOL, 12)(pile, _crossing_fits(pile, (0.10, 0.01)))
    assert _top_x(weak.pile.logs[0]) < 1.0 - 0.06
    fixed = JointSettler({}, lateral, on, TOL, 12)(pile, _crossing_fits(pile, (FIXED_SIGMA_M, FIXED_SIGMA_M)))
    assert _top_x(fixed.pile.logs[0]) > 1.0 - 0.01
    off = JointSettler({}, lateral, CFG, TOL, 12)(pile, _crossing_fits(pile, (0.10, 0.01)))
    assert _top_x(off.pile.logs[0]) == pytest.approx(1.0, abs=1e-6)


def test_the_along_priors_are_each_end_s_own_whichever_order_the_ends_come_in():
    log = _log(0.0)
    butt, top = log.endpoints_m()
    ends = [{"position_m": list(top), "sigma_along_in_m": 0.2, "sigma_along_out_m": 0.03},
            {"position_m": list(butt), "sigma_along_in_m": 0.01, "sigma_along_out_m": 0.02}]
    assert along_priors(log, ends, CFG) == (AlongPrior(0.01, 0.02), AlongPrior(0.2, 0.03))
    floor = AlongPrior(CFG.min_end_sigma_m, CFG.min_end_sigma_m)
    assert along_priors(log, None, CFG) == (floor, floor)


def test_the_settle_jacobian_is_scipys_forward_difference():
    from scipy.optimize._numdiff import approx_derivative

    pile, ev = _t_into_a_crossing_log(AlongPrior(0.10, 0.05))
    prob = _Problem(pile, ev, CFG)
    x = np.random.default_rng(0).normal(0.0, 1.0, 12)
    prob.terms = prob.bodies.terms(prob.segments(x), CFG.contact_reach_m)
    for contacts in (False, True):
        J = prob.jacobian(x, contacts)
        assert np.array_equal(J, approx_derivative(prob.residuals, x, method="2-point", args=(contacts,)))


def test_the_pile_parameters_are_checked():
    for name in ("settle_scan_sigma_m", "survey_loss_sigmas", "contact_sigma_m", "contact_reach_m", "refuse_sigma",
                 "twin_rounds", "run_on_inside_m", "run_below_inside_m", "run_outside_m", "run_on_outside_m",
                 "along_interval_sigmas"):
        with pytest.raises(ValueError, match=name):
            JointConfig(**{name: 0})
