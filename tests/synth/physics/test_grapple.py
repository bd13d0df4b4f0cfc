"""The grapple twin: geometry, actuation, compliance, hiding, no claw through a log."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from synth.physics.grapple import HEAD, SWING_A, Grapple, GrappleConfig
from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, Grasp
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, quat_from_x_axis
from synth.physics.world import PhysicsConfig, World


def flat_pile(logs, resolution: int = 16) -> PileSpec:
    heights = tuple(tuple(0.0 for _ in range(resolution)) for _ in range(resolution))
    return PileSpec(terrain=TerrainSpec(resolution=resolution, heights_m=heights), logs=tuple(logs))


def log_along_y(x: float = 0.0, d: float = 0.16) -> LogSpec:
    return LogSpec(centre_m=(x, 0.0, 0.41 * d), orientation=quat_from_x_axis((0, 1, 0)), length_m=2.5, diameter_m=d)


def test_config_geometry_matches_the_real_grapple_class():
    g = GrappleConfig()
    # the width range of the paper is reachable, the claws close completely
    assert g.closed_gap_m() == pytest.approx(0.0, abs=1e-9)
    assert g.gap_at(g.max_angle_rad()) == pytest.approx(g.max_opening_m, abs=1e-3)
    for w in (MIN_WIDTH_M, 0.8, MAX_WIDTH_M):
        assert g.gap_at(g.angle_for_gap(w)) == pytest.approx(w, abs=1e-3)
    # a 0.35 m² grapple: the area closed between the claws and the hinge line is close to it
    assert 0.33 <= g.enclosed_area_m2() <= 0.42
    assert 200.0 <= g.mass_kg() <= 280.0


def test_config_rejects_nonsense():
    with pytest.raises(ValueError, match="claw_torque_limit_nm"):
        GrappleConfig(claw_torque_limit_nm=0.0)
    with pytest.raises(ValueError, match="max_opening_m"):
        GrappleConfig(max_opening_m=1.0)
    with pytest.raises(ValueError, match="outside"):
        GrappleConfig().angle_for_gap(2.5)


def test_grapple_hangs_at_the_grasp_and_follows_commands():
    pile = flat_pile([log_along_y(1.5)])
    grasp = Grasp(0.3, -0.2, 0.7, 0.9)
    with World(pile, PhysicsConfig(dt_s=1 / 240)) as world:
        gr = Grapple(world.client, GrappleConfig(), grasp, 2.5, terrain_id=world.terrain_id)
        world.step(120)
        o, R = gr.head_pose()
        assert o[:2] == pytest.approx([0.3, -0.2], abs=5e-3)
        # closing axis (head u) points along phi; the grapple hangs plumb
        assert math.atan2(R[1, 0], R[0, 0]) == pytest.approx(0.7, abs=0.02)
        assert gr.cos_beta() > 0.9995
        assert gr.gap_m() == pytest.approx(0.9, abs=0.02)
        gr.move_z(-0.5)
        world.step(120)
        assert gr.boom_z() == pytest.approx(2.5 - 0.25, abs=0.01)
        gr.close()
        world.step(480)  # ~1.3 rad of stroke at 1 rad/s
        # nothing in between: the stroke's end, the interleaving tips far past each other
        g = GrappleConfig()
        assert gr.gap_m() == pytest.approx(float(g.gap_at(g.close_angle_rad())), abs=0.01)
        assert gr.gap_m() < -0.9


def test_unactuated_hinges_give_compliance():
    """A sideways push folds the grapple about the swing hinges; it swings back plumb."""
    pile = flat_pile([log_along_y(1.5)])
    with World(pile, PhysicsConfig(dt_s=1 / 240)) as world:
        gr = Grapple(world.client, GrappleConfig(), Grasp(0.0, 0.0, 0.0, 0.8), 2.5)
        c = world.client
        for _ in range(30):
            c.applyExternalForce(gr.body, HEAD, [3000.0, 0.0, 0.0], [0, 0, 1.2], c.WORLD_FRAME)
            c.stepSimulation()
        tilted = gr.cos_beta()
        assert tilted < 0.99  # it folded
        world.step(240 * 4)
        assert gr.cos_beta() > 0.995  # friction motor only: back (nearly) plumb
        assert abs(c.getJointState(gr.body, SWING_A)[0]) < 0.1


def test_hidden_grapple_is_invisible_in_renders():
    pile = flat_pile([log_along_y(1.5)])
    with World(pile) as world:
        gr = Grapple(world.client, GrappleConfig(), Grasp(0.0, 0.0, 0.0, 0.8), 1.6)
        c, p = world.client, world.p
        view = c.computeViewMatrix([0, 0, 5], [0, 0, 0], [0, 1, 0])
        proj = c.computeProjectionMatrixFOV(40, 1.0, 0.1, 10)

        def seg():
            img = c.getCameraImage(64, 64, view, proj, renderer=p.ER_TINY_RENDERER)
            return np.asarray(img[4]).reshape(64, 64) & ((1 << 24) - 1)

        assert (seg() == gr.body).sum() > 50
        gr.set_visible(False)
        assert (seg() == gr.body).sum() == 0
        gr.set_visible(True)
        assert (seg() == gr.body).sum() > 50


def test_terrain_contacts_are_disabled():
    pile = flat_pile([log_along_y(1.8)])
    with World(pile) as world:
        gr = Grapple(world.client, GrappleConfig(), Grasp(0.0, 0.0, 0.0, 0.8), 0.9, terrain_id=world.terrain_id)
        world.step(60)  # the claws hang below the ground: no contact, no force
        assert gr.contact_force_n() == 0.0
        assert gr.tips_world()[:, 2].max() < 0.0


def test_claws_squeezing_a_log_do_not_pass_through_it():
    """Close on a log held between the claws with full force: penetration stays below a few mm."""
    log = log_along_y(0.0, d=0.30)
    pile = flat_pile([log])
    with World(pile, PhysicsConfig(dt_s=1 / 120, solver_iterations=20)) as world:
        g = GrappleConfig()
        # claws straddle the log, tips at the log's axis height: they close onto its flanks
        q = g.angle_for_gap(0.5)
        boom_z = 0.41 * 0.30 + g.hang_height_m(q)
        gr = Grapple(world.client, g, Grasp(0.0, 0.0, 0.0, 0.5), boom_z, terrain_id=world.terrain_id)
        gr.close()
        worst = 0.0
        for _ in range(240):
            world.client.stepSimulation()
            worst = max(worst, gr.penetration_m({world.log_ids[0]}))
        assert gr.gap_m() > 0.10  # the log is in the way
        assert worst < 0.005
        assert gr.contact_force_n({world.log_ids[0]}) > 1000.0  # it really squeezes


def test_the_closed_bowl_is_the_configured_diameter():
    """The stroke ends where the bowl between the claws and the head holds a log of
    ``closed_bowl_diameter_m``: fully open it is wide, it shrinks as the claws close, and the
    default holds nothing wider than the twin's typical 0.16-0.20 m log loosely."""
    g = GrappleConfig()
    q = g.close_angle_rad()
    assert g.bowl_diameter_m(q) == pytest.approx(g.closed_bowl_diameter_m, abs=0.005)
    assert g.bowl_diameter_m(0.0) > 0.5  # tips just touching: the whole 0.35 m² bowl
    assert g.bowl_diameter_m(0.2) == 0.0  # tips apart: no bowl below
    qs = [0.0, -0.2, -0.4, -0.6, q]
    ds = [g.bowl_diameter_m(v) for v in qs]
    assert ds == sorted(ds, reverse=True)
    thinner = replace(g, closed_bowl_diameter_m=0.12)
    assert thinner.close_angle_rad() < q
    with pytest.raises(ValueError, match="closed_bowl_diameter_m"):
        GrappleConfig(closed_bowl_diameter_m=0.01)
