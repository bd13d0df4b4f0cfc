"""How a gripped load will hang: the balance f3 can score, from the target masks and the load's mass.

The grapple hangs from the rotator's unactuated pivot, so after the lift the grapple and its load
swing until their joint centre of mass lies under the pivot. A load gripped a horizontal distance
``d`` from its own centre of mass then tilts the grapple by

    tan(beta) = d / (h_load + M_grapple / m_load)

(moments about the pivot, small swing): ``h_load`` is how far the load's centre of mass hangs below
the pivot and ``M_grapple`` the grapple's own mass times its centre of mass's drop below it; a
heavier load tilts more for the same offset. ``d`` is taken from the image: the distance from the
grasp centre to the centroid of the target union's mask (the part of each log seen from above;
each pixel weighs the same). Both parameters are fitted to the twin's tilt of 294 successful grasps
on held-out piles (seeds 940,000,000+, the tried grasps of docs/results/ranking-v3model-rev4); on
393 successful grasps of other piles (seeds 970,000,000+) the model's tilt is within 2.1 deg of the
twin's on average, rank correlation 0.92 (``python -m experiments.hang_fit``), where the network's B
map is within 5.4-5.7 deg, rank correlation 0.19 (docs/results/README.md, "aft4").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class HangModel:
    """The tilt of a gripped load, ``tan(beta) = d / (load_drop_m + grapple_moment_kg_m / m_load)``."""

    load_drop_m: float = 0.95  # the load's centre of mass below the rotator's pivot (the twin's grapple:
    #                            fitted, see the module docstring) [m]
    grapple_moment_kg_m: float = 110.0  # the grapple's mass times its centre of mass's drop below the pivot
    #                                     (fitted with load_drop_m, loads at 900 kg/m^3) [kg m]

    def __post_init__(self) -> None:
        if not (self.load_drop_m > 0 and self.grapple_moment_kg_m >= 0):
            raise ValueError(f"HangModel needs load_drop_m > 0 and grapple_moment_kg_m >= 0, got "
                             f"{self.load_drop_m}, {self.grapple_moment_kg_m}")

    def lever_m(self, load_kg: float) -> float:
        """The offset that tilts the grapple by 45 deg for a load of ``load_kg`` [m]."""
        if not load_kg > 0:
            raise ValueError(f"a load's mass must be > 0 kg, got {load_kg}")
        return self.load_drop_m + self.grapple_moment_kg_m / load_kg

    def cos_beta(self, offset_m, load_kg: float):
        """cos(beta) of a load gripped ``offset_m`` from its centre of mass (element-wise)."""
        lever = self.lever_m(load_kg)
        return lever / np.sqrt(lever ** 2 + np.square(offset_m))

    def cos_beta_maps(self, subset_masks: np.ndarray, pixel_m: float, load_kg: Sequence[float]) -> np.ndarray:
        """(N, H, W) float32: cos(beta) of a grasp centred on each pixel, for each subset's mask (N, H, W)
        and load mass; 1 everywhere for an empty mask."""
        n, h, w = subset_masks.shape
        if len(load_kg) != n:
            raise ValueError(f"{n} subset masks but {len(load_kg)} load masses")
        rows, cols = np.arange(h, dtype=np.float32)[:, None], np.arange(w, dtype=np.float32)[None, :]
        out = np.ones((n, h, w), np.float32)
        for k in range(n):
            rr, cc = np.nonzero(subset_masks[k])
            if len(rr):
                offset = np.float32(pixel_m) * np.hypot(rows - rr.mean(), cols - cc.mean())
                out[k] = self.cos_beta(offset, float(load_kg[k]))
        return out


def tilt_deg(cos_beta: float) -> float:
    """beta [deg] of a balance value cos(beta)."""
    return math.degrees(math.acos(min(1.0, max(-1.0, float(cos_beta)))))
