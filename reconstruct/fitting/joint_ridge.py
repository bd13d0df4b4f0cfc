"""What the scan itself says about a ridge, for the joint matching (issue 37, step 2; joint revision 15).

Two pieces of evidence the assignment's costs lacked (docs/reconstruction.md, "Joint revision 15"):

- **The ridge's radius.** A ridge's radius comes from one cross-section profile of its whole run
  (:func:`reconstruct.fitting.scan_logs._profile_radius`). The same profile fitted on chunks of the run
  (``JointConfig.ridge_chunk_m``) gives its spread, the radius's own sigma. A radius the field's logs do not have
  (``log_radius_min_m`` to ``log_radius_max_m``) within that sigma is evidence that the ridge is not one log (a
  scrap, a flank, two logs side by side): :func:`not_one_log_nats`, the log-likelihood ratio of "something else"
  (radii uniform over the profile search's span) against "one log", counted where it favours something else.
- **Open ground where a log would be.** A log matched to a ridge runs on past the ridge's end to its survey
  point; where the scan sees below that stretch's axis (the raster's highest point under it,
  :class:`HeightRaster`), nothing lies there: :func:`open_length_m` measures that length, priced per metre by
  ``coverage_nats_per_m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.scan_logs import (PROFILE_HALF_WIDTH_M, PROFILE_MAX_POINTS, ScanLog, _height_raster,
                                           _profile_radius)


@dataclass(frozen=True)
class HeightRaster:
    """The scan seen from above: the highest point per square cell (rows = y), NaN where no point fell."""

    top_m: np.ndarray  # (ny, nx) highest point per cell [m]
    origin_m: np.ndarray  # (2,) the corner of cell (0, 0) (x, y) [m]
    cell_m: float  # the cells' side [m]

    @classmethod
    def of(cls, points_m: np.ndarray, cell_m: float) -> "HeightRaster":
        """The raster the scan-log search makes (:func:`~reconstruct.fitting.scan_logs._height_raster`)."""
        top, have, lo = _height_raster(np.asarray(points_m, dtype=float), cell_m)
        return cls(np.where(have, top, np.nan), lo, float(cell_m))

    def highest(self, xy_m: np.ndarray) -> np.ndarray:
        """The highest scan point in the cell of each (x, y) row [m]; NaN where none, or off the raster."""
        ij = np.floor((np.atleast_2d(xy_m) - self.origin_m) / self.cell_m).astype(np.int64)
        ny, nx = self.top_m.shape
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        out = np.full(len(ij), np.nan)
        out[ok] = self.top_m[ij[ok, 1], ij[ok, 0]]
        return out


@dataclass(frozen=True)
class RidgeEvidence:
    """Per scan log, its radius's sigma; and the scan's height raster (None: no coverage evidence)."""

    radius_sigma_m: tuple[float, ...]  # one per scan log, in the order of the scan logs [m]
    raster: HeightRaster | None = None


def chunk_radii(points_m: np.ndarray, log: ScanLog, cfg: JointConfig) -> list[float]:
    """The profile radius [m] of each ``ridge_chunk_m`` chunk of ``log``'s run that explains a circle: the
    points within the profile's half width across its line, their height under the ridge's top line (its
    axis one radius up), as :mod:`reconstruct.fitting.scan_logs` fits the whole run."""
    p0, p1 = log.start_m, log.end_m
    d = p1[:2] - p0[:2]
    L = float(np.linalg.norm(d))
    if L <= 0:
        return []
    u = d / L
    rel = points_m[:, :2] - p0[:2]
    t, s = rel @ u, rel @ np.array([-u[1], u[0]])
    n_chunks = max(1, int(round(L / cfg.ridge_chunk_m)))
    edges = np.linspace(0.0, L, n_chunks + 1)
    out = []
    for t0, t1 in zip(edges[:-1], edges[1:]):
        near = np.flatnonzero((t > t0) & (t < t1) & (np.abs(s) < PROFILE_HALF_WIDTH_M))
        if len(near) > PROFILE_MAX_POINTS:
            near = near[np.linspace(0, len(near) - 1, PROFILE_MAX_POINTS).astype(np.int64)]
        top = p0[2] + (p1[2] - p0[2]) * t[near] / L + log.radius_m
        r = _profile_radius(s[near], points_m[near, 2] - top)
        if r is not None:
            out.append(r)
    return out


def radius_sigma(radii_m: Sequence[float], radius_m: float, cfg: JointConfig) -> float:
    """A ridge's radius sigma [m] from its chunks' radii: their RMS about the whole run's ``radius_m`` (a chunk
    disagreeing with it says the whole run's profile is not one log's: a 3 cm run over 7-9 cm chunks is no sure 3
    cm), at least ``ridge_radius_sigma_floor_m``; ``ridge_radius_sigma_prior_m`` where fewer than two chunks
    explain a circle."""
    if len(radii_m) < 2:
        return cfg.ridge_radius_sigma_prior_m
    r = np.asarray(radii_m, dtype=float)
    return max(float(np.sqrt(np.sum((r - radius_m) ** 2) / (len(r) - 1))), cfg.ridge_radius_sigma_floor_m)


def ridge_evidence(points_m: np.ndarray, scan_logs: Sequence[ScanLog], cfg: JointConfig) -> RidgeEvidence:
    """The scan's evidence about its ridges (see the module docstring), for the terms ``cfg`` switches on."""
    P = np.asarray(points_m, dtype=float)
    sig = tuple(radius_sigma(chunk_radii(P, log, cfg), log.radius_m, cfg) if cfg.ridge_radius_evidence else
                cfg.ridge_radius_sigma_prior_m for log in scan_logs)
    raster = HeightRaster.of(P, cfg.coverage_cell_m) if cfg.ridge_coverage and len(P) else None
    return RidgeEvidence(sig, raster)


