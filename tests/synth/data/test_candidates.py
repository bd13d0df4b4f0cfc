import math
from types import SimpleNamespace

import numpy as np
import pytest

from synth.data.candidates import (
    CandidateConfig, PlaneScene, generate_candidates, rectangle_overlap_area, reduce_candidates,
    segment_distance,
)
from synth.geometry.grasp import Grasp
from synth.scene.pile import LogSpec, PileSpec, RockSpec, StumpSpec, TerrainSpec


def _log(y, z=0.1, x0=-1.2, x1=1.2, d=0.16):
    return LogSpec.from_endpoints((x0, y, z), (x1, y, z), d)


def _pile(logs, rocks=(), stumps=()):
    return PileSpec(terrain=TerrainSpec(), logs=tuple(logs), rocks=tuple(rocks), stumps=tuple(stumps))


def _claws(g, cfg=CandidateConfig()):
    a = g.closing_axis()
    c = np.array([g.x_m, g.y_m])
    return c - a * g.width_m / 2, c + a * g.width_m / 2


def test_two_parallel_logs_yield_candidates_spanning_both():
    cfg = CandidateConfig()
    pile = _pile([_log(0.0), _log(0.3)])
    cands = generate_candidates(pile, [0, 1], cfg)
    assert len(cands) > 20
    widths = [g.width_m for g in cands]
    assert widths == sorted(widths)
    for g in cands:
        c1, c2 = _claws(g)
        # closing axis across the logs (within max_dphi of pile y), claws outside both logs, crossings
        # at least end_margin from the logs' ends
        assert abs(math.sin(g.phi_rad)) >= math.cos(cfg.max_dphi_rad) - 1e-9
        ys = sorted([c1[1], c2[1]])
        assert ys[0] < 0.0 - 0.08 and ys[1] > 0.3 + 0.08
        for y_log in (0.0, 0.3):
            x_cross = g.x_m + (y_log - g.y_m) * math.cos(g.phi_rad) / math.sin(g.phi_rad)
            assert -1.2 + cfg.end_margin_m - 1e-6 <= x_cross <= 1.2 - cfg.end_margin_m + 1e-6
    # the narrowest is perpendicular, centred between the logs, span + 2 radii + 2 margins
    g0 = cands[0]
    assert g0.y_m == pytest.approx(0.15, abs=1e-6)
    assert g0.width_m == pytest.approx(0.3 + 0.16 + 2 * 0.08, abs=1e-6)
    # wider variants (+0.15, +0.30 m), centred or shifted by half the extra along the closing axis
    here = [g for g in cands if abs(g.x_m - g0.x_m) < 1e-6 and abs(g.phi_rad - g0.phi_rad) < 1e-9]
    assert sorted({round(g.width_m - g0.width_m, 6) for g in here}) == [0.0, 0.15, 0.3]
    assert sorted({round(g.y_m, 6) for g in here}) == [0.0, 0.075, 0.15, 0.225, 0.3]
    # single targets work too and sit on their log
    for i, y in ((0, 0.0), (1, 0.3)):
        one = generate_candidates(pile, [i])
        assert one and abs(one[0].y_m - y) < 1e-6


def test_claws_never_land_on_a_third_log():
    cfg = CandidateConfig()
    # a third log 0.18 m outside log 1: claws of a {0, 1} grasp need 0.08 m beyond log 1's surface
    third = _log(0.3 + 0.30, z=0.1)
    pile = _pile([_log(0.0), _log(0.3), third])
    scene = PlaneScene.from_pile(pile)
    cands = generate_candidates(pile, [0, 1], cfg)
    free = generate_candidates(_pile([_log(0.0), _log(0.3)]), [0, 1], cfg)
    assert len(cands) < len(free)
    lg = scene.logs[2]
    hw = cfg.claw_width_m / 2
    for g in cands:
        a = g.closing_axis()
        b = np.array([-a[1], a[0]])
        for e in _claws(g):
            assert segment_distance(e - b * hw, e + b * hw, lg.a2, lg.b2) >= lg.radius_m + cfg.claw_clearance_m - 1e-9
    # a non-target log lying across between the claws, on top, removes every candidate it crosses
    on_top = LogSpec.from_endpoints((0.0, -0.6, 0.35), (0.0, 0.9, 0.35), 0.16)
    crossed = generate_candidates(_pile([_log(0.0), _log(0.3), on_top]), [0, 1], cfg)
    assert all(abs(g.x_m) > 0.2 for g in crossed)


def test_a_rock_next_to_a_target_removes_the_candidates_over_it():
    pile0 = _pile([_log(0.0), _log(0.3)])
    cube = tuple((sx * 0.15, sy * 0.15, sz * 0.15) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1))
    rock = RockSpec(position_m=(0.6, 0.55, 0.1), orientation=(0, 0, 0, 1), vertices_m=cube)
    pile = _pile([_log(0.0), _log(0.3)], rocks=[rock])
    free, blocked = generate_candidates(pile0, [0, 1]), generate_candidates(pile, [0, 1])
    assert len(blocked) < len(free)
    near = [g for g in free if abs(g.x_m - 0.6) < 0.1 and abs(math.sin(g.phi_rad)) > 0.99]
    assert near  # there were perpendicular candidates at the rock
    assert not [g for g in blocked if abs(g.x_m - 0.6) < 0.1 and abs(math.sin(g.phi_rad)) > 0.99]
    assert [g for g in blocked if g.x_m < 0.0]  # away from the rock candidates survive
    # a stump works the same way
    stump = StumpSpec(position_m=(-0.5, -0.30), height_m=0.4, bottom_radius_m=0.15, top_radius_m=0.12)
    s_blocked = generate_candidates(_pile([_log(0.0), _log(0.3)], stumps=[stump]), [0, 1])
    assert not [g for g in s_blocked if abs(g.x_m + 0.5) < 0.1 and abs(math.sin(g.phi_rad)) > 0.99]


