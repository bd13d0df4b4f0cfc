"""How a gripped load will hang: the balance f3 can score, from the target masks and the load's mass.

The grapple hangs from the rotator's unactuated pivot, so after the lift the grapple and its load
swing until their joint centre of mass lies under the pivot. A load gripped a horizontal distance
``d`` from its own centre of mass then tilts the grapple by

    tan(beta) = d / (h_load + M_grapple / m_load)

(moments about the pivot, small swing): ``h_load`` is how far the load's centre of mass hangs below
the pivot and ``M_grapple`` the grapple's own mass times its centre of mass's drop below it; a
heavier load tilts more for the same offset.

``d`` is taken from the image, along the load: the distance from the grasp centre to the centroid of
the target union's mask (the part of each log seen from above; each pixel weighs the same), measured
along the mask's principal axis (``offset="along_axis"``, the default). Across the logs the claws gather
the load to the grapple's middle as they close, so an offset across them does not tilt the load; it is
U's business (collisions, whether the claws close). The first version measured the whole distance
(``offset="radial"``); both fit the twin's tilts equally well, and on 328 held-out piles f3 chose the
same grasp with either on 239 and succeeded as often (docs/results/README.md, "eval-*-1200").

The two parameters are fitted to the twin's tilt of successful grasps on held-out piles (seeds
940,000,000+, the tried grasps of docs/results/ranking-v3model-rev4) and checked on other piles (seeds
970,000,000+): ``python -m experiments.hang_fit`` (docs/model.md, "The balance f3 scores").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np


@dataclass(frozen=True)
class HangModel:
    """The tilt of a gripped load, ``tan(beta) = d / (load_drop_m + grapple_moment_kg_m / m_load)``."""

    load_drop_m: float = 0.95  # the load's centre of mass below the rotator's pivot (the twin's grapple:
    #                            fitted, see the module docstring) [m]
    grapple_moment_kg_m: float = 110.0  # the grapple's mass times its centre of mass's drop below the pivot
    #                                     (fitted with load_drop_m, loads at 900 kg/m^3) [kg m]
    offset: Literal["along_axis", "radial"] = "along_axis"  # which part of the grasp's offset from the
    #                                     load's centroid tilts it (module docstring)

    def __post_init__(self) -> None:
        if not (self.load_drop_m > 0 and self.grapple_moment_kg_m >= 0):
            raise ValueError(f"HangModel needs load_drop_m > 0 and grapple_moment_kg_m >= 0, got "
                             f"{self.load_drop_m}, {self.grapple_moment_kg_m}")
        if self.offset not in ("along_axis", "radial"):
            raise ValueError(f"HangModel offset must be 'along_axis' or 'radial', got {self.offset!r}")

    @property
    def tag(self) -> str:
        """What an evaluation's fingerprint records of it: its offset and parameters."""
        return f"{self.offset}-{self.load_drop_m:g}m-{self.grapple_moment_kg_m:g}kgm"

    def lever_m(self, load_kg: float) -> float:
        """The offset that tilts the grapple by 45 deg for a load of ``load_kg`` [m]."""
        if not load_kg > 0:
            raise ValueError(f"a load's mass must be > 0 kg, got {load_kg}")
        return self.load_drop_m + self.grapple_moment_kg_m / load_kg

    def cos_beta(self, offset_m, load_kg: float):
        """cos(beta) of a load gripped ``offset_m`` from its centre of mass (element-wise)."""
        lever = self.lever_m(load_kg)
        return lever / np.sqrt(lever ** 2 + np.square(offset_m))

    def offsets_m(self, mask: np.ndarray, pixel_m: float, rows, cols) -> np.ndarray:
        """The tilting offset [m] of grasp centres at pixel ``(rows, cols)`` (broadcast) from the load
        whose top-down mask is ``mask`` (H, W; non-empty)."""
        rr, cc = np.nonzero(mask)
        dr, dc = np.asarray(rows, np.float32) - rr.mean(), np.asarray(cols, np.float32) - cc.mean()
        if self.offset == "radial":
            return np.float32(pixel_m) * np.hypot(dr, dc)
        ar, ac = principal_axis(rr, cc)
        return np.float32(pixel_m) * np.abs(dr * ar + dc * ac)

    def cos_beta_maps(self, subset_masks: np.ndarray, pixel_m: float, load_kg: Sequence[float]) -> np.ndarray:
        """(N, H, W) float32: cos(beta) of a grasp centred on each pixel, for each subset's mask (N, H, W)
        and load mass; 1 everywhere for an empty mask."""
        n, h, w = subset_masks.shape
        if len(load_kg) != n:
            raise ValueError(f"{n} subset masks but {len(load_kg)} load masses")
        rows, cols = np.arange(h, dtype=np.float32)[:, None], np.arange(w, dtype=np.float32)[None, :]
        out = np.ones((n, h, w), np.float32)
        for k in range(n):
            if subset_masks[k].any():
                out[k] = self.cos_beta(self.offsets_m(subset_masks[k], pixel_m, rows, cols), float(load_kg[k]))
        return out


def principal_axis(rr: np.ndarray, cc: np.ndarray) -> tuple[float, float]:
    """Unit (row, col) direction of the largest spread of the pixels ``(rr, cc)``: along the logs of a
    load (a round blob gives some direction; its offsets then hardly matter)."""
    if len(rr) < 2:
        return 1.0, 0.0
    cov = np.cov(np.stack([rr, cc]).astype(np.float64))
    _, vecs = np.linalg.eigh(cov)  # eigenvalues ascending
    return float(vecs[0, -1]), float(vecs[1, -1])


def tilt_deg(cos_beta: float) -> float:
    """beta [deg] of a balance value cos(beta)."""
    return math.degrees(math.acos(min(1.0, max(-1.0, float(cos_beta)))))
