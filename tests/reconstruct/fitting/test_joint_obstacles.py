"""Obstacles as states of the joint pile estimate (reconstruct.fitting.joint_obstacles, JointConfig.obstacle_states):
each stump's or rock's sigma from its own scan points, and a contact shared by a log's evidence and the obstacle's.
Hand-made logs and a stump on flat ground; the twin checks each settled pile."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruct.errors import SeparationError
from reconstruct.fitting.fit_config import LogFit
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_contact import ROLL_SHARE, Bodies, Segment
from reconstruct.fitting.joint_obstacles import moved_obstacles, obstacle_sigma, obstacle_sigmas
from reconstruct.fitting.joint_settle import JointSettler, LogEvidence, _Problem, settle_pile
from reconstruct.fitting.survey_points import SurveyEnd
from synth.scene.pile import LogSpec, PileSpec, RockSpec, StumpSpec, TerrainSpec

CFG = JointConfig(radius_states=False)  # obstacle states with fixed radii (radius states: test_joint_radius)
R = 0.1  # the log's radius [m]
TOL = 0.01  # the twin's tolerance [m]
FLAT = TerrainSpec(extent_m=4.0, resolution=16, heights_m=tuple(tuple(0.0 for _ in range(16)) for _ in range(16)))
STUMP_Y_M = 0.25  # the stump's axis, beside the log lying along x at y = 0 [m]
FOUND_R_M = 0.22  # the stump as the scan found it: its side 7 cm into the log, 5.1 cm past the prism's roll [m]
INTO_M = FOUND_R_M + R - STUMP_Y_M - R * ROLL_SHARE  # how far past the roll [m]
STUMP_H_M = 0.5


def _log() -> LogSpec:
    return LogSpec.from_endpoints((-1.0, 0.0, R), (1.0, 0.0, R), 2 * R)


def _pile(radius_m: float = FOUND_R_M) -> PileSpec:
    stump = StumpSpec(position_m=(0.0, STUMP_Y_M), height_m=STUMP_H_M, bottom_radius_m=radius_m, top_radius_m=radius_m)
    return PileSpec(terrain=FLAT, logs=(_log(),), stumps=(stump,))


def _stump_points(radius_m: float, noise_m: float, n: int = 2000, seed: int = 0) -> np.ndarray:
    """Stereo points on a stump of ``radius_m`` at the test's place: its top disc and its side, each point
    off the surface by Gaussian ``noise_m``."""
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, 2 * np.pi, n)
    side = rng.random(n) < 0.5
    rad = np.where(side, radius_m, radius_m * np.sqrt(rng.random(n))) + np.where(side, rng.normal(0, noise_m, n), 0.0)
    z = np.where(side, rng.uniform(0.1, STUMP_H_M, n), STUMP_H_M + rng.normal(0, noise_m, n))
    return np.column_stack([rad * np.cos(ang), STUMP_Y_M + rad * np.sin(ang), z])


def _fit(log: LogSpec) -> LogFit:
    butt, top = log.endpoints_m()
    ends = [{"position_m": list(map(float, p)), "contradicted": False} for p in (butt, top)]
    return LogFit("log1", 0, tuple(butt), tuple(top), log.length_m, log.diameter_m, None, 100, 0.005, 1.0,
                  0.0, 0.0, 0.0, False, ends=ends, fit="partial")


def _fixed_ends(log: LogSpec) -> dict:
    """RTK fixed points on both ends of ``log`` where it truly is."""
    return {"log1": tuple(SurveyEnd(p, 0.01, 0.018, "rtk_fixed") for p in log.endpoints_m())}


def _axis_y(log: LogSpec) -> float:
    return float(np.mean([p[1] for p in log.endpoints_m()]))


def _near_side_y(st: StumpSpec) -> float:
    """Where the stump's side facing the log is (the log lies at smaller y) [m]."""
    return st.position_m[1] - st.top_radius_m


def _twin_accepts(pile: PileSpec) -> bool:
    from synth.physics.world import World

    with World(pile, visuals=False) as world:
        return not world.penetrations(TOL)


