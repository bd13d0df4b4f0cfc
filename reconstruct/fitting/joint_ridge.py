"""What the scan itself says about a ridge, for the joint matching (issue 37, step 2; joint revisions 15-16).

Evidence the assignment's costs lacked (docs/reconstruction.md, "Joint revision 15", "Joint revision 16"):

- **The ridge's radius.** A ridge's radius comes from one cross-section profile of its whole run
  (:func:`reconstruct.fitting.scan_logs.profile_radius`). The same profile fitted on chunks of the run
  (``JointConfig.ridge_chunk_m``) gives its spread, the radius's own sigma. A radius the field's logs do not have
  (``log_radius_min_m`` to ``log_radius_max_m``) within that sigma is evidence that the ridge is not one log (a
  scrap, a flank, two logs side by side): :func:`not_one_log_nats`, the log-likelihood ratio of "something else"
  (radii uniform over the profile search's span) against "one log", counted where it favours something else.
- **Open ground where a log would be.** A log matched to a ridge runs on past the ridge's end to its survey
  point; where the scan sees below that stretch's axis (the raster's highest point under it,
  :class:`HeightRaster`), nothing lies there: :func:`open_length_m` measures that length, priced per metre by
  ``coverage_nats_per_m``.
- **Where the ridge's axis runs** (joint revision 16). The whole run's axis is one straight line: the principal
  direction of its ridge pixels, its height a robust line through their tops. The chunks' profile circles say
  where the axis is chunk by chunk; the Bayesian line through their centres (:class:`RidgeLine`, across and in
  height, about the whole run's axis, which is its prior) corrects the run's direction (a short ridge's pixels
  tilt it by a few degrees: 10 cm at a fixed end a metre past it) and, through its residuals, says how straight
  the ridge is: a ridge that is one log over part of its run and something else over the rest predicts its
  axis badly, and a point measured against it is a weaker test. A survey point is measured against that line,
  its prediction's variance (:meth:`RidgeLine.lateral_var_m2`, :meth:`RidgeLine.height_var_m2`) added to its
  own. The chunks past a point inside the ridge also say whether the ridge runs on as the log or as something
  else (:func:`reconstruct.fitting.joint_match.run_on_evidence_nats`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.scan_logs import (PROFILE_CENTRE_TOLERANCE_M, PROFILE_HALF_WIDTH_M, PROFILE_MAX_POINTS,
                                           PROFILE_PRIOR_DEPTH_M, ScanLog, _height_raster, profile_circle)

PROFILE_EDGE_M = 0.001  # a chunk circle's centre this close to the edge of the profile's centre search is at it [m]


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
class ChunkProfile:
    """One chunk's profile circle, about the whole run's axis."""

    t_m: float  # the chunk's middle, along the run from its start [m]
    lateral_m: float  # the circle's centre across the run's axis (left of start -> end positive) [m]
    height_m: float  # the circle's centre above the run's axis [m]
    radius_m: float  # the circle's radius [m]


@dataclass(frozen=True)
class AxisCorrection:
    """A correction ``c(t) = a + b (t - t_mean)`` to the whole run's axis at a place ``t`` along it (across or in
    height), with its posterior covariance and the chunk centres' scatter about it (how straight the ridge is)."""

    coef: tuple[float, float]  # (a [m], b [-]): the posterior mean
    cov: tuple[tuple[float, float], tuple[float, float]]  # its 2 x 2 posterior covariance [m^2, m, -]
    scatter_m: float  # the chunk centres' RMS about the least-squares line, at least the floor [m]

    def at_m(self, dt_m: float) -> float:
        return self.coef[0] + self.coef[1] * dt_m

    def var_m2(self, dt_m: float) -> float:
        """The variance of the axis at ``dt_m`` from the chunks' mean place: the line's own (from its covariance)
        and the ridge's departure from any straight line (its scatter) [m^2]."""
        (caa, cab), (_, cbb) = self.cov
        return caa + 2.0 * cab * dt_m + cbb * dt_m * dt_m + self.scatter_m ** 2


