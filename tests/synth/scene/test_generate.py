import numpy as np
import pytest

from synth.scene.generate import GenerationConfig, generate_pile, settle
from synth.scene.pile import write_pile
from synth.render.ortho import OrthoRenderConfig, render_ortho
from synth.physics.world import World


def test_same_seed_same_pile_and_renders(tmp_path):
    cfg = GenerationConfig(n_logs=4, n_obstacles=2)
    a, _ = generate_pile(11, cfg)
    b, _ = generate_pile(11, cfg)
    assert write_pile(a, tmp_path / "a.json").read_bytes() == write_pile(b, tmp_path / "b.json").read_bytes()
    with World(a) as wa, World(b) as wb:
        ra, rb = render_ortho(wa, seed=11), render_ortho(wb, seed=11)
    np.testing.assert_array_equal(ra.intensity, rb.intensity)
    np.testing.assert_array_equal(ra.depth, rb.depth)
    np.testing.assert_array_equal(ra.instance, rb.instance)
    c, _ = generate_pile(12, cfg)
    assert c != a


@pytest.mark.parametrize("n_logs,n_obst,packed", [(4, 0, False), (4, 3, False), (5, 0, True)])
def test_settled_piles_are_at_rest_and_valid(n_logs, n_obst, packed):
    cfg = GenerationConfig(n_logs=n_logs, n_obstacles=n_obst, packed=packed)
    pile, report = generate_pile(3, cfg)
    assert pile.n_logs == n_logs and pile.n_obstacles == n_obst
    with World(pile) as world:
        before = world.log_poses()
        world.step(int(0.5 / world.physics.dt_s))
        after = world.log_poses()
        world.check_valid()
    # reloaded from the file's poses, the pile stays put (creep of mm at most)
    assert np.linalg.norm(after[:, :3] - before[:, :3], axis=1).max() < 0.01
    half = pile.terrain.extent_m / 2
    for log in pile.logs:
        for end in log.endpoints_m():
            assert abs(end[0]) < half and abs(end[1]) < half


def test_packed_logs_are_aligned_and_touching():
    pile, _ = generate_pile(5, GenerationConfig(n_logs=4, packed=True))
    axes = np.array([log.axis()[:2] / np.linalg.norm(log.axis()[:2]) for log in pile.logs])
    assert np.abs(axes @ axes[0]).min() > 0.97  # within ~14 degrees
    centres = np.array([log.centre_m[:2] for log in pile.logs])
    normal = np.array([-axes[0][1], axes[0][0]])
    offsets = np.sort(centres @ normal)
    assert np.diff(offsets).max() < 0.3  # side by side, no big gaps


def test_settle_gives_up_on_a_pile_that_never_rests():
    from synth.errors import GenerationError

    pile, _ = generate_pile(1, GenerationConfig(n_logs=2))
    cfg = GenerationConfig(n_logs=2, settle_tol_m=-1.0, settle_max_s=0.5)  # impossible tolerance
    with World(pile) as world, pytest.raises(GenerationError, match="still moving"):
        settle(world, cfg)


def test_generation_config_validation():
    with pytest.raises(ValueError, match="n_logs"):
        GenerationConfig(n_logs=0)
    with pytest.raises(ValueError, match="n_obstacles"):
        GenerationConfig(n_obstacles=99)
