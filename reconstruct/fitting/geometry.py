"""Where scan points and fitted logs lie with respect to each other (pile frame, metres): distances to a
log's surface, to its top-view footprint, under its round underside; which log a point lies on; how deep
two logs interpenetrate; the natural order of log ids."""

from __future__ import annotations

import re
from typing import Any, Sequence

import numpy as np

from synth.scene.pile import LogSpec

#: what lies under a log (the ground, a stump) is held this far under its underside [m]
UNDER_LOG_GAP_M = 0.003


def natural_key(log_id: str) -> tuple:
    """Sort key putting ``log2`` before ``log10``."""
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(log_id)))


def _distance_to_logs(P: np.ndarray, logs: Sequence[LogSpec], pad_m: float) -> np.ndarray:
    """Signed distance [m] of points to the nearest log surface (negative inside); logs are
    extended by ``pad_m`` at both ends."""
    best = np.full(len(P), np.inf)
    for log in logs:
        p0, p1 = log.endpoints_m()
        L = log.length_m
        u = (p1 - p0) / L
        rel = P - p0
        t = rel @ u
        inside = (t > -pad_m) & (t < L + pad_m)
        if not inside.any():
            continue
        ri = rel[inside]
        ti = t[inside]
        rad = np.linalg.norm(ri - np.outer(ti, u), axis=1)
        r = log.diameter_m / 2 + (log.top_d_m - log.diameter_m) / 2 * np.clip(ti / L, 0, 1)
        d = rad - r
        best[inside] = np.minimum(best[inside], d)
    return best


def points_on_no_other_log(P: np.ndarray, logs: Sequence[LogSpec], band_m: float) -> list[np.ndarray]:
    """For each of ``logs``, a mask of the points ``P`` that lie on no other log (farther than ``band_m``
    from every other log's surface): what may show where that log ends (a neighbour's top where it
    touches the end is not this log)."""
    on_log = [np.abs(_distance_to_logs(P, [log], pad_m=0.0)) <= band_m for log in logs]
    out = []
    for i in range(len(logs)):
        others = [m for j, m in enumerate(on_log) if j != i]
        out.append(~np.logical_or.reduce(others) if others else np.ones(len(P), bool))
    return out


def _owners(P: np.ndarray, logs: Sequence[LogSpec], band_m: float,
            suspect: Sequence[bool] | None = None) -> np.ndarray:
    """Index of the log whose surface each point lies on (within ``band_m``, nearest wins);
    -1 for points on no log. A ``suspect`` log (its fit strayed from its GNSS axis) gets only the
    points no other log's surface explains: it had most likely taken a neighbour's."""
    best = np.full(len(P), np.inf)
    owner = np.full(len(P), -1, dtype=np.int64)
    sus = list(suspect) if suspect is not None else [False] * len(logs)
    claimed = np.zeros(len(P), dtype=bool)  # within the band of a trusted log
    ds = [np.abs(_distance_to_logs(P, [log], pad_m=0.0)) for log in logs]
    for i, d in enumerate(ds):
        if not sus[i]:
            claimed |= d < band_m
    for i, d in enumerate(ds):
        closer = (d < best) & (d < band_m)
        if sus[i]:
            closer &= ~claimed
        owner[closer] = i
        best = np.where(closer, d, best)
    return owner