@dataclass(frozen=True)
class RidgeLine:
    """Where a ridge's axis runs, from its chunks' profile circles (see the module docstring): corrections to
    the whole run's axis across and in height about the chunks' mean place along it."""

    t_mean_m: float  # the chunks' mean place along the run [m]
    lateral: AxisCorrection  # across the axis (left of start -> end positive)
    height: AxisCorrection  # in height

    def lateral_m(self, t_m: float) -> float:
        return self.lateral.at_m(t_m - self.t_mean_m)

    def height_m(self, t_m: float) -> float:
        return self.height.at_m(t_m - self.t_mean_m)

    def lateral_var_m2(self, t_m: float) -> float:
        return self.lateral.var_m2(t_m - self.t_mean_m)

    def height_var_m2(self, t_m: float) -> float:
        return self.height.var_m2(t_m - self.t_mean_m)


@dataclass(frozen=True)
class RidgeEvidence:
    """Per scan log, its radius's sigma and its chunk line (None: too few chunks, or the term off); and the scan's
    height raster (None: no coverage evidence)."""

    radius_sigma_m: tuple[float, ...]  # one per scan log, in the order of the scan logs [m]
    raster: HeightRaster | None = None
    lines: tuple[RidgeLine | None, ...] = ()  # one per scan log (empty: none for any)
    chunks: tuple[tuple[ChunkProfile, ...], ...] = ()  # one per scan log: its chunks off the search's edge

    def line(self, j: int) -> RidgeLine | None:
        return self.lines[j] if j < len(self.lines) else None

    def chunks_of(self, j: int) -> tuple[ChunkProfile, ...]:
        return self.chunks[j] if j < len(self.chunks) else ()


def chunk_profiles(points_m: np.ndarray, log: ScanLog, cfg: JointConfig) -> list[ChunkProfile]:
    """The profile circle of each ``ridge_chunk_m`` chunk of ``log``'s run that explains one: the points within
    the profile's half width across its line, their height under the ridge's top line (its axis one radius up),
    as :mod:`reconstruct.fitting.scan_logs` fits the whole run."""
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
        fit = profile_circle(s[near], points_m[near, 2] - top)
        if fit is not None:
            centre, r = fit
            out.append(ChunkProfile(0.5 * float(t0 + t1), float(centre[0]), float(centre[1]) + log.radius_m, r))
    return out


def chunk_radii(points_m: np.ndarray, log: ScanLog, cfg: JointConfig) -> list[float]:
    """The profile radius [m] of each chunk of ``log``'s run that explains a circle (:func:`chunk_profiles`)."""
    return [c.radius_m for c in chunk_profiles(points_m, log, cfg)]


def _correction(dt_m: np.ndarray, y_m: np.ndarray, offset_sigma_m: float, slope_sigma: float,
                floor_m: float) -> AxisCorrection:
    """The Bayesian straight line through ``y_m`` at ``dt_m``: noise the points' scatter about their
    least-squares line (at least ``floor_m``), prior zero with ``offset_sigma_m`` and ``slope_sigma``."""
    A = np.column_stack([np.ones(len(dt_m)), dt_m])
    ls = np.linalg.lstsq(A, y_m, rcond=None)[0]
    scatter = max(math.sqrt(float(np.sum((y_m - A @ ls) ** 2)) / (len(y_m) - 2)), floor_m)
    precision = A.T @ A / scatter ** 2 + np.diag([offset_sigma_m ** -2, slope_sigma ** -2])
    cov = np.linalg.inv(precision)
    coef = cov @ A.T @ y_m / scatter ** 2
    return AxisCorrection((float(coef[0]), float(coef[1])), ((float(cov[0, 0]), float(cov[0, 1])),
                                                             (float(cov[1, 0]), float(cov[1, 1]))), scatter)


