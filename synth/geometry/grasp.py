"""The grasp: one owner for the type every package exchanges.

A grasp is ``(x_m, y_m, phi_rad, width_m)`` in the pile frame (see :mod:`synth.geometry.frames` for the
angle convention): the grapple's vertical axis passes through (x, y), its closing axis points along
``phi_rad`` and the claws open ``width_m`` apart before closing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from synth.geometry.frames import wrap_phi

#: Opening-width range of the grapple [m] (the paper's target map range).
MIN_WIDTH_M = 0.30
MAX_WIDTH_M = 1.55
#: Constant width of the grasp rectangle used in target maps and overlap tests [m].
RECT_WIDTH_M = 0.20


@dataclass(frozen=True)
class Grasp:
    x_m: float  # pile frame [m]
    y_m: float  # pile frame [m]
    phi_rad: float  # closing-axis angle from +x, counter-clockwise [rad], pi-periodic
    width_m: float  # opening width [m]

    def __post_init__(self) -> None:
        for name in ("x_m", "y_m", "phi_rad", "width_m"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(v):
                raise ValueError(f"grasp {name} must be a finite number, got {v!r}")
        if not MIN_WIDTH_M - 1e-9 <= self.width_m <= MAX_WIDTH_M + 1e-9:
            raise ValueError(
                f"grasp width_m must be in [{MIN_WIDTH_M}, {MAX_WIDTH_M}] m (the grapple's "
                f"opening range), got {self.width_m}"
            )
        object.__setattr__(self, "phi_rad", float(wrap_phi(self.phi_rad)))

    def closing_axis(self) -> np.ndarray:
        return np.array([math.cos(self.phi_rad), math.sin(self.phi_rad)])

    def rectangle(self, rect_width_m: float = RECT_WIDTH_M) -> np.ndarray:
        """Corners (4, 2) [m] of the grasp rectangle: ``width_m`` along the closing axis,
        ``rect_width_m`` across it, centred on (x, y)."""
        return self.footprint(0.0, rect_width_m)

    def footprint(self, beyond_m: float, across_m: float) -> np.ndarray:
        """Corners (4, 2) [m] of the opening extended by ``beyond_m`` past each end along the closing axis
        (where the claws come down), ``across_m`` wide across it, centred on (x, y)."""
        a = self.closing_axis()
        b = np.array([-a[1], a[0]])
        c = np.array([self.x_m, self.y_m])
        hw, hr = self.width_m / 2 + beyond_m, across_m / 2
        return np.array([c - a * hw - b * hr, c + a * hw - b * hr, c + a * hw + b * hr, c - a * hw + b * hr])

    def to_dict(self) -> dict:
        return {"x_m": self.x_m, "y_m": self.y_m, "phi_rad": self.phi_rad, "width_m": self.width_m}
