"""Balance means something: the grapple swings until the load hangs under the hinges."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from synth.physics.grapple import GrappleConfig
from synth.geometry.grasp import Grasp
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, quat_from_x_axis
from synth.physics.trial import TrialConfig, run_trial


def flat_pile(logs, resolution: int = 32) -> PileSpec:
    heights = tuple(tuple(0.0 for _ in range(resolution)) for _ in range(resolution))
    return PileSpec(terrain=TerrainSpec(resolution=resolution, heights_m=heights), logs=tuple(logs))


def log_along_y(x: float, d: float = 0.16) -> LogSpec:
    return LogSpec(centre_m=(x, 0.0, 0.41 * d), orientation=quat_from_x_axis((0, 1, 0)), length_m=2.5, diameter_m=d)


def _beta_deg(result) -> float:
    return math.degrees(math.acos(min(1.0, result.cos_beta)))


@pytest.fixture(scope="module")
def two_logs():
    return flat_pile([log_along_y(-0.085), log_along_y(0.085)])


def test_off_centre_grasp_tilts_the_grapple(two_logs):
    """Two 2.5 m logs gripped 0.6 m from their middle: the load's centre of mass pulls the grapple
    several degrees off vertical; gripped in the middle it hangs plumb."""
    cfg = TrialConfig.fast()
    centred = run_trial(two_logs, Grasp(0.0, 0.0, 0.0, 0.6), [0, 1], cfg)
    off = run_trial(two_logs, Grasp(0.0, 0.6, 0.0, 0.6), [0, 1], cfg)
    assert centred.success and off.success, (centred.outcome, off.outcome)
    assert _beta_deg(centred) < 2.0
    assert _beta_deg(off) > _beta_deg(centred) + 3.0


def test_a_friction_brake_would_hold_the_grapple_plumb(two_logs):
    """The damper is what lets it swing: with the hinges braked (no damping, a 2 kN·m friction
    motor) the same off-centre grasp stays near plumb."""
    braked = replace(GrappleConfig(), hinge_damping_nms=0.0, hinge_friction_nm=2000.0)
    cfg = replace(TrialConfig.fast(), grapple=braked)
    off = run_trial(two_logs, Grasp(0.0, 0.6, 0.0, 0.6), [0, 1], cfg)
    free = run_trial(two_logs, Grasp(0.0, 0.6, 0.0, 0.6), [0, 1], TrialConfig.fast())
    assert _beta_deg(off) < _beta_deg(free) - 2.0


def test_the_lift_goes_on_until_the_load_hangs_free():
    """Two 4.5 m logs gripped 1.2 m from their middle and lifted only 5 cm: their far ends still
    lie on the ground, so the lift goes on until the load hangs free (and tilts the grapple);
    without the free lift the trial judges a load that still rests on the ground."""
    d = 0.16
    long_logs = flat_pile([LogSpec(centre_m=(x, 0.0, 0.41 * d), orientation=quat_from_x_axis((0, 1, 0)),
                                   length_m=4.5, diameter_m=d) for x in (-0.085, 0.085)])
    short = replace(TrialConfig.fast(), lift_height_m=0.05, min_lift_m=0.05)
    r = run_trial(long_logs, Grasp(0.0, 1.2, 0.0, 0.6), [0, 1], short)
    p = run_trial(long_logs, Grasp(0.0, 1.2, 0.0, 0.6), [0, 1], replace(short, free_lift_max_m=0.0))
    assert r.phase_s["lift"] > p.phase_s["lift"] + 0.2, (r.phase_s, p.phase_s)
    assert r.success and not p.success, (r.outcome, p.outcome)
    assert _beta_deg(r) > 4.0
