"""Each log's radius as a state of the joint pile estimate (reconstruct.fitting.joint_radius,
JointConfig.radius_states): a log fitted too thick in a packed pile is thinned within its own radius sigma,
its top kept, instead of pushing its neighbour or being refused; a radius its scan holds tightly is not.
Hand-made logs on flat ground; the twin checks each settled pile."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from reconstruct.errors import SeparationError
from reconstruct.fitting.fit_config import LogFit
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_radius import MIN_RADIUS_M, radius_notes, radius_segment, resized_log
from reconstruct.fitting.joint_contact import Segment
from reconstruct.fitting.joint_settle import JointSettler, LogEvidence, _Problem, settle_pile, survey_pull
from synth.scene.pile import LogSpec, PileSpec, StumpSpec, TerrainSpec

OFF = JointConfig(radius_states=False)
ON = JointConfig(radius_states=True)
R = 0.1  # the logs' true radius [m]
THICK_M = 0.02  # log 0 fitted 4 cm too thick: its radius 2 cm too big, its seen top where it truly is [m]
GAP_M = 0.165  # the logs' axes apart: the true prisms clear at their best roll, the thick one's do not [m]
LOOSE_M = 0.025  # a radius the scan holds loosely (a top arc between neighbours) [m]
TIGHT_M = 0.003  # a radius the scan holds tightly (both flanks seen) [m]
FIXED_SIGMA_M = 0.0106  # an RTK fixed point's sigma per axis with the scan pose's [m]
TOL = 0.01  # the twin's tolerance [m]
FLAT = TerrainSpec(extent_m=4.0, resolution=16, heights_m=tuple(tuple(0.0 for _ in range(16)) for _ in range(16)))


def _log(y: float, r: float) -> LogSpec:
    """A 2 m log along x whose top is at 2 R (where the scan sees it), of radius ``r``."""
    z = 2 * R - r
    return LogSpec.from_endpoints((-1.0, y, z), (1.0, y, z), 2 * r)


def _pile(thick_m: float = THICK_M) -> PileSpec:
    return PileSpec(terrain=FLAT, logs=(_log(0.0, R + thick_m), _log(GAP_M, R)))


def _pinned(log: LogSpec, sigma_radius_m: float | None) -> LogEvidence:
    """A scan-placed log with an RTK fixed point on each end, on its axis, and its radius's sigma."""
    pulls = tuple(survey_pull(log, p, FIXED_SIGMA_M, FIXED_SIGMA_M) for p in log.endpoints_m())
    return LogEvidence(OFF.settle_scan_sigma_m, OFF.settle_scan_sigma_m, pulls, None, sigma_radius_m)


def _evidence(pile: PileSpec, thick_sigma_m: float) -> list[LogEvidence]:
    return [_pinned(pile.logs[0], thick_sigma_m), _pinned(pile.logs[1], TIGHT_M)]


def _axis(log: LogSpec) -> np.ndarray:
    return np.mean(log.endpoints_m(), axis=0)


def _twin_accepts(pile: PileSpec) -> bool:
    from synth.physics.world import World

    with World(pile, visuals=False) as world:
        return not world.penetrations(TOL)


def test_a_log_fitted_too_thick_against_its_neighbour_is_thinned_within_its_sigma_its_top_kept():
    pile = _pile()
    out, _ = settle_pile(pile, _evidence(pile, LOOSE_M), ON, TOL, 12)
    thick, neighbour = out.pile.logs
    thinned = (pile.logs[0].diameter_m - thick.diameter_m) / 2
    assert 0.01 < thinned < LOOSE_M  # thinned, within its sigma
    top = _axis(thick)[2] + thick.diameter_m / 2
    assert top == pytest.approx(2 * R, abs=1e-3)  # its top kept: its axis raised by what it lost
    assert abs(_axis(thick)[1]) < 0.003 and out.moved[0] < 0.003  # kept where its fixed points are
    assert np.linalg.norm(_axis(neighbour) - _axis(pile.logs[1])) < 0.002  # the neighbour not pushed
    assert neighbour.diameter_m == pytest.approx(2 * R, abs=1e-3)  # nor thinned: its radius is held tightly
    assert any(n.startswith("log 0 thinned") and "more than its sigma" not in n for n in out.notes)
    assert _twin_accepts(out.pile)
    with pytest.raises(SeparationError, match="log 0 would have to move"):  # revision 13's fixed radii
        settle_pile(pile, _evidence(pile, LOOSE_M), OFF, TOL, 12)


