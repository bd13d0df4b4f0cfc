"""Sight lines in the joint end model (reconstruct.fitting.joint_sight, JointConfig.sight_lines, joint
revision 19): the ground a camera sees under a raised log is no evidence that the log ends there; the
ground a camera could only have seen through the log is. Hand-made points and cameras: runs in a second."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.joint_config import JOINT_REVISION, JointConfig
from reconstruct.fitting.joint_ends import BELOW, ON, UNSEEN, JointEndPlacer, place_joint_ends
from reconstruct.fitting.joint_ends import bin_states
from reconstruct.fitting.joint_sight import seen_past, segment_distances
from reconstruct.fitting.survey_points import SurveyEnd
from synth.scene.pile import LogSpec

CFG, FCFG = JointConfig(), FuseConfig()
R = 0.1  # the log's radius [m]
Z = 0.6  # its axis's height: a log lying on others, 60 cm over the ground [m]
TRUE_END_M = 1.0  # the log runs along x from -1.0 to this [m]
SEEN_TO_M = 0.0  # the scan shows its top only to here (the cameras' view of it cut off past it) [m]
GROUND_TO_M = 0.3  # ... and the ground under it to here, then nothing [m]
BESIDE = np.array([[0.15, 1.5, 3.0]])  # a camera 1.5 m to the side, 3 m up: it sees under the raised log
ABOVE = np.array([[0.15, 0.0, 3.0]])  # a camera over the log's axis: the log would hide the ground under it


def _points() -> np.ndarray:
    x = np.arange(-1.0, GROUND_TO_M, 0.005)
    top = x < SEEN_TO_M
    pts = np.c_[x, np.zeros_like(x), np.where(top, Z + R, 0.0)]
    return np.r_[pts, pts + [0.0, 0.01, 0.0]]  # two rows, so every bin has its points


def _states(cameras):
    pa, u = np.array([-1.0, 0.0, Z]), np.array([1.0, 0.0, 0.0])
    return bin_states(_points(), pa, u, R, 0.0, 100, FCFG, fitted_m=1.0, cameras=cameras, middle_m=0.5)


def test_segment_distances_match_a_dense_sampling():
    rng = np.random.default_rng(0)
    p0, p1, q0, q1 = (rng.normal(size=(50, 3)) for _ in range(4))
    s = np.linspace(0, 1, 401)
    dense = [np.min(np.linalg.norm((a + s[:, None] * (b - a))[:, None] - (c + s[:, None] * (d - c))[None], axis=2))
             for a, b, c, d in zip(p0, p1, q0, q1)]
    assert segment_distances(p0, p1, q0, q1) == pytest.approx(dense, abs=5e-3)
    assert segment_distances(np.zeros(3), np.array([1.0, 0, 0]), np.array([2.0, 0, 0]), np.array([3.0, 0, 0])) \
        == pytest.approx(1.0)  # collinear, apart


def test_the_ground_under_a_raised_log_is_seen_past_it_from_beside_not_from_above():
    ground = np.array([[0.15, 0.0, 0.0], [0.25, 0.005, 0.0]])
    pa, u = np.array([-1.0, 0.0, Z]), np.array([1.0, 0.0, 0.0])
    t = (ground - pa) @ u
    assert seen_past(ground, BESIDE, pa, u, t, 1.0, R).all()
    assert not seen_past(ground, ABOVE, pa, u, t, 1.0, R).any()
    assert seen_past(ground, np.r_[ABOVE, BESIDE], pa, u, t, 1.0, R).all()  # one camera that sees it is enough
    assert not seen_past(ground, np.zeros((0, 3)), pa, u, t, 1.0, R).any()  # no cameras: every point is evidence


def test_bins_over_ground_a_camera_sees_under_the_log_say_nothing():
    c = -1.0 + FCFG.end_bin_m * (np.arange(100) + 0.5)  # bin centres, x [m]
    under = (c > SEEN_TO_M + 0.02) & (c < GROUND_TO_M - 0.02)
    assert (_states(None)[under] == BELOW).all()  # revision 18: every bin there read 'below'
    assert (_states(ABOVE)[under] == BELOW).all()  # from above the log would have hidden that ground
    assert (_states(BESIDE)[under] == UNSEEN).all()  # from beside it says nothing of where the log ends
    assert (_states(BESIDE)[c < SEEN_TO_M - 0.02] == ON).all()
    assert (_states(BESIDE)[c > GROUND_TO_M + 0.02] == UNSEEN).all()


SPEC = LogSpec.from_endpoints((-1.0, 0.0, Z), (SEEN_TO_M, 0.0, Z), 2 * R)  # fitted to the top the scan shows
S_H = 0.015 / math.sqrt(2)
FIXED = (SurveyEnd(np.array([-1.0, 0.0, Z]), S_H, 0.025, "rtk_fixed"),
         SurveyEnd(np.array([TRUE_END_M, 0.0, Z]), S_H, 0.025, "rtk_fixed"))  # both correct


def _place(cfg: JointConfig, cameras):
    return place_joint_ends(_points(), SPEC, "scan", FIXED, False, 0.005, cfg, FCFG, cameras=cameras)


def test_a_correct_fixed_point_past_the_ground_under_a_raised_log_places_its_end():
    placed, (_, b) = _place(CFG, BESIDE)
    assert not b.contradicted and b.outlier_prob < 0.5
    assert abs(placed.length_m - (TRUE_END_M + 1.0)) < 0.03
    _, (_, b18) = _place(JointConfig(sight_lines=False), BESIDE)  # revision 18: the point thrown away
    assert b18.contradicted and b18.outlier_prob > 0.9
    _, (_, above) = _place(CFG, ABOVE)  # a camera that would have seen the log there: the ground is evidence
    assert above.contradicted


def test_the_pipeline_s_end_placer_hands_the_cameras_on():
    placer = JointEndPlacer({"log1": FIXED}, {"log1": 0.005}, CFG, FCFG, cameras=BESIDE)
    _, (_, b) = placer("log1", SPEC, "scan", _points(), False, np.ones(len(_points()), bool))
    assert not b.contradicted
    blind = JointEndPlacer({"log1": FIXED}, {"log1": 0.005}, CFG, FCFG)  # no cameras known: revision 18's reading
    _, (_, b) = blind("log1", SPEC, "scan", _points(), False, np.ones(len(_points()), bool))
    assert b.contradicted


def test_revision_19_turns_sight_lines_and_radius_states_on():
    assert JOINT_REVISION == 19
    assert JointConfig().sight_lines is True and JointConfig().radius_states is True
    with pytest.raises(ValueError, match="sight_lines"):
        JointConfig(sight_lines=1)