def test_an_obstacle_s_sigma_is_its_points_spread_about_its_surface_grown_where_they_are_few():
    pile = _pile()
    tight = obstacle_sigmas(pile, _stump_points(FOUND_R_M, 0.003), CFG)[0]
    loose = obstacle_sigmas(pile, _stump_points(FOUND_R_M, 0.02), CFG)[0]
    assert tight == pytest.approx(np.hypot(CFG.obstacle_sigma_floor_m, 0.003), abs=1e-3)  # the floor rules
    assert loose == pytest.approx(np.hypot(CFG.obstacle_sigma_floor_m, 0.02), abs=3e-3)
    # a stump found 3 cm too big: its points lie inside it, and that is its sigma
    assert obstacle_sigmas(pile, _stump_points(FOUND_R_M - 0.03, 0.005), CFG)[0] > 2 * tight
    few = obstacle_sigmas(pile, _stump_points(FOUND_R_M, 0.003, n=20), CFG)[0]
    assert few > 1.5 * tight  # 20 points: grown by sqrt(50 / ~18)
    rng = np.random.default_rng(2)  # the ground round its foot (within the band of its side): not its evidence
    ang, rad = rng.uniform(0, 2 * np.pi, 500), rng.uniform(FOUND_R_M, FOUND_R_M + 0.05, 500)
    ground = np.column_stack([rad * np.cos(ang), STUMP_Y_M + rad * np.sin(ang), rng.normal(0, 0.003, 500)])
    with_ground = obstacle_sigmas(pile, np.vstack([_stump_points(FOUND_R_M, 0.003), ground]), CFG)[0]
    assert with_ground == pytest.approx(tight, abs=1e-9)
    assert obstacle_sigmas(pile, None, CFG) == [CFG.obstacle_sigma_max_m]
    assert obstacle_sigma(np.full(1000, 0.2), CFG) == CFG.obstacle_sigma_max_m


def test_the_points_of_a_log_resting_on_an_obstacle_are_not_its_evidence():
    pile = _pile()
    tight = _stump_points(FOUND_R_M, 0.003)
    # the log's top where it runs along the stump's side: within the band of both surfaces
    log_pts = np.column_stack([np.linspace(-0.2, 0.2, 400), np.full(400, 0.03),
                               np.full(400, R + np.sqrt(R ** 2 - 0.03 ** 2))])
    assert obstacle_sigmas(pile, np.vstack([tight, log_pts]), CFG)[0] == pytest.approx(
        obstacle_sigmas(pile, tight, CFG)[0], abs=1e-9)
    away = LogSpec.from_endpoints((-1.0, -1.5, R), (1.0, -1.5, R), 2 * R)
    bare = PileSpec(terrain=FLAT, logs=(away,), stumps=pile.stumps)  # no log there to own them: the stump's (badly)
    assert obstacle_sigmas(bare, np.vstack([tight, log_pts]), CFG)[0] > obstacle_sigmas(bare, tight, CFG)[0] + 0.002


def test_a_fixed_end_pressed_into_a_stump_found_too_big_is_kept_and_the_stump_gives_way_within_its_sigma():
    pile = _pile()
    points = _stump_points(FOUND_R_M - 0.05, 0.005)  # the stump is 5 cm smaller than found
    sigma = obstacle_sigmas(pile, points, CFG)[0]
    out = JointSettler(_fixed_ends(_log()), {"log1": 0.01}, CFG, TOL, 12, points=points)(pile, [_fit(_log())])
    assert abs(_axis_y(out.pile.logs[0])) < 0.005  # the log stays where its RTK fixed points are
    st = out.pile.stumps[0]
    gave = _near_side_y(st) - _near_side_y(pile.stumps[0])
    assert gave == pytest.approx(INTO_M - abs(_axis_y(out.pile.logs[0])), abs=3e-3)
    shift = st.position_m[1] - STUMP_Y_M
    shrink = FOUND_R_M - st.top_radius_m
    assert 0 < shift < sigma and 0 < shrink < sigma  # each within its own sigma
    assert any(n.startswith("obstacle 0 shrunk") for n in out.notes)
    assert _twin_accepts(out.pile)
    with pytest.raises(SeparationError, match="clear stump 0|clear obstacle 0"):  # fixed bodies: revision 12 refuses
        JointSettler(_fixed_ends(_log()), {"log1": 0.01}, JointConfig(obstacle_states=False, radius_states=False), TOL, 12,
                     points=points)(pile, [_fit(_log())])


def test_a_stump_its_points_hold_tightly_stays_and_the_loosely_placed_log_moves_off_it():
    pile = _pile()
    points = _stump_points(FOUND_R_M, 0.003)  # the stump is where it was found, its surface seen to 3 mm
    out = JointSettler({}, {"log1": 0.04}, CFG, TOL, 12, points=points)(pile, [_fit(_log())])
    st = out.pile.stumps[0]
    gave = _near_side_y(st) - _near_side_y(pile.stumps[0])
    moved = -_axis_y(out.pile.logs[0])
    assert moved + gave == pytest.approx(INTO_M, abs=3e-3)  # together, just clear
    assert moved > 0.7 * INTO_M  # the log (placed to +-4 cm) does most of it
    assert gave < 0.3 * INTO_M
    assert _twin_accepts(out.pile)


