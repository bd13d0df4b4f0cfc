"""``run_trial(should_abort=...)``: an aborted trial stops at once and says what it holds; without
an abort the trial is bit-identical to one run without the hook."""

from __future__ import annotations

import itertools

from synth.geometry.grasp import Grasp
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, quat_from_x_axis
from synth.physics.trial import TrialConfig, run_trial

FAST = TrialConfig.fast()


def one_log_pile() -> PileSpec:
    heights = tuple(tuple(0.0 for _ in range(32)) for _ in range(32))
    log = LogSpec(centre_m=(0.0, 0.0, 0.41 * 0.16), orientation=quat_from_x_axis((0, 1, 0)), length_m=2.5,
                  diameter_m=0.16)
    return PileSpec(terrain=TerrainSpec(resolution=32, heights_m=heights), logs=(log,), rocks=())


def after(n_steps: int):
    """A should_abort that turns True at its n-th call (one call per simulation step)."""
    calls = itertools.count(1)
    return lambda: next(calls) >= n_steps


def comparable(r) -> dict:
    d = r.to_dict()
    d.pop("wall_time_s")
    d.pop("cpu_time_s")
    return d


def test_no_abort_is_bit_identical():
    pile, grasp = one_log_pile(), Grasp(0.0, 0.0, 0.0, 0.6)
    plain = run_trial(pile, grasp, [0], FAST)
    hooked = run_trial(pile, grasp, [0], FAST, should_abort=lambda: False)
    assert comparable(hooked) == comparable(plain)
    assert "aborted_in" not in plain.to_dict() and plain.aborted_in is None


def test_abort_in_the_hold_stops_at_once_and_reports_the_held_log():
    pile, grasp = one_log_pile(), Grasp(0.0, 0.0, 0.0, 0.6)
    full = run_trial(pile, grasp, [0], FAST)
    assert full.success
    dt = FAST.physics.dt_s
    before_hold = round((full.phase_s["lower"] + full.phase_s["close"] + full.phase_s["lift"]) / dt)
    stop_at = before_hold + round(full.phase_s["hold"] / dt / 2)
    r = run_trial(pile, grasp, [0], FAST, should_abort=after(stop_at))
    assert r.stop_reason == "aborted" and r.aborted_in == "hold"
    assert r.grasped == (0,) and r.enclosed == (0,)  # the log is in the air: never "0 logs"
    assert abs(r.sim_time_s - stop_at * dt) < 1e-9  # stopped on the very step
    assert r.to_dict()["aborted_in"] == "hold"


def test_abort_while_lowering_holds_nothing():
    r = run_trial(one_log_pile(), Grasp(0.0, 0.0, 0.0, 0.6), [0], FAST, should_abort=after(3))
    assert (r.stop_reason, r.aborted_in, r.grasped) == ("aborted", "lower", ())
    assert r.sim_time_s == 3 * FAST.physics.dt_s
