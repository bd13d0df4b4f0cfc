import math

import numpy as np
import pytest
import torch

from planner.augment import AugmentConfig, augment, flip_lr, rotate
from planner.loss import LossWeights, grasp_loss
from synth.geometry.frames import OrthoGrid, wrap_phi
from synth.geometry.grasp import Grasp
from synth.data.maps import decode_maps, encode_grasps

GRID = OrthoGrid(64, 5.0)


def _decode_single(maps):
    """Position (centroid of U) and angle (mean of C, S) of a map holding one grasp rectangle."""
    u = maps[3] > 0.5
    rows, cols = np.nonzero(u)
    x, y = GRID.pixel_to_pile(rows.mean(), cols.mean())
    phi = wrap_phi(math.atan2(maps[1][u].mean(), maps[0][u].mean()) / 2)
    return float(x), float(y), float(phi), float(maps[2][u].mean())


def _angle_diff(a, b):
    return abs(float(wrap_phi(a - b)))


def _sample(g, length_m: float = 0.2):
    maps = encode_grasps(GRID, [g], [0.9], length_m=length_m)
    inten = np.random.default_rng(0).random((64, 64)).astype(np.float32)
    depth = np.full((64, 64), 5.0, np.float32)
    return inten, depth, maps[3] > 0, maps


def test_loss_ignores_predictions_outside_u():
    g = Grasp(0.3, -0.2, 0.4, 0.8)
    tgt = torch.from_numpy(encode_grasps(GRID, [g], [0.9]))[None]
    pred = torch.zeros_like(tgt)
    pred[:, 3] = -2.0
    l1, _ = grasp_loss(pred, tgt)
    pred2 = pred.clone()
    outside = tgt[:, 3:4].expand_as(pred2) == 0
    pred2[:, [0, 1, 2, 4]] = torch.where(outside[:, [0, 1, 2, 4]], torch.randn_like(pred2[:, [0, 1, 2, 4]]) * 5,
                                         pred2[:, [0, 1, 2, 4]])
    l2, _ = grasp_loss(pred2, tgt)
    assert torch.allclose(l1, l2)
    # ...while predictions inside U do change it, by exactly lambda * u * err^2 / N^2
    pred3 = pred.clone()
    r, c = np.argwhere(tgt[0, 3].numpy() > 0)[0]
    pred3[0, 4, r, c] += 1.0  # B error at one pixel
    l3, _ = grasp_loss(pred3, tgt)
    b = tgt[0, 4, r, c]
    expected = LossWeights().lambda_b * (((b - 1.0) ** 2 - b ** 2) / 64 ** 2)
    assert float(l3 - l1) == pytest.approx(float(expected), rel=1e-4)


def test_loss_rejects_bad_shapes():
    with pytest.raises(ValueError):
        grasp_loss(torch.zeros(1, 4, 8, 8), torch.zeros(1, 4, 8, 8))


@pytest.mark.parametrize("theta", [math.pi / 2, math.pi, -math.pi / 2, 0.7, -2.1])
@pytest.mark.parametrize("flip", [False, True])
def test_rotated_flipped_sample_decodes_to_transformed_grasp(theta, flip):
    g = Grasp(0.8, 0.5, 0.3, 0.9)
    inten, depth, mask, maps = _sample(g, length_m=0.9)  # a long region: its orientation is visible
    x, y, phi = g.x_m, g.y_m, g.phi_rad
    if flip:
        inten, depth, mask, maps = flip_lr(inten, depth, mask, maps)
        x, phi = -x, -phi
    inten, depth, mask, maps = rotate(inten, depth, mask, maps, theta)
    ct, st = math.cos(theta), math.sin(theta)
    x, y, phi = ct * x - st * y, st * x + ct * y, phi + theta
    dx, dy, dphi, dw = _decode_single(maps)
    assert math.hypot(dx - x, dy - y) < 0.6 * GRID.pixel_m + 1e-6
    assert _angle_diff(dphi, phi) < 0.02
    assert dw == pytest.approx(0.9, abs=1e-5)
    # the whole-image decoder of synth.data.maps agrees with the transformed angle on every U pixel
    phis, _, u, _ = decode_maps(maps)
    assert all(_angle_diff(p, phi) < 1e-4 for p in phis[u > 0.5])
    # the region keeps its orientation: its long axis (closing axis) lies along the new phi
    rows, cols = np.nonzero(maps[3] > 0.5)
    xs, ys = GRID.pixel_to_pile(rows, cols)
    pts = np.stack([xs - xs.mean(), ys - ys.mean()])
    w, v = np.linalg.eigh(pts @ pts.T)
    long_axis = math.atan2(v[1, 1], v[0, 1])
    assert _angle_diff(long_axis, phi) < 0.08


def test_augment_random_is_consistent_and_bounded():
    g = Grasp(-0.5, 0.2, -1.0, 0.6)
    inten, depth, mask, maps = _sample(g)
    rng = np.random.default_rng(3)
    for _ in range(5):
        i2, d2, m2, mp2 = augment(inten, depth, mask, maps, rng)
        assert i2.min() >= 0 and i2.max() <= 1 and i2.dtype == np.float32
        assert np.isfinite(d2).all()
        # C^2 + S^2 == 1 on grasp pixels (angles rotated, not smeared)
        u = mp2[3] > 0.5
        assert u.sum() > 0.5 * (maps[3] > 0).sum()
        np.testing.assert_allclose(mp2[0][u] ** 2 + mp2[1][u] ** 2, 1.0, atol=1e-5)
    # inputs untouched
    np.testing.assert_array_equal(maps, encode_grasps(GRID, [g], [0.9]))
    # "off" is the identity
    i3, d3, m3, mp3 = augment(inten, depth, mask, maps, rng, AugmentConfig.off())
    np.testing.assert_allclose(i3, inten)
    np.testing.assert_array_equal(mp3, maps)


def test_augment_config_validation():
    with pytest.raises(ValueError):
        AugmentConfig(rotation="sideways")
    with pytest.raises(ValueError):
        AugmentConfig(flip_prob=2.0)
