"""Surveyed log ends with their accuracy: :class:`SurveyEnd`, and a GNSS point's accuracy from what its
receiver reports, or typical values of its fix (:func:`point_accuracy`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


#: No survey point is taken as more accurate than this, 1 sigma [m] (a receiver may report 0)
MIN_POINT_SIGMA_M = 1e-3
#: A survey point is looked for, and may place an end, within this many of its sigmas [-]
SURVEY_REACH_SIGMAS = 3
#: Typical 1-sigma accuracies (horizontal radial, vertical) [m] when a receiver reports none.
TYPICAL_ACCURACY_M = {"rtk_fixed": (0.015, 0.025), "rtk_float": (0.25, 0.40), "dgnss": (0.5, 1.0),
                      "single": (2.0, 4.0), "none": (10.0, 20.0)}


@dataclass(frozen=True)
class SurveyEnd:
    """One surveyed log end, with its accuracy (per axis)."""

    position_m: np.ndarray  # (3,) in the frame in use [m]
    sigma_h_m: float  # 1 sigma per horizontal axis [m] (the receiver's radial accuracy / sqrt 2)
    sigma_v_m: float  # 1 sigma vertical [m]
    fix: str  # reconstruct.survey.gnss.FIXES

    @property
    def label(self) -> str:
        """``fixed`` or ``float`` (what placed an end taken from this point)."""
        return "fixed" if self.fix == "rtk_fixed" else "float"

    def moved(self, T: np.ndarray) -> "SurveyEnd":
        p = np.asarray(T, dtype=float)[:3, :3] @ self.position_m + np.asarray(T, dtype=float)[:3, 3]
        return SurveyEnd(p, self.sigma_h_m, self.sigma_v_m, self.fix)

    def sigma_along(self, u: np.ndarray) -> float:
        """1-sigma accuracy along the unit direction ``u`` [m]."""
        u = np.asarray(u, dtype=float)
        return float(math.sqrt(self.sigma_h_m ** 2 * (u[0] ** 2 + u[1] ** 2) + self.sigma_v_m ** 2 * u[2] ** 2))

    @property
    def sigma_3d_m(self) -> float:
        return float(math.sqrt(2 * self.sigma_h_m ** 2 + self.sigma_v_m ** 2))


def point_accuracy(p: Any) -> tuple[float, float]:
    """(horizontal radial, vertical) 1-sigma accuracy [m] of a :class:`reconstruct.survey.gnss.GnssPoint`:
    the receiver's estimates, at least the scatter of its averaged epochs; typical values of its fix
    when it reports none (:data:`TYPICAL_ACCURACY_M`)."""
    th, tv = TYPICAL_ACCURACY_M.get(p.fix, TYPICAL_ACCURACY_M["none"])
    h = p.h_acc_m if math.isfinite(p.h_acc_m) else th
    v = p.v_acc_m if math.isfinite(p.v_acc_m) else tv
    return float(max(h, p.spread_h_m, MIN_POINT_SIGMA_M)), float(max(v, p.spread_v_m, MIN_POINT_SIGMA_M))
