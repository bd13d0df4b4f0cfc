import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from synth.geometry.frames import OrthoGrid
from synth.geometry.grasp import Grasp, RECT_WIDTH_M
from synth.data.maps import (
    MAP_CHANNELS, U_BREADTH_M, U_LENGTH_M, decode_at, decode_maps, denormalise_width, encode_grasps, normalise_width,
    rectangle_mask, region_mask,
)

GRID = OrthoGrid(128, 5.0)


def _pixel(grid, x, y):
    r, c = grid.pile_to_pixel(x, y)
    return int(round(float(r))), int(round(float(c)))


@settings(max_examples=60, deadline=None)
@given(phi=st.floats(-10, 10), width=st.floats(0.30, 1.55), x=st.floats(-1.5, 1.5), y=st.floats(-1.5, 1.5),
       b=st.floats(0.0, 1.0))
def test_round_trip_at_the_grasp_centre(phi, width, x, y, b):
    g = Grasp(x, y, phi, width)
    maps = encode_grasps(GRID, [g], [b])
    assert maps.shape == (5, 128, 128) and maps.dtype == np.float32
    row, col = _pixel(GRID, x, y)
    phi_d, w_d, u, b_d = decode_at(maps, row, col)
    assert u == 1.0
    # pi-periodic: compare on the doubled angle
    assert abs(math.sin(phi_d - g.phi_rad)) < 1e-5
    assert abs(phi_d - g.phi_rad) < 1e-5 or abs(abs(phi_d - g.phi_rad) - math.pi) < 1e-5
    assert w_d == pytest.approx(width, abs=1e-6)
    assert b_d == pytest.approx(b, abs=1e-6)


def test_angle_is_pi_periodic_and_in_the_pile_frame():
    a = encode_grasps(GRID, [Grasp(0, 0, 0.3, 0.8)], [1.0])
    b = encode_grasps(GRID, [Grasp(0, 0, 0.3 + math.pi, 0.8)], [1.0])
    np.testing.assert_allclose(a[:2], b[:2], atol=1e-6)
    # phi = pi/2 (closing along pile +y = image up/down): a region long along the closing axis is tall
    maps = encode_grasps(GRID, [Grasp(0, 0, math.pi / 2, 1.2)], [1.0], length_m=0.8)
    rows, cols = np.nonzero(maps[3])
    assert np.ptp(rows) > 3 * np.ptp(cols)
    phi, _, _, _ = decode_at(maps, *_pixel(GRID, 0, 0))
    assert abs(abs(phi) - math.pi / 2) < 1e-6


def test_rectangle_size_matches_the_grasp():
    g = Grasp(0.1, -0.2, 0.0, 1.0)
    m = rectangle_mask(GRID, g)
    px = GRID.pixel_m
    area = m.sum() * px * px
    assert area == pytest.approx(1.0 * RECT_WIDTH_M, rel=0.15)
    X, Y = GRID.pixel_centres()
    assert np.all(np.abs(X[m] - 0.1) <= 0.5 + 1e-9) and np.all(np.abs(Y[m] + 0.2) <= 0.1 + 1e-9)
    assert m[_pixel(GRID, 0.1 + 0.45, -0.2)] and not m[_pixel(GRID, 0.1 + 0.6, -0.2)]


def test_negative_is_all_zero_and_outside_is_zero():
    assert not encode_grasps(GRID, [], []).any()
    maps = encode_grasps(GRID, [Grasp(0, 0, 0.5, 0.6)], [0.9])
    off = maps[3] == 0
    assert not maps[:, off].any()


def test_u_marks_the_graspable_region_not_the_footprint():
    g = Grasp(0.4, 0.1, 0.7, 1.3)
    u = encode_grasps(GRID, [g], [1.0])[3].astype(bool)
    np.testing.assert_array_equal(u, region_mask(GRID, g))
    area = u.sum() * GRID.pixel_m ** 2
    assert area == pytest.approx(U_LENGTH_M * U_BREADTH_M, rel=0.3)
    # a pixel 0.3 m from the centre along the closing axis is inside the footprint, not the region
    a = g.closing_axis()
    rc = _pixel(GRID, 0.4 + 0.3 * a[0], 0.1 + 0.3 * a[1])
    assert rectangle_mask(GRID, g)[rc] and not u[rc]
    with pytest.raises(ValueError, match="positive size"):
        encode_grasps(GRID, [g], [1.0], length_m=0.0)


def test_overlaps_union_and_nearest_centre_wins():
    g1 = Grasp(0.0, 0.0, 0.0, 1.2)  # closing along x, centre (0, 0)
    g2 = Grasp(0.12, 0.0, 0.0, 0.6)  # centre (0.12, 0): regions overlap on 0.02 <= x <= 0.1
    for order in ([g1, g2], [g2, g1]):
        bal = [0.9 if g is g1 else 0.5 for g in order]
        maps = encode_grasps(GRID, order, bal)
        union = region_mask(GRID, g1) | region_mask(GRID, g2)
        np.testing.assert_array_equal(maps[3].astype(bool), union)
        X, Y = GRID.pixel_centres()
        both = region_mask(GRID, g1) & region_mask(GRID, g2)
        assert both.any()
        d1, d2 = np.hypot(X, Y), np.hypot(X - 0.12, Y)
        near1, near2 = both & (d1 < d2), both & (d1 > d2)
        assert near1.any() and near2.any()
        assert np.allclose(maps[2][near1], 1.2) and np.allclose(maps[4][near1], 0.9)
        assert np.allclose(maps[2][near2], 0.6) and np.allclose(maps[4][near2], 0.5)


def test_decode_maps_matches_decode_at():
    maps = encode_grasps(GRID, [Grasp(0.3, 0.3, -1.0, 0.9), Grasp(-0.8, 0.1, 1.2, 0.4)], [0.7, 0.95])
    phi, w, u, b = decode_maps(maps)
    for rc in [_pixel(GRID, 0.3, 0.3), _pixel(GRID, -0.8, 0.1), (0, 0)]:
        assert (phi[rc], w[rc], u[rc], b[rc]) == pytest.approx(decode_at(maps, *rc), abs=1e-6)
    assert MAP_CHANNELS == ("C", "S", "W", "U", "B")


def test_width_normalisation_round_trip():
    w = np.array([0.30, 0.9, 1.55])
    np.testing.assert_allclose(normalise_width(w), [0.0, 0.48, 1.0])
    np.testing.assert_allclose(denormalise_width(normalise_width(w)), w)


@pytest.mark.parametrize("bal", [float("nan"), 1.5, -2.0])
def test_bad_balance_is_refused(bal):
    with pytest.raises(ValueError, match="balance"):
        encode_grasps(GRID, [Grasp(0, 0, 0, 0.5)], [bal])


def test_bad_inputs():
    with pytest.raises(ValueError, match="one balance per grasp"):
        encode_grasps(GRID, [Grasp(0, 0, 0, 0.5)], [])
    with pytest.raises(ValueError, match="width_m"):
        Grasp(0, 0, 0, 1.8)
    with pytest.raises(ValueError, match="shape"):
        decode_at(np.zeros((4, 8, 8)), 0, 0)
