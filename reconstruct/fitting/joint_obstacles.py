"""Obstacles as states of the joint pile estimate (joint revision 13, ``JointConfig.obstacle_states``): each
stump or rock the scan found may move horizontally and shrink (or grow) within its own uncertainty, so a
contact with a log is shared by the two bodies' evidence instead of the obstacle being taken as exact.

An obstacle is drawn from the outermost of its points (a stump's top disc at a high percentile of its
points' distances, a rock as their convex hull): its outline lies about as far out as its points scatter
about its surface, not that over the square root of their number. Its sigma (:func:`obstacle_sigma`) is
therefore the RMS of its points' signed distances from its surface (the fit's own residuals), with a floor
(``obstacle_sigma_floor_m``), grown where few points carry it (``obstacle_sigma_ref_points``) and capped
(``obstacle_sigma_max_m``). Its state is three numbers: a shift in x and y and an erosion of its surface,
each a Gaussian of that sigma about zero; a log's depth into the moved obstacle is its depth into the found
one, the log shifted back, less the erosion (:func:`offset_depths`). The settled pile carries the moved
obstacles (:func:`moved_obstacles`), so the twin checks what the estimate says."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Sequence

import numpy as np

from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_contact import Bodies, Segment, stump_point_distance
from synth.scene.pile import PileSpec, RockSpec, StumpSpec

#: an obstacle's three state numbers: shift in x, in y, erosion of its surface [m]
N_STATES = 3
#: a moved stump keeps within the radius and height a stump may have (StumpSpec's limits) [m]
STUMP_MIN_RADIUS_M = 0.03
STUMP_MIN_HEIGHT_M = 0.05
STUMP_MAX_HEIGHT_M = 2.0


def offset_depths(bodies: Bodies, s: Segment, j: int, off: np.ndarray) -> np.ndarray:
    """How deep log ``s`` and obstacle ``j`` overlap [m] with the obstacle shifted by ``off[:2]`` and its
    surface moved inward by ``off[2]`` (the log shifted back the same: the depths are the same)."""
    shift = np.array([off[0], off[1], 0.0])
    return bodies.obstacle_depths(Segment(s.a - shift, s.b - shift, s.ra, s.rb), j) - off[2]


def _near(P: np.ndarray, lo: np.ndarray, hi: np.ndarray, band_m: float) -> np.ndarray:
    """The points within ``band_m`` of the box ``lo``..``hi`` (top view and height)."""
    m = np.all((P >= lo - band_m) & (P <= hi + band_m), axis=1)
    return P[m]


def obstacle_residuals(pile: PileSpec, bodies: Bodies, j: int, P: np.ndarray, band_m: float) -> np.ndarray:
    """The signed distances [m] from obstacle ``j``'s surface (stumps first, then rocks) of the points of
    ``P`` within ``band_m`` of it and more than ``band_m`` above the ground (the ground's own points lie on
    the obstacle's foot)."""
    if not len(P):
        return np.zeros(0)
    if j < len(pile.stumps):
        d = stump_point_distance(bodies.stumps[j], P)
    else:
        d = bodies.rocks[j - len(pile.stumps)].signed_distance(P)
    above = P[:, 2] > pile.terrain.height_at(P[:, 0], P[:, 1]) + band_m
    return d[above & (np.abs(d) < band_m)]


def obstacle_sigma(residuals: np.ndarray, cfg: JointConfig) -> float:
    """An obstacle's sigma [m] (its place across and its surface's) from its points' signed distances from
    it: their RMS with the floor in quadrature, grown by sqrt(ref / n) for n points under the reference
    count, at most ``obstacle_sigma_max_m`` (no points: that)."""
    n = len(residuals)
    if n == 0:
        return cfg.obstacle_sigma_max_m
    rms = float(np.sqrt(np.mean(np.square(residuals))))
    sigma = math.hypot(cfg.obstacle_sigma_floor_m, rms) * math.sqrt(max(1.0, cfg.obstacle_sigma_ref_points / n))
    return min(sigma, cfg.obstacle_sigma_max_m)


def obstacle_sigmas(pile: PileSpec, points: np.ndarray | None, cfg: JointConfig) -> list[float]:
    """Each obstacle's sigma (stumps first, then rocks) from the scan ``points`` on its surface that no log
    explains: a point within ``obstacle_sigma_band_m`` of a log's round surface is the log's (its underside
    resting on the obstacle, its smeared flank), not the obstacle's evidence. No points: the largest sigma."""
    from reconstruct.fitting.geometry import _distance_to_logs

    bodies = Bodies(pile)
    if points is None:
        return [cfg.obstacle_sigma_max_m] * bodies.n_obstacles
    P = np.asarray(points, dtype=float)
    P = P[np.all(np.isfinite(P), axis=1)]
    band = cfg.obstacle_sigma_band_m
    out = []
    for j in range(bodies.n_obstacles):
        Q = _points_about(pile, bodies, j, P, band)
        if pile.logs and len(Q):
            Q = Q[_distance_to_logs(Q, list(pile.logs), pad_m=0.0) >= band]
        out.append(obstacle_sigma(obstacle_residuals(pile, bodies, j, Q, band), cfg))
    return out


def _points_about(pile: PileSpec, bodies: Bodies, j: int, P: np.ndarray, band_m: float) -> np.ndarray:
    """The points of ``P`` in obstacle ``j``'s box grown by ``band_m``."""
    if j < len(pile.stumps):
        seg = bodies.stumps[j]
        r = max(seg.ra, seg.rb)
        return _near(P, np.array([seg.a[0] - r, seg.a[1] - r, seg.a[2]]),
                     np.array([seg.a[0] + r, seg.a[1] + r, seg.b[2]]), band_m)
    V = bodies.rocks[j - len(pile.stumps)].vertices
    return _near(P, V.min(axis=0), V.max(axis=0), band_m)


def _moved_stump(st: StumpSpec, off: np.ndarray) -> StumpSpec:
    shrink = float(off[2])
    top = max(STUMP_MIN_RADIUS_M, st.top_radius_m - shrink)
    return replace(st, position_m=(st.position_m[0] + float(off[0]), st.position_m[1] + float(off[1])),
                   height_m=float(np.clip(st.height_m - shrink, STUMP_MIN_HEIGHT_M, STUMP_MAX_HEIGHT_M)),
                   top_radius_m=top,
                   bottom_radius_m=max(top, st.bottom_radius_m - shrink))


def _moved_rock(rk: RockSpec, off: np.ndarray) -> RockSpec:
    """The rock shifted and its faces moved ``off[2]`` inward (its hull's planes offset: the erosion the
    estimate's depths take, ``offset_depths``); one it would erode to nothing is drawn in toward its centre
    instead, to a twentieth of its size."""
    from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

    V = np.asarray(rk.vertices_m, dtype=float)
    c = V.mean(axis=0)
    shrink = float(off[2])
    try:
        eq = ConvexHull(V).equations.copy()  # n . x + b <= 0 inside
        eq[:, 3] += shrink
        eroded = HalfspaceIntersection(eq, c).intersections if np.all(eq[:, :3] @ c + eq[:, 3] < 0) else None
    except QhullError:  # a flat hull
        eroded = None
    if eroded is None:  # a flat hull, or eroded past its centre
        d = V - c
        k = np.clip(1.0 - shrink / np.maximum(np.linalg.norm(d, axis=1), 1e-9), 0.05, None)
        eroded = c + d * k[:, None]
    V = eroded
    pos = (rk.position_m[0] + float(off[0]), rk.position_m[1] + float(off[1]), rk.position_m[2])
    return replace(rk, position_m=pos, vertices_m=tuple(tuple(float(v) for v in row) for row in V))


def moved_obstacles(pile: PileSpec, offsets: np.ndarray) -> PileSpec:
    """``pile`` with each obstacle moved by its state (``offsets``: per obstacle, stumps first, its shift in
    x and y and its erosion [m])."""
    ns = len(pile.stumps)
    stumps = tuple(_moved_stump(st, offsets[j]) for j, st in enumerate(pile.stumps))
    rocks = tuple(_moved_rock(rk, offsets[ns + j]) for j, rk in enumerate(pile.rocks))
    return replace(pile, stumps=stumps, rocks=rocks)


def obstacle_notes(offsets: np.ndarray, sigmas: Sequence[float], presses: Sequence[int | None]) -> list[str]:
    """A note per obstacle the estimate moved or shrank by a millimetre or more (``presses``: per obstacle,
    the log that pressed it most, or None)."""
    notes = []
    for j, (off, sig) in enumerate(zip(offsets, sigmas)):
        shift, shrink = float(np.hypot(off[0], off[1])), float(off[2])
        if max(shift, abs(shrink)) < 1e-3:
            continue
        by = f" by log {presses[j]}" if presses[j] is not None else ""
        notes.append(f"obstacle {j} {'shrunk' if shrink >= 0 else 'grown'} {abs(shrink) * 1000:.1f} mm and moved "
                     f"{shift * 1000:.1f} mm{by} ({float(np.linalg.norm(off)) / sig:.1f} sigma of its scan, "
                     f"+-{sig * 100:.1f} cm)")
    return notes
