"""Frames, pixels and the grasp-angle convention — stated once, here.

Pile frame: see :mod:`synth.scene.pile` (metres, z up, origin at the terrain patch centre).

Orthographic images (every top-down render, mask and grasp map) are square grids over the terrain
patch, seen from above:

* pixel ``(row, col)`` covers the square whose centre is
  ``x = -extent/2 + (col + 0.5) * pixel_m``, ``y = +extent/2 - (row + 0.5) * pixel_m``;
  i.e. columns grow with +x, rows grow with -y (north-up picture, row 0 at the top).

Grasp angle ``phi_rad``: the direction of the grapple's *closing axis* (claw tip to claw tip,
the direction in which the opening ``width_m`` is measured), counter-clockwise from the pile +x
axis, in the pile frame. Grasps are pi-periodic: ``phi`` and ``phi + pi`` are the same grasp. A
log lying along +y is grasped across with ``phi = 0``. In image (row, col) space the angle's sign
flips because rows point down: :func:`phi_to_image` / :func:`phi_from_image` convert.

Homogeneous transforms are 4x4 float64 arrays named ``T_to_from``: ``p_to = T_to_from @ p_from``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OrthoGrid:
    """The pixel grid of a square top-down image over the terrain patch."""

    size_px: int = 128  # pixels per side [-]
    extent_m: float = 5.0  # side of the imaged square [m]

    def __post_init__(self) -> None:
        if not 16 <= self.size_px <= 2048:
            raise ValueError(f"image size must be in [16, 2048] px, got {self.size_px}")
        if self.extent_m <= 0:
            raise ValueError(f"image extent must be > 0 m, got {self.extent_m}")

    @property
    def pixel_m(self) -> float:
        """Side of one pixel [m]."""
        return self.extent_m / self.size_px

    def pixel_to_pile(self, row, col):
        """Pixel (row, col) — integers or fractional — to pile-frame (x, y) [m] of the centre."""
        row = np.asarray(row, dtype=float)
        col = np.asarray(col, dtype=float)
        x = -self.extent_m / 2 + (col + 0.5) * self.pixel_m
        y = self.extent_m / 2 - (row + 0.5) * self.pixel_m
        return x, y

    def pile_to_pixel(self, x, y):
        """Pile-frame (x, y) [m] to fractional pixel (row, col); inverse of :meth:`pixel_to_pile`."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        col = (x + self.extent_m / 2) / self.pixel_m - 0.5
        row = (self.extent_m / 2 - y) / self.pixel_m - 0.5
        return row, col

    def pixel_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """(X, Y) [m] arrays of shape (size, size) holding every pixel centre."""
        r, c = np.mgrid[0 : self.size_px, 0 : self.size_px]
        return self.pixel_to_pile(r, c)


def wrap_phi(phi_rad):
    """Map an angle to the grasp's canonical range [-pi/2, pi/2) (grasps are pi-periodic)."""
    return (np.asarray(phi_rad, dtype=float) + math.pi / 2) % math.pi - math.pi / 2


def phi_to_image(phi_rad):
    """Pile-frame grasp angle -> angle in image (col right, row down) coordinates."""
    return wrap_phi(-np.asarray(phi_rad, dtype=float))


def phi_from_image(phi_img_rad):
    """Inverse of :func:`phi_to_image`."""
    return wrap_phi(-np.asarray(phi_img_rad, dtype=float))


def make_T(R=None, t=None) -> np.ndarray:
    """Homogeneous 4x4 transform from a 3x3 rotation and a translation (float64)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = np.asarray(R, dtype=np.float64)
    if t is not None:
        T[:3, 3] = np.asarray(t, dtype=np.float64)
    return T


def invert_T(T) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ t)


def apply_T(T, points) -> np.ndarray:
    """Apply a 4x4 transform to (..., 3) points."""
    T = np.asarray(T, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]


def rot_z(yaw_rad: float) -> np.ndarray:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