def segment_closest(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> tuple[float, float, float]:
    """The closest points of the 3-D segments p1q1 and p2q2 (both of non-zero length): where along each
    (0 at p, 1 at q) and their distance [m]."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    b, c = float(d1 @ d2), float(d1 @ r)
    denom = a * e - b * b
    s = float(np.clip((b * f - c * e) / denom, 0.0, 1.0)) if denom > 1e-12 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, float(np.clip(-c / a, 0.0, 1.0))
    elif t > 1.0:
        t, s = 1.0, float(np.clip((b - c) / a, 0.0, 1.0))
    return s, float(t), float(np.linalg.norm(p1 + d1 * s - (p2 + d2 * t)))


def _segment_distance_3d(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> float:
    """Shortest distance between the 3-D segments p1q1 and p2q2 (both of non-zero length) [m]."""
    return segment_closest(p1, q1, p2, q2)[2]


def points_to_segment(P: np.ndarray, p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where along the segment ``p`` → ``q`` (0 at p, 1 at q, clipped) each point of ``P`` ((N, 3)) is
    nearest, and its distance from the segment [m]."""
    d = q - p
    t = np.clip((P - p) @ d / max(float(d @ d), 1e-12), 0.0, 1.0)
    return t, np.linalg.norm(P - (p + np.outer(t, d)), axis=1)


def _interpenetration(a: LogSpec, b: LogSpec) -> float:
    """How deep two logs (as cylinders of their mean radius) interpenetrate [m]; <= 0: apart."""
    return (a.mean_diameter_m + b.mean_diameter_m) / 2 - _segment_distance_3d(*a.endpoints_m(), *b.endpoints_m())


def _axis_shift(log: LogSpec, end_a: Any, end_b: Any) -> float:
    """Largest perpendicular distance of the two GNSS points from the log's axis line [m]."""
    p0, p1 = log.endpoints_m()
    u = (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9)
    out = 0.0
    for e in (end_a, end_b):
        r = np.asarray(e, dtype=float) - p0
        out = max(out, float(np.linalg.norm(r - (r @ u) * u)))
    return out


def _along_across(xy: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seen from above, each point ``xy`` ((N, 2)) against the segment ``p0`` → ``p1`` (their x, y
    are used): where along it (0 at p0, 1 at p1, not clipped) and how far from it [m]."""
    a, d = np.asarray(p0, dtype=float)[:2], np.asarray(p1, dtype=float)[:2] - np.asarray(p0, dtype=float)[:2]
    t = (xy - a) @ d / max(float(d @ d), 1e-12)
    return t, np.linalg.norm(xy - (a + np.outer(np.clip(t, 0.0, 1.0), d)), axis=1)


def _footprint_distance(xy: np.ndarray, logs: Sequence[LogSpec]) -> np.ndarray:
    """Horizontal distance [m] of points outside the nearest log's top-view footprint
    (negative inside)."""
    best = np.full(len(xy), np.inf)
    for log in logs:
        t, dist = _along_across(xy, *log.endpoints_m())
        t = np.clip(t, 0.0, 1.0)
        r = log.diameter_m / 2 + (log.top_d_m - log.diameter_m) / 2 * t
        best = np.minimum(best, dist - r)
    return best


def _underside_z(logs: Sequence[LogSpec], xy: np.ndarray, reach_m: float = 0.0) -> np.ndarray:
    """Lowest height [m] of any of ``logs``' round undersides within ``reach_m`` (horizontally)
    of each point ``xy`` ((N, 2), pile frame), less the axis' rise over that reach; ``+inf`` where
    no log is that close. Nothing lying on the ground can stand above it there."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    out = np.full(len(xy), np.inf)
    for log in logs:
        p0, p1 = log.endpoints_m()
        d = p1 - p0
        t, lat = _along_across(xy, p0, p1)
        t = np.clip(t, 0.0, 1.0)
        r = log.diameter_m / 2 + (log.top_d_m - log.diameter_m) / 2 * t
        near = np.maximum(lat - reach_m, 0.0)  # the underside's lowest point within reach
        inside = near < r
        if not inside.any():
            continue
        slope = abs(float(d[2])) / max(float(np.linalg.norm(d[:2])), 1e-6)  # axis rise per metre of run [-]
        z_axis = p0[2] + t[inside] * d[2] - slope * reach_m
        z = z_axis - np.sqrt(np.clip(r[inside] ** 2 - near[inside] ** 2, 0.0, None))
        out[inside] = np.minimum(out[inside], z)
    return out
