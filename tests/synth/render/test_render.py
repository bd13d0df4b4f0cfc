import numpy as np
import pytest

from synth.errors import PileFormatError
from synth.geometry.frames import OrthoGrid
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, quat_from_euler
from synth.render.ortho import OrthoObservation, OrthoRenderConfig, render_ortho, target_mask
from synth.physics.world import OBSTACLE_BASE, World


def flat(h=0.1, n=32):
    return TerrainSpec(resolution=n, heights_m=tuple(tuple([h] * n) for _ in range(n)))


def test_pixel_mapping_round_trip_and_corners():
    g = OrthoGrid(128, 5.0)
    x, y = g.pixel_to_pile(0, 0)
    assert (x, y) == pytest.approx((-2.5 + 5 / 256, 2.5 - 5 / 256))
    x, y = g.pixel_to_pile(127, 127)
    assert (x, y) == pytest.approx((2.5 - 5 / 256, -2.5 + 5 / 256))
    rows, cols = np.random.default_rng(0).uniform(0, 127, size=(2, 50))
    r2, c2 = g.pile_to_pixel(*g.pixel_to_pile(rows, cols))
    np.testing.assert_allclose(r2, rows, atol=1e-9)
    np.testing.assert_allclose(c2, cols, atol=1e-9)


@pytest.fixture(scope="module")
def two_logs():
    pile = PileSpec(terrain=flat(), logs=(
        LogSpec(centre_m=(0.4, -0.6, 0.1 + 0.15), orientation=quat_from_euler(0, 0, 0.3), length_m=2.5, diameter_m=0.3),
        LogSpec(centre_m=(-0.5, 1.2, 0.1 + 0.1), orientation=quat_from_euler(0, 0, -1.2), length_m=2.0, diameter_m=0.2),
    ))
    with World(pile) as w:
        return pile, render_ortho(w, OrthoRenderConfig(size_px=128, n_renders=3), seed=1)


def test_shapes_ranges_and_dtypes(two_logs):
    _, obs = two_logs
    assert obs.intensity.shape == (3, 128, 128) and obs.intensity.dtype == np.float32
    assert obs.depth.shape == (128, 128) and obs.instance.shape == (128, 128)
    assert 0.0 <= obs.intensity.min() and obs.intensity.max() <= 1.0
    assert set(np.unique(obs.instance)) == {0, 1, 2}
    # renders differ in colour and light, not in geometry
    assert not np.array_equal(obs.intensity[0], obs.intensity[1])


def test_depth_is_metric(two_logs):
    _, obs = two_logs
    h = obs.height()
    ground = h[obs.instance == 0]
    np.testing.assert_allclose(ground, 0.1, atol=1e-3)
    # top of log 0 (axis at 0.25 m, radius 0.15 m) is at 0.40 m
    assert h[obs.instance == 1].max() == pytest.approx(0.40, abs=3e-3)
    assert h[obs.instance == 2].max() == pytest.approx(0.30, abs=3e-3)


@pytest.mark.parametrize("i", [0, 1])
def test_masks_match_log_geometry(two_logs, i):
    pile, obs = two_logs
    log = pile.logs[i]
    X, Y = obs.grid.pixel_centres()
    a = log.axis()[:2] / np.linalg.norm(log.axis()[:2])
    rel = np.stack([X - log.centre_m[0], Y - log.centre_m[1]], -1)
    inside = (np.abs(rel @ a) < log.length_m / 2) & (np.abs(rel @ np.array([-a[1], a[0]])) < log.diameter_m / 2)
    mask = obs.log_mask(i)
    iou = (inside & mask).sum() / (inside | mask).sum()
    assert iou > 0.95


def test_target_mask_is_union(two_logs):
    _, obs = two_logs
    np.testing.assert_array_equal(obs.target_mask([0, 1]), obs.log_mask(0) | obs.log_mask(1))
    np.testing.assert_array_equal(target_mask(obs.instance, []), np.zeros_like(obs.log_mask(0)))


def test_obstacles_get_obstacle_codes():
    from synth.scene.generate import GenerationConfig, generate_pile

    pile, _ = generate_pile(2, GenerationConfig(n_logs=2, n_obstacles=3))
    with World(pile) as w:
        obs = render_ortho(w, OrthoRenderConfig(n_renders=1))
    codes = set(np.unique(obs.instance))
    assert codes >= {0, 1, 2}
    assert all(c < 3 or OBSTACLE_BASE <= c < OBSTACLE_BASE + 3 for c in codes)


def test_save_load_round_trip(two_logs, tmp_path):
    _, obs = two_logs
    path = obs.save(tmp_path / "ortho.npz")
    back = OrthoObservation.load(path)
    np.testing.assert_array_equal(back.intensity, obs.intensity)
    np.testing.assert_array_equal(back.depth, obs.depth)
    np.testing.assert_array_equal(back.instance, obs.instance)
    assert back.n_logs == 2 and back.extent_m == 5.0


def test_load_rejects_garbage(tmp_path):
    (tmp_path / "ortho.npz").write_bytes(b"garbage")
    with pytest.raises(PileFormatError, match="cannot read"):
        OrthoObservation.load(tmp_path / "ortho.npz")


def test_render_config_validation():
    with pytest.raises(ValueError, match="image size"):
        OrthoRenderConfig(size_px=4)
    with pytest.raises(ValueError, match="n_renders"):
        OrthoRenderConfig(n_renders=0)