def not_one_log_nats(radius_m: float, sigma_m: float, cfg: JointConfig) -> float:
    """How much likelier [nats] a ridge of ``radius_m`` (sigma ``sigma_m``) is something else than one log, where
    it is (else 0): the log of the ratio of the radius's density under "something else" (uniform over
    ``other_radius_span_m``) to that under "one log" (uniform over ``log_radius_min_m`` to ``log_radius_max_m``,
    seen through the radius's Gaussian)."""
    lo, hi = cfg.log_radius_min_m, cfg.log_radius_max_m
    s = sigma_m * math.sqrt(2.0)
    p_log = 0.5 * (math.erf((hi - radius_m) / s) - math.erf((lo - radius_m) / s)) / (hi - lo)
    p_other = 1.0 / cfg.other_radius_span_m
    return max(0.0, math.log(p_other) - math.log(max(p_log, p_other * math.exp(-cfg.not_one_log_max_nats))))


def open_length_m(log: ScanLog, t_from_m: float, t_to_m: float, raster: HeightRaster, cfg: JointConfig) -> float:
    """The length [m] of ``log``'s axis, extended, from ``t_from_m`` to ``t_to_m`` along it (from its start) where
    the scan sees below the axis by ``open_drop_m``: no log lies there, or the scan could not see under it."""
    if t_to_m <= t_from_m:
        return 0.0
    p0, p1 = log.start_m, log.end_m
    L = max(log.length_m, 1e-6)
    u = (p1[:2] - p0[:2]) / L
    ts = np.arange(t_from_m + 0.5 * raster.cell_m, t_to_m, raster.cell_m)
    if not len(ts):
        return 0.0
    z_axis = p0[2] + (p1[2] - p0[2]) * ts / L
    top = raster.highest(p0[:2] + np.outer(ts, u))
    with np.errstate(invalid="ignore"):
        return float(np.sum(top < z_axis - cfg.open_drop_m)) * raster.cell_m
