"""Each log's scan uncertainty from its own evidence (joint revision 11): how far the scan lets the pile check
move a log fitted to its points, across its axis and up, at each end.

A log fitted to the scan is known where the scan shows its surface and not where it does not: a log on top
of a dropped pile shows its top and both flanks, a log in a packed pile only a top arc between neighbours
that hide its sides. Its sigma is the Laplace covariance of a round cross-section fitted to the points on its
surface (:func:`scan_sigma`):

- the points within ``band_m`` of the placed log's surface, nearer it than any other log's, are grouped in
  cells ``sigma_cell_along_m`` long and ``sigma_cell_deg`` round the axis: stereo errors are correlated over a
  patch (the matching's block, its smear), so a cell - not a point - is one independent observation;
- each cell observes the surface at its angle phi from the top: a radial residual whose derivatives by the
  axis' shift across (c) and up (h) at its place along the log (a line: c0 + c1 tau, h0 + h1 tau, tau the
  share of the length from the middle) and by the radius are ``(sin phi, tau sin phi, cos phi, tau cos phi,
  1)``; its noise is the RMS of the cells' mean residuals (the fit's own residuals, not a fixed number), at
  least ``sigma_cell_min_m``, a share ``sigma_bias_share`` of it common to every cell of its angle bin along
  the whole log (stereo's bias by the view angle: a longer log is hardly surer, a wider arc is); the radius
  has a prior of ``sigma_radius_prior_m``;
- what the pile check moves is the log's surface towards a contact with its radius kept: across, a flank
  (``c +- r``); up, its underside (``h - r``). A top arc alone leaves the radius - and with it the flanks and
  the underside - loose; flanks seen pin them;
- the log is not round: the twin's pentagonal prism (and a real stem's ovality) puts the round fit's axis off
  by a share of the radius whatever the scan shows (``sigma_shape_per_radius``), added in quadrature; the
  result is at most ``sigma_max_m``;
- with the radius a state of the pile estimate (``JointConfig.radius_states``) the radius sigma also carries
  what the cells cannot see, the fit's misfit (:func:`radius_misfit`): nothing is seen inside a solid log, so
  the points inside its fitted surface are its surface's noise where the fit is right; a fit too thick (or off
  across) leaves the log's own points inside its surface, deeper than ``band_m``, where the cells do not look.
  The part of their RMS depth within ``radius_sigma_band_m`` beyond their RMS depth within ``band_m`` is added
  to the radius sigma in quadrature.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reconstruct.fitting.joint_config import JointConfig
from synth.scene.pile import LogSpec

#: the parameters' order: shift across, its slope along, shift up, its slope along, radius
_N_PARAMS = 5


@dataclass(frozen=True)
class ScanSigma:
    """A log's scan sigmas [m]: across its axis at its butt and top, up at both, its radius; and what they
    came from (cells with points, the angle round from the top the seen cells span on each side [deg], the
    cells' noise [m])."""

    across_m: tuple[float, float]
    up_m: tuple[float, float]
    radius_m: float
    cells: int
    arc_deg: tuple[float, float]
    cell_noise_m: float
    radius_misfit_m: float = 0.0  # what radius_m carries of the fit's misfit (radius_misfit) [m]

    def to_dict(self) -> dict:
        return {"across_m": list(self.across_m), "up_m": list(self.up_m), "radius_m": self.radius_m,
                "cells": self.cells, "arc_deg": list(self.arc_deg), "cell_noise_m": self.cell_noise_m,
                "radius_misfit_m": self.radius_misfit_m}


def _frame(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Across (horizontal) and up (perpendicular to the axis, upward) unit vectors of an axis ``u``."""
    n = np.array([-u[1], u[0], 0.0])
    n = n / max(float(np.linalg.norm(n)), 1e-9)
    w = np.cross(u, n)
    return n, (w if w[2] >= 0 else -w)


def _radial(points: np.ndarray, log: LogSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Each point's place along ``log`` from its butt [m], its offset from the axis (perpendicular) [m], its
    radial residual from the log's (tapered) round surface [m], and the log's axis and length [m]."""
    butt, top = log.endpoints_m()
    L = float(np.linalg.norm(top - butt))
    u = (top - butt) / L
    rel = np.asarray(points, dtype=float).reshape(-1, 3) - butt
    t = rel @ u
    perp = rel - np.outer(t, u)
    r = log.diameter_m / 2 + (log.top_d_m - log.diameter_m) / 2 * np.clip(t / L, 0.0, 1.0)
    return t, perp, np.linalg.norm(perp, axis=1) - r, u, L


def surface_cells(points: np.ndarray, log: LogSpec, band_m: float, cfg: JointConfig
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cells of ``log``'s surface that ``points`` (its own, pile frame) show: per cell its mean angle from
    the top (+ toward the across vector) [rad], its mean place along the log (-0.5 butt .. 0.5 top) [-], its
    mean radial residual [m] and its angle bin (cells of one bin share the stereo's bias along the log)."""
    t, perp, res, u, L = _radial(points, log)
    n, w = _frame(u)
    on = (t >= 0) & (t <= L) & (np.abs(res) <= band_m)
    if not on.any():
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, np.int64)
    phi = np.arctan2(perp[on] @ n, perp[on] @ w)
    ia = np.floor(t[on] / cfg.sigma_cell_along_m).astype(np.int64)
    ip = np.floor((phi + math.pi) / math.radians(cfg.sigma_cell_deg)).astype(np.int64)
    keys, cell, count = np.unique(ia * 10_000 + ip, return_inverse=True, return_counts=True)
    cell = cell.ravel()

    def mean(v: np.ndarray) -> np.ndarray:
        return np.bincount(cell, weights=v) / count

    return mean(phi), mean(t[on] / L - 0.5), mean(res[on]), keys % 10_000


def _information(A: np.ndarray, group: np.ndarray, noise_m: float, cfg: JointConfig) -> np.ndarray:
    """A^T C^-1 A for cells whose residuals have the covariance C = noise^2 ((1 - b) I + b Z Z^T): each cell its
    own share 1 - b, and a share b (``sigma_bias_share``) common to the cells of its angle bin (Z), however far
    apart along the log. By Woodbury: C^-1 = (I - Z diag(1 / (a / c + n_g)) Z^T) / a, a = noise^2 (1 - b),
    c = noise^2 b, n_g the cells in bin g."""
    a = noise_m ** 2 * (1 - cfg.sigma_bias_share)
    c = noise_m ** 2 * cfg.sigma_bias_share
    _, g, n_g = np.unique(group, return_inverse=True, return_counts=True)
    S = np.zeros((len(n_g), A.shape[1]))
    np.add.at(S, g.ravel(), A)  # each bin's column sums
    return (A.T @ A - (S.T * (1.0 / (a / c + n_g))) @ S) / a


def _inside_depth_m(t: np.ndarray, res: np.ndarray, L: float, within_m: float) -> float:
    """The RMS depth of the points inside a log's surface by at most ``within_m`` and within its length [m]
    (0 without such points)."""
    d = res[(t >= 0) & (t <= L) & (res < 0) & (res >= -within_m)]
    return float(np.sqrt(np.mean(d ** 2))) if d.size else 0.0


def radius_misfit(points: np.ndarray, log: LogSpec, band_m: float, cfg: JointConfig) -> float:
    """What the cells of :func:`surface_cells` cannot see of ``log``'s fit [m]: the RMS depth of the points inside
    its surface within ``cfg.radius_sigma_band_m`` beyond that within ``band_m`` (in quadrature; ``points``: the
    scan near it that no other log's surface claims, pile frame). Nothing is seen inside a solid log: where the fit
    is right both are its points' noise (the wider adds little); where it is too thick its own points lie inside,
    past the band."""
    t, _, res, _, L = _radial(points, log)
    wide, inner = _inside_depth_m(t, res, L, cfg.radius_sigma_band_m), _inside_depth_m(t, res, L, band_m)
    return math.sqrt(max(wide ** 2 - inner ** 2, 0.0))


def scan_sigma(points: np.ndarray, log: LogSpec, band_m: float, cfg: JointConfig,
               near: np.ndarray | None = None) -> ScanSigma:
    """``log``'s scan sigmas from the points on its surface (``points``: those no other log explains, pile
    frame; ``band_m``: how near its surface a point is on it). See the module's text for the model. ``near``:
    the scan near the log that no other log's surface claims (within ``band_m``); given, the radius sigma
    carries the fit's misfit (:func:`radius_misfit`)."""
    phi, tau, res, group = surface_cells(points, log, band_m, cfg)
    noise = max(float(np.sqrt(np.mean(res ** 2))) if res.size else 0.0, cfg.sigma_cell_min_m)
    A = np.column_stack([np.sin(phi), tau * np.sin(phi), np.cos(phi), tau * np.cos(phi), np.ones_like(phi)])
    info = _information(A, group, noise, cfg) if res.size else np.zeros((_N_PARAMS, _N_PARAMS))
    # priors: the radius as the pile's logs vary; the axis no better known than sigma_max_m without cells
    info += np.diag([1 / cfg.sigma_max_m ** 2] * 4 + [1 / cfg.sigma_radius_prior_m ** 2])
    cov = np.linalg.inv(info)
    shape = cfg.sigma_shape_per_radius * log.mean_diameter_m / 2

    def sd(g: np.ndarray) -> float:
        return min(math.sqrt(float(g @ cov @ g) + shape ** 2), cfg.sigma_max_m)

    across, up = [], []
    for s in (-0.5, 0.5):  # butt, top
        flank = [sd(np.array([1.0, s, 0.0, 0.0, k])) for k in (1.0, -1.0)]  # c + r, c - r
        across.append(max(flank))
        up.append(sd(np.array([0.0, 0.0, 1.0, s, -1.0])))  # the underside, h - r
    arc = (float(np.degrees(-phi.min())) if phi.size else 0.0, float(np.degrees(phi.max())) if phi.size else 0.0)
    radius = sd(np.eye(_N_PARAMS)[4])
    misfit = 0.0 if near is None else radius_misfit(near, log, band_m, cfg)
    if misfit > 0.0:
        radius = math.hypot(radius, misfit)
    return ScanSigma((across[0], across[1]), (up[0], up[1]), radius, int(phi.size), arc, noise, misfit)