def test_a_fixed_end_pressed_far_into_a_stump_its_points_hold_tightly_is_refused_on_both_their_evidence():
    # 8 cm past the roll: the log's points and the stump's take ~3 sigma each, together over 4
    pile = PileSpec(terrain=FLAT, logs=(_log(),), stumps=(StumpSpec(position_m=(0.0, STUMP_Y_M), height_m=STUMP_H_M,
                                                                    bottom_radius_m=0.25, top_radius_m=0.25),))
    points = _stump_points(0.25, 0.003)
    with pytest.raises(SeparationError, match=r"and survey points, obstacle 0's \(\+-1\.0 cm, "):
        JointSettler(_fixed_ends(_log()), {"log1": 0.01}, CFG, TOL, 12, points=points)(pile, [_fit(_log())])


def test_a_log_lying_across_a_stump_s_flat_top_is_not_in_it():
    stump = StumpSpec(position_m=(0.0, 0.0), height_m=0.4, bottom_radius_m=0.17, top_radius_m=0.15)
    on_top = LogSpec.from_endpoints((-1.0, 0.0, 0.401 + R), (1.0, 0.0, 0.401 + R), 2 * R)  # 1 mm over its top
    pile = PileSpec(terrain=FLAT, logs=(on_top,), stumps=(stump,))
    seg = Bodies(pile).stumps[0]
    log_seg = Segment(*on_top.endpoints_m(), R, R)
    assert Bodies(pile, flat_stumps=True).obstacle_depths(log_seg, 0).max() == pytest.approx(-0.001, abs=1e-6)
    assert Bodies(pile, flat_stumps=False).obstacle_depths(log_seg, 0).max() == pytest.approx(0.15 - 0.001, abs=1e-6)
    out, _ = settle_pile(pile, [LogEvidence(0.02, 0.02)], CFG, TOL, 12)
    assert out.moved[0] < 1e-3 and _twin_accepts(out.pile)  # the twin agrees: nothing to move
    with pytest.raises(SeparationError):  # the round-ended stump of revision 12 lifts it its top radius: refused
        settle_pile(pile, [LogEvidence(0.02, 0.02)], JointConfig(flat_stumps=False), TOL, 12)
    # past the top edge, the corner: a log whose axis is as far out as up from the edge is that times sqrt 2 from it
    off = R / np.sqrt(2) + 0.005
    corner = Segment(np.array([-1.0, 0.15 + off, 0.4 + off]), np.array([1.0, 0.15 + off, 0.4 + off]), R, R)
    assert seg.b[2] == pytest.approx(0.4)
    depth = Bodies(pile, flat_stumps=True).obstacle_depths(corner, 0).max()
    assert depth == pytest.approx(R - np.sqrt(2) * off, abs=1e-6)


def test_a_rock_moved_by_its_state_is_shifted_and_its_faces_moved_in_by_its_erosion():
    box = tuple((x, y, z) for x in (-0.4, 0.4) for y in (-0.4, 0.4) for z in (-0.2, 0.2))
    rock = RockSpec(position_m=(0.0, 0.45, 0.2), orientation=(0.0, 0.0, 0.0, 1.0), vertices_m=box)
    pile = PileSpec(terrain=FLAT, logs=(_log(),), rocks=(rock,))
    moved = moved_obstacles(pile, np.array([[0.01, 0.02, 0.03]])).rocks[0]
    V = np.asarray(moved.vertices_m)
    assert moved.position_m == pytest.approx((0.01, 0.47, 0.2))
    assert np.ptp(V, axis=0) == pytest.approx([0.8 - 0.06, 0.8 - 0.06, 0.4 - 0.06])  # each face 3 cm in
    assert len(V) == 8


def test_the_settle_jacobian_with_obstacle_states_is_scipys_forward_difference():
    from scipy.optimize._numdiff import approx_derivative

    pile = _pile()
    prob = _Problem(pile, [LogEvidence(0.02, 0.02)], CFG, [0.02])
    x = np.random.default_rng(1).normal(0.0, 0.5, 7)
    prob.terms = prob.bodies.terms(prob.segments(x), CFG.contact_reach_m)
    assert any(t.kind == "obstacle" for t in prob.terms)
    for contacts in (False, True):
        J = prob.jacobian(x, contacts)
        assert np.abs(J[:, 4:]).sum() > 0
        assert np.array_equal(J, approx_derivative(prob.residuals, x, method="2-point", args=(contacts,)))
    with pytest.raises(ValueError, match="obstacle sigmas"):
        _Problem(pile, [LogEvidence(0.02, 0.02)], CFG, [0.02, 0.02])


def test_the_obstacle_parameters_are_checked():
    for name in ("obstacle_sigma_floor_m", "obstacle_sigma_max_m", "obstacle_sigma_band_m",
                 "obstacle_sigma_ref_points"):
        with pytest.raises(ValueError, match=name):
            JointConfig(**{name: 0})
