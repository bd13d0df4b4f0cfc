"""Test-time views are mapped back with the training augmentation's geometry.

A mirrored picture shows a grasp at (x, y, phi) at (-x, y, -phi): its cos 2phi stays and its
sin 2phi changes sign; a quarter turn adds 90 deg (both signs flip). The references here are
independent of planner.inference: the augmentation of planner.augment (whose geometry is checked
against decoded grasps in test_planner_loss_augment.py) and a stand-in network that computes its
grasp from the geometry of the target mask it is shown, so it is exactly equivariant. All angles
are far from the symmetric 0 and 90 deg, where a lost sign would not show.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from planner.augment import flip_lr, rotate
from planner.inference import Objective, Planner, _view, _view_back, _view_list, plan
from planner.model import UNetConfig, build_unet
from synth.geometry.frames import OrthoGrid, wrap_phi
from synth.geometry.grasp import Grasp
from synth.data.maps import decode_maps, encode_grasps
from synth.render.ortho import OrthoObservation

TINY = UNetConfig.tiny()  # 32 px over 5 m
GRID = OrthoGrid(TINY.size_px, TINY.extent_m)


def _angle_deg(a: float, b: float) -> float:
    return abs(math.degrees(float(wrap_phi(a - b))))


def _augmented(maps: np.ndarray, flip: bool, k: int, image: np.ndarray | None = None):
    """``maps`` (5, H, W) and an input ``image`` (2, H, W) as the training augmentation shows them
    in view (flip, k)."""
    inten, depth = image if image is not None else np.zeros((2, *maps.shape[1:]), np.float32)
    mask = np.zeros(maps.shape[1:], bool)
    if flip:
        inten, depth, mask, maps = flip_lr(inten, depth, mask, maps)
    inten, depth, _, maps = rotate(inten, depth, mask, maps, k * math.pi / 2)
    return maps, np.stack([inten, depth])


@pytest.mark.parametrize("flip,k", _view_list(8))
def test_view_back_undoes_the_augmentation_of_each_view(flip, k):
    g = Grasp(0.6, -0.4, math.radians(32.0), 0.9)
    maps = encode_grasps(GRID, [g], [0.8], length_m=0.9).astype(np.float32)
    back = _view_back(_augmented(maps, flip, k)[0][None], flip, k)[0]
    np.testing.assert_allclose(back, maps, atol=1e-6)
    phis, _, u, _ = decode_maps(back)
    assert (u > 0.5).any() and max(_angle_deg(p, g.phi_rad) for p in phis[u > 0.5]) < 1e-3
    # and the inputs are shown the way the augmentation shows them
    img = np.random.default_rng(1).random((1, 2, *maps.shape[1:])).astype(np.float32)
    want = _augmented(maps, flip, k, img[0])[1]
    np.testing.assert_array_equal(_view(img, flip, k)[0], want)


def _equivariant_net(x: np.ndarray) -> np.ndarray:
    """Stand-in network: for each target mask (last input channel) a grasp across its principal
    axis at its centroid, 0.8 m wide, balance 0.9; U as logits (+-6)."""
    out = np.zeros((len(x), 5, x.shape[-2], x.shape[-1]), np.float32)
    for n, m in enumerate(x[:, -1] > 0.5):
        rows, cols = np.nonzero(m)
        px, py = GRID.pixel_to_pile(rows, cols)
        pts = np.stack([px - px.mean(), py - py.mean()])
        _, v = np.linalg.eigh(pts @ pts.T)
        axis = math.atan2(v[1, 1], v[0, 1])
        g = Grasp(float(px.mean()), float(py.mean()), float(wrap_phi(axis + math.pi / 2)), 0.8)
        maps = encode_grasps(GRID, [g], [0.9], length_m=0.5)
        maps[3] = np.where(maps[3] > 0.5, 6.0, -6.0)
        out[n] = maps
    return out


def _diagonal_log(direction_deg: float) -> OrthoObservation:
    """One log 3 m long, 0.35 m thick, along ``direction_deg`` through (0.3, -0.2) m."""
    xs, ys = GRID.pixel_centres()
    d = np.array([math.cos(math.radians(direction_deg)), math.sin(math.radians(direction_deg))])
    along = (xs - 0.3) * d[0] + (ys + 0.2) * d[1]
    across = -(xs - 0.3) * d[1] + (ys + 0.2) * d[0]
    inst = ((np.abs(along) < 1.5) & (np.abs(across) < 0.175)).astype(np.int16)
    depth = np.where(inst > 0, 4.7, 5.0).astype(np.float32)
    inten = np.where(inst > 0, 0.8, 0.3).astype(np.float32)[None]
    return OrthoObservation(intensity=inten, depth=depth, instance=inst, extent_m=GRID.extent_m, camera_height_m=5.0,
                            n_logs=1)


@pytest.mark.parametrize("views", [2, 4, 8])
@pytest.mark.parametrize("direction_deg", [32.0, -61.0])
def test_averaged_views_keep_the_grasp_angle_of_an_equivariant_network(views, direction_deg):
    torch.manual_seed(0)
    planners = {}
    for v in (1, views):
        p = Planner(build_unet(TINY), TINY, precision="fp32", views=v)
        p._predict_once = _equivariant_net  # the views' own plumbing (predict) stays real
        planners[v] = p
    obs = _diagonal_log(direction_deg)
    want = math.radians(direction_deg + 90.0)  # across the log
    one = plan(obs, planners[1], Objective("f1")).best.grasp
    assert _angle_deg(one.phi_rad, want) < 3.0  # the stand-in is what it claims
    many = plan(obs, planners[views], Objective("f1")).best.grasp
    assert _angle_deg(many.phi_rad, one.phi_rad) < 1.0, (
        f"{views} views turn the grasp from {math.degrees(one.phi_rad):.1f} to {math.degrees(many.phi_rad):.1f} deg")
    assert math.hypot(many.x_m - one.x_m, many.y_m - one.y_m) < 2.0 * GRID.pixel_m