def test_targets_too_far_apart_or_not_overlapping():
    assert generate_candidates(_pile([_log(0.0), _log(1.6)]), [0, 1]) == []  # needs > 1.55 m
    end_to_end = _pile([_log(0.0, x0=-2.2, x1=-0.1), _log(0.0, x0=0.1, x1=2.2)])
    assert generate_candidates(end_to_end, [0, 1]) == []
    with pytest.raises(ValueError, match="outside"):
        generate_candidates(_pile([_log(0.0)]), [3])
    with pytest.raises(ValueError, match="empty"):
        generate_candidates(_pile([_log(0.0)]), [])


# ---------------------------------------------------------------------------------------------
# Algorithm 1
# ---------------------------------------------------------------------------------------------
def _fake(success):
    calls = []

    def simulate(g):
        calls.append(g)
        return SimpleNamespace(success=bool(success(g)), balance=0.9)

    return simulate, calls


def test_narrowest_first_and_failures_only_remove_themselves():
    cands = [Grasp(0.0, 3 * k, 0.0, w) for k, w in enumerate([0.9, 0.5, 0.7, 0.4])]
    sim, calls = _fake(lambda g: False)
    res = reduce_candidates(cands, sim)
    assert [g.width_m for g in calls] == [0.4, 0.5, 0.7, 0.9]
    assert res.accepted == [] and res.n_trials == 4


def test_widening_kept_when_it_succeeds_and_rejected_when_not():
    g = Grasp(0.0, 0.0, 0.0, 0.6)
    sim, calls = _fake(lambda h: True)
    res = reduce_candidates([g], sim, rng=np.random.default_rng(1))
    assert len(calls) == 2 and calls[0] == g
    dw = calls[1].width_m - 0.6
    assert 0.05 <= dw <= 0.10 and (calls[1].x_m, calls[1].y_m, calls[1].phi_rad) == (0.0, 0.0, 0.0)
    assert res.accepted[0][0] == calls[1] and res.widened == 1
    sim, calls = _fake(lambda h: h.width_m <= 0.6 + 1e-9)
    res = reduce_candidates([g], sim, rng=np.random.default_rng(1))
    assert res.accepted[0][0] == g and res.widened == 0 and res.n_trials == 2
    # no widening past the grapple's range
    sim, calls = _fake(lambda h: True)
    res = reduce_candidates([Grasp(0, 0, 0, 1.52)], sim)
    assert len(calls) == 1 and res.accepted[0][0].width_m == 1.52


def test_overlap_removal_at_the_threshold():
    # accepted: 1.0 m x 0.2 m along x at the origin. Candidates shifted along y overlap by
    # 1.0 * (0.2 - dy) m² (widths chosen so they are tried after it, and widening fails)
    acc = Grasp(0.0, 0.0, 0.0, 0.5)
    sim, calls = _fake(lambda h: h == acc)
    big = [Grasp(0.0, dy, 0.0, 1.0) for dy in (0.05, 0.15, 0.17)]  # overlap 0.5*0.15, 0.5*0.05, 0.5*0.03
    res = reduce_candidates([big[0], big[1], big[2], acc], sim)
    assert rectangle_overlap_area(acc, big[0]) == pytest.approx(0.075, abs=1e-6)
    assert rectangle_overlap_area(acc, big[1]) == pytest.approx(0.025, abs=1e-6)
    tried = [g for g in calls if g.width_m == 1.0]
    assert big[0] not in tried and big[1] in tried and big[2] in tried
    assert [g for g, _ in res.accepted] == [acc]
    # exactly at 0.04 m² the candidate stays (the paper discards only above the threshold)
    edge = Grasp(0.0, 0.2 - 0.08, 0.0, 1.0)  # overlap 0.5 * 0.08 = 0.04
    assert rectangle_overlap_area(acc, edge) == pytest.approx(0.04, abs=1e-6)
    sim, calls = _fake(lambda h: h == acc)
    reduce_candidates([edge, acc], sim)
    assert edge in calls
    # crossing rectangles: area of the crossing square, 0.2 x 0.2 = 0.04
    cross = Grasp(0.0, 0.0, math.pi / 2, 1.0)
    assert rectangle_overlap_area(acc, cross) == pytest.approx(0.04, abs=1e-6)


def test_trial_cap_and_trial_result_outcomes():
    cands = [Grasp(float(k), 0.0, 0.0, 0.5) for k in range(5)]
    sim, calls = _fake(lambda h: False)
    res = reduce_candidates(cands, sim, max_trials=3)
    assert res.n_trials == 3 and res.capped
    # results shaped like synth.physics.trial.TrialResult (outcome enum with .ok) are understood

    class Outcome:
        def __init__(self, ok):
            self.ok = ok

    res = reduce_candidates([cands[0]], lambda g: SimpleNamespace(outcome=Outcome(True)))
    assert len(res.accepted) == 1
    with pytest.raises(ValueError):
        reduce_candidates(cands, sim, max_trials=0)