def test_the_radius_states_thin_it_where_they_are_on_and_the_default_has_them_on_as_a_rescue():
    pile = _pile()
    out, _ = settle_pile(pile, _evidence(pile, LOOSE_M), ON, TOL, 12)
    assert 0.01 < (pile.logs[0].diameter_m - out.pile.logs[0].diameter_m) / 2 < LOOSE_M
    assert any(n.startswith("log 0 thinned") for n in out.notes)
    # on from revision 20, as the rescue of a refused pile only (joint_rescue; test_joint_rescue)
    assert JointConfig().radius_states is True and JointConfig().radius_rescue is True


def test_a_pinned_log_whose_radius_its_scan_holds_tightly_is_refused_as_before():
    pile = _pile()
    with pytest.raises(SeparationError, match=r"log 0 .*its radius \+-0\.3 cm"):
        settle_pile(pile, _evidence(pile, TIGHT_M), ON, TOL, 12)


def test_a_free_log_whose_radius_its_scan_holds_tightly_is_hardly_thinned_and_moves_as_before():
    pile = _pile()
    ev = [LogEvidence(OFF.settle_scan_sigma_m, OFF.settle_scan_sigma_m, (), None, TIGHT_M),
          _pinned(pile.logs[1], TIGHT_M)]
    out, _ = settle_pile(pile, ev, ON, TOL, 12)
    before, _ = settle_pile(pile, ev, OFF, TOL, 12)
    assert before.moved[0] > 0.01  # lifted off the ground and away from its neighbour
    assert (pile.logs[0].diameter_m - out.pile.logs[0].diameter_m) / 2 < 2 * TIGHT_M  # of the 2 cm too thick
    # moved about as with fixed radii (less by twice its thinning: its underside rises that, its top kept)
    assert out.moved[0] == pytest.approx(before.moved[0], abs=0.008)
    loose = settle_pile(pile, [replace(ev[0], sigma_radius_m=LOOSE_M), ev[1]], ON, TOL, 12)[0]
    assert loose.moved[0] < 0.5 * before.moved[0]  # where a loose radius is thinned instead
    assert _twin_accepts(out.pile)


def test_a_log_thinned_past_its_sigma_is_kept_and_said_to_be():
    pile = _pile(thick_m=0.03)  # 6 cm too thick: 23 % of its radius off
    out, _ = settle_pile(pile, _evidence(pile, LOOSE_M), ON, TOL, 12)
    thinned = (pile.logs[0].diameter_m - out.pile.logs[0].diameter_m) / 2
    assert thinned > LOOSE_M and out.moved[0] < 0.005
    assert any(n.startswith("log 0 thinned") and "more than its sigma" in n for n in out.notes)
    assert _twin_accepts(out.pile)


def test_a_log_thinned_more_than_its_sigma_is_said_to_be():
    logs = [_log(0.0, R), _log(1.0, R)]
    notes = radius_notes(np.array([-0.03, -0.0105, 0.0004]), [0.02, 0.02, 0.02], logs + [logs[0]])
    assert notes[0] == ("log 0 thinned 60.0 mm to 14.0 cm thick, its top kept (1.5 sigma of its scan radius, "
                        "+-2.0 cm, more than its sigma: its scan fit is too thick)")
    assert "more than its sigma" not in notes[1] and len(notes) == 2


def test_a_resized_log_keeps_its_top_and_taper_and_is_never_thinner_than_its_floor():
    s = Segment(np.array([0.0, 0.0, 0.12]), np.array([2.0, 0.0, 0.12]), 0.12, 0.10)
    t = radius_segment(s, -0.02, ON.radius_min_share)
    assert (t.ra, t.rb) == pytest.approx((0.10, 0.08))
    assert t.a[2] + t.ra == pytest.approx(s.a[2] + s.ra) and t.b[2] + t.rb == pytest.approx(s.b[2] + s.rb)
    assert (radius_segment(s, -0.5, 0.6).ra, radius_segment(s, -0.5, 0.6).rb) == pytest.approx((0.072, 0.06))
    assert radius_segment(s, -0.5, 0.01).rb == MIN_RADIUS_M
    tapered = LogSpec.from_endpoints((0.0, 0.0, 0.1), (2.0, 0.0, 0.1), 0.24, 0.20)
    thin = resized_log(tapered, -0.02, ON.radius_min_share)
    assert (thin.diameter_m, thin.top_d_m) == pytest.approx((0.20, 0.16))
    assert resized_log(tapered, -0.5, 0.6).diameter_m == pytest.approx(0.6 * 0.24)
    assert resized_log(tapered, 0.0, 0.6) is tapered


