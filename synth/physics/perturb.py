"""Positioning error: where the real crane puts the grapple when asked for a grasp.

A field grasp is executed by a crane whose boom tip stands a few centimetres off the commanded
point (RTK survey of the log ends ±1–2 cm, the reconstruction's own error, the crane's joint
sensing and boom deflection) and whose rotator is a degree or two off. :class:`PositioningError`
names that error as two isotropic Gaussian standard deviations; :func:`perturbed_grasps` draws
repeatable perturbed copies of a grasp from it. The twin's robust labels, the field row of the
evaluation and the robustness benchmark all draw through here, so they mean the same thing by
"σ 2 cm, 2°".
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np

from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, Grasp


@dataclass(frozen=True)
class PositioningError:
    """Gaussian positioning error of the executed grasp about the commanded one.

    ``sigma_xy_m`` is the standard deviation of each horizontal coordinate (x and y independent);
    ``sigma_phi_deg`` that of the rotator angle. The width is not perturbed: the claws open to
    the commanded width by their own cylinder stroke, which the crane measures directly.
    """

    sigma_xy_m: float = 0.02  # per horizontal axis [m]
    sigma_phi_deg: float = 2.0  # rotator angle [deg]

    def __post_init__(self) -> None:
        for name in ("sigma_xy_m", "sigma_phi_deg"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"positioning error {name} must be a finite number > 0, got {v!r}")
        if self.sigma_xy_m > 0.5 or self.sigma_phi_deg > 45:
            raise ValueError(f"positioning error ({self.sigma_xy_m} m, {self.sigma_phi_deg} deg) is not a positioning "
                             "error (sigma_xy_m <= 0.5 m, sigma_phi_deg <= 45 deg)")

    @staticmethod
    def parse(text: str) -> "PositioningError":
        """``"0.02,2"`` (metres, degrees) → PositioningError; ValueError naming the format otherwise."""
        try:
            xy, phi = (float(v) for v in text.split(","))
        except ValueError as e:
            raise ValueError(f"positioning error {text!r} must be 'SIGMA_XY_M,SIGMA_PHI_DEG', e.g. '0.02,2'") from e
        return PositioningError(xy, phi)

    def to_dict(self) -> dict:
        return {"sigma_xy_m": self.sigma_xy_m, "sigma_phi_deg": self.sigma_phi_deg}

    def label(self) -> str:
        return f"σ {self.sigma_xy_m * 100:g} cm, {self.sigma_phi_deg:g}°"


def grasp_rng(seed: int, *keys: object) -> np.random.Generator:
    """A generator seeded from ``seed`` and any keys (pile seed, subset, grasp rank …), the same in
    every process: the perturbation draws of a grasp never depend on what ran before it."""
    text = repr((int(seed), *keys)).encode()
    return np.random.default_rng(int.from_bytes(hashlib.sha256(text).digest()[:8], "little"))


def perturbed_grasps(grasp: Grasp, error: PositioningError, n: int, rng: np.random.Generator) -> list[Grasp]:
    """``n`` copies of ``grasp`` moved by draws of ``error`` (x, y Gaussian; phi Gaussian)."""
    if n < 0:
        raise ValueError(f"number of perturbed copies must be >= 0, got {n}")
    d = rng.standard_normal((n, 3))
    width = min(max(grasp.width_m, MIN_WIDTH_M), MAX_WIDTH_M)
    return [Grasp(grasp.x_m + error.sigma_xy_m * dx, grasp.y_m + error.sigma_xy_m * dy,
                  grasp.phi_rad + math.radians(error.sigma_phi_deg) * dp, width)
            for dx, dy, dp in d]
