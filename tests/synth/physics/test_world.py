"""synth.physics.world.World: a log rebuilt in place, and a log's deepest contact."""

from __future__ import annotations

from synth.physics.world import World
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec

N = 16
FLAT = TerrainSpec(extent_m=5.0, resolution=N, amplitude_m=0.0, heights_m=tuple(tuple(0.0 for _ in range(N)) for _ in range(N)))


def test_a_log_rebuilt_in_place_is_what_contacts_and_the_pile_see():
    a = LogSpec.from_endpoints((-1.0, 0.0, 0.08), (1.0, 0.0, 0.08), 0.16)
    b = LogSpec.from_endpoints((-1.0, 0.5, 0.08), (1.0, 0.5, 0.08), 0.16)
    into_a = LogSpec.from_endpoints((-1.0, 0.5, 0.08), (0.5, 0.05, 0.08), 0.16)
    with World(PileSpec(terrain=FLAT, logs=(a, b)), visuals=False) as w:
        depth, other = w.deepest_contact(1)
        assert depth < 0.01 and other in (None, w.terrain_id)
        body = w.replace_log(1, into_a)
        assert body == w.log_ids[1] and w.instance_of_body[body] == 2  # (pybullet may reuse the old id)
        assert w.pile.logs[1] == into_a and w.pile.logs[0] == a
        depth, other = w.deepest_contact(1)
        assert depth > 0.05 and other == w.log_ids[0]
        assert any({"log 0", "log 1"} == {x, y} for x, y, _ in w.penetrations())
        w.replace_log(1, b)
        assert w.deepest_contact(1)[0] < 0.01