def test_a_log_that_only_clears_thinned_past_its_floor_is_refused():
    pile = _pile(thick_m=0.03)  # needs 23 % of its radius off; at most 10 % allowed here
    with pytest.raises(SeparationError, match="log 0 would have to move"):
        settle_pile(pile, _evidence(pile, 0.03), JointConfig(radius_states=True, radius_min_share=0.9), TOL, 12)
    with pytest.raises(ValueError, match="radius_min_share"):
        JointConfig(radius_min_share=1.0)


def test_a_scan_fitted_log_s_radius_sigma_is_its_scan_s_and_a_placed_log_s_the_prior():
    log = _log(0.0, R)
    rng = np.random.default_rng(0)
    x, ang = rng.uniform(-0.9, 0.9, 3000), rng.uniform(-0.5, 0.5, 3000)  # its top arc, +-30 deg
    P = np.column_stack([x, R * np.sin(ang), R + R * np.cos(ang) + rng.normal(0, 0.002, 3000)])
    settler = JointSettler({}, {}, ON, TOL, 12, points=P)
    butt, top = log.endpoints_m()
    fit = LogFit("log1", 0, tuple(butt), tuple(top), log.length_m, log.diameter_m, None, 100, 0.005, 1.0,
                 0.0, 0.0, 0.0, False, ends=[], fit="scan")
    ev = settler.evidence(log, fit, P)
    assert ev.sigma_radius_m == settler.sigmas["log1"].radius_m
    assert ev.sigma_radius_m > 0.01  # a top arc leaves the radius loose
    placed = settler.evidence(log, LogFit(**{**fit.__dict__, "fit": "partial"}), None)
    assert placed.sigma_radius_m is None
    assert _Problem(PileSpec(terrain=FLAT, logs=(log,)), [placed], ON).radius_sigmas[0] == ON.sigma_radius_prior_m


def test_the_settle_jacobian_with_radius_states_is_scipys_forward_difference():
    from scipy.optimize._numdiff import approx_derivative

    stump = StumpSpec(position_m=(0.0, -0.25), height_m=0.5, bottom_radius_m=0.2, top_radius_m=0.2)
    pile = PileSpec(terrain=FLAT, logs=_pile().logs, stumps=(stump,))
    ev = _evidence(pile, LOOSE_M)
    prob = _Problem(pile, ev, ON, [0.02])
    x = np.random.default_rng(3).normal(0.0, 0.5, 4 * 2 + 3 + 2)
    prob.terms = prob.bodies.terms(prob.segments(x), ON.contact_reach_m)
    assert {t.kind for t in prob.terms} == {"log", "obstacle", "terrain"}
    for contacts in (False, True):
        J = prob.jacobian(x, contacts)
        assert np.abs(J[:, -2:]).sum() > 0
        assert np.array_equal(J, approx_derivative(prob.residuals, x, method="2-point", args=(contacts,)))


def test_a_log_s_refusal_cost_counts_the_radius_prior_of_each_neighbour_it_touches():
    pile = _pile()
    far = PileSpec(terrain=FLAT, logs=(pile.logs[0], _log(1.0, R)))
    for p, shared in ((pile, True), (far, False)):
        prob = _Problem(p, _evidence(p, LOOSE_M), ON)
        x = np.zeros(len(prob.scale))
        prob.terms = prob.bodies.terms(prob.segments(x), ON.contact_reach_m)
        own = float(np.sum(prob.evidence_residuals(x, 0) ** 2))
        x[-1] = 2.0  # log 1 thinned (or thickened) 2 sigma
        assert prob.cost(x, 0) == pytest.approx(own + (4.0 if shared else 0.0))
        assert prob.cost(x, 1) == pytest.approx(4.0)  # its own prior
