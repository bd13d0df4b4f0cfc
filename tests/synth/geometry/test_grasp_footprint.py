"""synth.geometry.grasp: the grasp rectangle and the claws' footprint."""

import math

import numpy as np
import pytest

from synth.geometry.grasp import RECT_WIDTH_M, Grasp


def test_the_rectangle_is_the_footprint_of_the_opening_alone():
    g = Grasp(0.3, -0.2, 0.7, 0.9)
    assert np.array_equal(g.rectangle(), g.footprint(0.0, RECT_WIDTH_M))


def test_the_footprint_reaches_past_each_end_and_spans_across():
    g = Grasp(1.0, 2.0, math.pi / 2, 0.8)  # the closing axis along +y
    corners = g.footprint(0.05, 0.22)
    assert corners[:, 1].min() == pytest.approx(2.0 - 0.45) and corners[:, 1].max() == pytest.approx(2.0 + 0.45)
    assert corners[:, 0].min() == pytest.approx(1.0 - 0.11) and corners[:, 0].max() == pytest.approx(1.0 + 0.11)
