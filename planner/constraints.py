"""Operational constraints on planned grasps: crane reach, lift capacity, keep-out zones.

* **Reach**: the grasp centre's horizontal distance from the crane base (pile frame) must lie in
  [``min_reach_m``, ``max_reach_m``]; applied per pixel before the arg-max, so the best grasp *in
  reach* is returned for each subset.
* **Lift capacity**: a subset whose estimated mass exceeds ``lift_capacity_kg`` is not evaluated.
  Log mass = volume x ``wood_density_kg_m3``. The volume comes from the pile when it is known
  (:meth:`synth.scene.pile.LogSpec.volume_m3`); otherwise from the visible mask: a log of length L and
  diameter d seen from above covers A = L d, so V = pi d^2 L / 4 = A pi d / 4 with the assumed
  diameter ``assumed_diameter_m``. Occluded parts are missed, so the mask estimate is low for
  buried logs — set a capacity margin accordingly.
* **Keep-out zones**: polygons in the pile frame (people, a machine, a ditch); a grasp whose
  rectangle (opening x 0.20 m) overlaps a zone is skipped and the next-best pixel is tried.
* **Obstacles under the claws** (``clear_obstacles``): closing, the claws sweep the rectangle between
  them, from where the tips touch down at the opening's ends to the bowl under the logs, so a rock or
  stump that shows in that rectangle stops them (in the twin: COLLISION). A grasp whose rectangle covers
  a pixel the observation shows as an obstacle (its instance codes from ``OBSTACLE_CODE_BASE`` on: the
  render of the twin's pile or of a reconstructed one) is skipped like one in a keep-out zone. What lies
  hidden under a log cannot be seen, and is not checked. The claws themselves come down outside the
  opening, so the footprint tested against obstacles is the claws': it reaches ``claw_plate_m`` beyond each
  end of the opening and is ``claw_width_m`` wide across the closing axis, by default the grapple's own
  (:class:`synth.physics.grapple.GrappleConfig`: plates 0.05 m thick, 0.22 m wide; ``claw_plate_m`` 0 and
  ``claw_width_m`` 0.20 m is the opening's rectangle, what was tested before; docs/results/README.md,
  "obstacle-footprint").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from synth.geometry.frames import OrthoGrid
from synth.physics.grapple import GrappleConfig

_GRAPPLE = GrappleConfig()  # the grapple the twin simulates, sized after the field's (its docstring)


@dataclass(frozen=True)
class Constraints:
    crane_base_xy_m: tuple[float, float] | None = None  # crane slewing axis in the pile frame [m]; None = no reach limit
    min_reach_m: float = 0.0  # closest grasp centre to the base [m]
    max_reach_m: float = math.inf  # farthest grasp centre from the base [m]
    lift_capacity_kg: float | None = None  # None = unlimited [kg]
    wood_density_kg_m3: float = 900.0  # fresh conifer roundwood, ~800-1000 [kg/m^3]
    assumed_diameter_m: float = 0.16  # log diameter used when the pile is unknown [m]
    keep_out_zones: tuple[tuple[tuple[float, float], ...], ...] = ()  # polygons, (x, y) vertices [m]
    clear_obstacles: bool = True  # skip grasps whose claws' rectangle covers an obstacle the observation shows
    claw_plate_m: float = _GRAPPLE.claw_thickness_m  # how far the obstacle footprint reaches beyond each end of
    #                                                  the opening [m]: the claws' plates (0: the opening alone)
    claw_width_m: float = _GRAPPLE.claw_width_m  # the obstacle footprint's extent across the closing axis [m]

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_reach_m <= self.max_reach_m:
            raise ValueError(f"need 0 <= min_reach_m <= max_reach_m, got {self.min_reach_m}, {self.max_reach_m}")
        if self.lift_capacity_kg is not None and not self.lift_capacity_kg > 0:
            raise ValueError(f"lift_capacity_kg must be > 0 or None, got {self.lift_capacity_kg}")
        if not self.wood_density_kg_m3 > 0 or not self.assumed_diameter_m > 0:
            raise ValueError("wood_density_kg_m3 and assumed_diameter_m must be > 0")
        if self.crane_base_xy_m is not None and len(self.crane_base_xy_m) != 2:
            raise ValueError("crane_base_xy_m must be (x, y) in metres")
        if not isinstance(self.clear_obstacles, bool):
            raise ValueError(f"clear_obstacles is a switch: must be True or False, got {self.clear_obstacles!r}")
        if not (math.isfinite(self.claw_plate_m) and 0.0 <= self.claw_plate_m <= 0.5):
            raise ValueError(f"claw_plate_m must be in [0, 0.5] m, got {self.claw_plate_m}")
        if not (math.isfinite(self.claw_width_m) and 0.0 < self.claw_width_m <= 1.0):
            raise ValueError(f"claw_width_m must be in (0, 1] m, got {self.claw_width_m}")
        for z in self.keep_out_zones:
            if len(z) < 3 or any(len(p) != 2 for p in z):
                raise ValueError(f"a keep-out zone needs >= 3 (x, y) vertices, got {z!r}")

    def reach_ok(self, grid: OrthoGrid) -> np.ndarray | None:
        """(H, W) bool: pixel centres within reach, or None when reach is unconstrained."""
        if self.crane_base_xy_m is None:
            return None
        X, Y = grid.pixel_centres()
        r = np.hypot(X - self.crane_base_xy_m[0], Y - self.crane_base_xy_m[1])
        return (r >= self.min_reach_m) & (r <= self.max_reach_m)

    def keep_out_raster(self, grid: OrthoGrid) -> np.ndarray | None:
        """(H, W) uint8 raster of the keep-out zones (1 inside), or None without zones."""
        if not self.keep_out_zones:
            return None

        out = np.zeros((grid.size_px, grid.size_px), np.uint8)
        for zone in self.keep_out_zones:
            out |= polygon_raster(grid, np.asarray(zone, dtype=float))
        return out

    def log_masses_kg(self, visible_px: dict[int, int], pixel_m: float, pile=None) -> dict[int, float]:
        """Estimated mass [kg] of each log index (see the module docstring)."""
        out = {}
        for i, n_px in visible_px.items():
            if pile is not None and i < len(pile.logs):
                v = pile.logs[i].volume_m3()
            else:
                v = n_px * pixel_m ** 2 * math.pi * self.assumed_diameter_m / 4
            out[i] = v * self.wood_density_kg_m3
        return out


def polygon_raster(grid: OrthoGrid, poly_xy: np.ndarray) -> np.ndarray:
    """(H, W) uint8: 1 on pixels a pile-frame polygon touches (cv2.fillPoly on pixel centres)."""
    import cv2

    rows, cols = grid.pile_to_pixel(poly_xy[:, 0], poly_xy[:, 1])
    pts = np.round(np.stack([cols, rows], axis=1) * 16).astype(np.int32)  # 4 fractional bits
    out = np.zeros((grid.size_px, grid.size_px), np.uint8)
    cv2.fillPoly(out, [pts], 1, lineType=cv2.LINE_8, shift=4)
    return out