def usable_chunks(chunks: Sequence[ChunkProfile], log: ScanLog) -> tuple[ChunkProfile, ...]:
    """The chunks whose circle's centre lies inside the profile's centre search, not at its edge (a circle at
    the edge is beyond the search: it says where the axis is not, not where it is)."""
    inner = PROFILE_CENTRE_TOLERANCE_M - PROFILE_EDGE_M
    return tuple(c for c in chunks if abs(c.lateral_m) < inner
                 and abs(c.height_m - log.radius_m + PROFILE_PRIOR_DEPTH_M) < inner)


def ridge_line(chunks: Sequence[ChunkProfile], log: ScanLog, cfg: JointConfig,
               fcfg: FuseConfig | None = None) -> RidgeLine | None:
    """Where ``log``'s axis runs from its chunks (:class:`RidgeLine`): across and in height, the Bayesian line
    through the chunks' circle centres, its prior the whole run's axis (offset within ``fcfg.axis_sigma_m``
    across and ``fcfg.radius_sigma_m`` in height, the sigmas the matching gives the run's axis; direction within
    ``ridge_direction_sigma_m`` over its seen length). A chunk whose circle lies at the edge of the profile's
    centre search is left out (the circle is beyond the search, not there). None with fewer than
    ``ridge_line_min_chunks`` chunks (two make a line with nothing to say how straight the ridge is)."""
    fcfg = fcfg or FuseConfig()
    use = usable_chunks(chunks, log)
    if len(use) < cfg.ridge_line_min_chunks:
        return None
    t = np.array([c.t_m for c in use])
    tm = float(t.mean())
    slope_sigma = cfg.ridge_direction_sigma_m / max(log.seen_m, cfg.ridge_chunk_m)
    lat = _correction(t - tm, np.array([c.lateral_m for c in use]), fcfg.axis_sigma_m, slope_sigma,
                      cfg.ridge_line_sigma_floor_m)
    hgt = _correction(t - tm, np.array([c.height_m for c in use]), fcfg.radius_sigma_m, slope_sigma,
                      cfg.ridge_line_sigma_floor_m)
    return RidgeLine(tm, lat, hgt)


def radius_sigma(radii_m: Sequence[float], radius_m: float, cfg: JointConfig) -> float:
    """A ridge's radius sigma [m] from its chunks' radii: their RMS about the whole run's ``radius_m`` (a chunk
    disagreeing with it says the whole run's profile is not one log's: a 3 cm run over 7-9 cm chunks is no sure 3
    cm), at least ``ridge_radius_sigma_floor_m``; ``ridge_radius_sigma_prior_m`` where fewer than two chunks
    explain a circle."""
    if len(radii_m) < 2:
        return cfg.ridge_radius_sigma_prior_m
    r = np.asarray(radii_m, dtype=float)
    return max(float(np.sqrt(np.sum((r - radius_m) ** 2) / (len(r) - 1))), cfg.ridge_radius_sigma_floor_m)


def ridge_evidence(points_m: np.ndarray, scan_logs: Sequence[ScanLog], cfg: JointConfig,
                   fcfg: FuseConfig | None = None) -> RidgeEvidence:
    """The scan's evidence about its ridges (see the module docstring), for the terms ``cfg`` switches on
    (``fcfg``: the axis sigmas of the chunk lines' prior)."""
    P = np.asarray(points_m, dtype=float)
    chunked = cfg.ridge_radius_evidence or cfg.ridge_chunk_line or cfg.run_on_chunks
    chunks = [chunk_profiles(P, log, cfg) if chunked else [] for log in scan_logs]
    sig = tuple(radius_sigma([c.radius_m for c in ch], log.radius_m, cfg) if cfg.ridge_radius_evidence else
                cfg.ridge_radius_sigma_prior_m for ch, log in zip(chunks, scan_logs))
    lines = tuple(ridge_line(ch, log, cfg, fcfg) for ch, log in zip(chunks, scan_logs)) if cfg.ridge_chunk_line else ()
    usable = tuple(usable_chunks(ch, log) for ch, log in zip(chunks, scan_logs)) if cfg.run_on_chunks else ()
    raster = HeightRaster.of(P, cfg.coverage_cell_m) if cfg.ridge_coverage and len(P) else None
    return RidgeEvidence(sig, raster, lines, usable)


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
