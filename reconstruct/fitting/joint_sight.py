"""Sight lines for the joint end model (joint revision 19): whether the scan could have seen a point past
a log that is not there.

A bin along a log's axis reads "below" (:data:`reconstruct.fitting.joint_ends.BELOW`) where the scan has
points under where the log's top would be: past the log's end, the ground or a lower log. That is evidence
that the log is not there only if the log, had it been there, would have hidden those points. A camera
beside a log raised off the ground sees the ground under it along a sight line that passes below the log;
where the camera's view of the log's top is cut off (the edge of its image, where the top is nearer the
camera than the ground), the scan then shows the ground under the log and not its top, and the bins read
"below" inside the log. :func:`seen_past` finds those points: a point some camera could have seen with the
log in place says nothing about where the log ends.

The cameras are the scan's pairs' (left) camera centres; which pair saw a point is not kept with the fused
cloud, so a point counts as evidence only when every camera's sight line to it crosses the log.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def segment_distances(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """The closest distance between segments ``p0``-``p1`` and ``q0``-``q1``, row by row ((N, 3) each, or
    broadcastable) [m] (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.maximum(np.einsum("...i,...i", d1, d1), _EPS)
    e = np.maximum(np.einsum("...i,...i", d2, d2), _EPS)
    b, c, f = (np.einsum("...i,...i", d1, d2), np.einsum("...i,...i", d1, r), np.einsum("...i,...i", d2, r))
    denom = a * e - b * b
    s = np.where(denom > _EPS * a * e, np.clip((b * f - c * e) / np.maximum(denom, _EPS), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    gap = (p0 + s[..., None] * d1) - (q0 + t[..., None] * d2)
    return np.sqrt(np.einsum("...i,...i", gap, gap))


def seen_past(points: np.ndarray, cameras: np.ndarray, pa: np.ndarray, u: np.ndarray, t_points: np.ndarray,
              t_from_m: float, radius_m: float) -> np.ndarray:
    """Per point, whether some camera in ``cameras`` ((C, 3)) sees it past the log: its sight line clears the
    log's axis segment from ``pa + t_from_m u`` to the point's own place along it (``t_points``) by more than
    ``radius_m`` (the log as far as it would have to reach to cover the point). No cameras: False (every
    point is evidence, as without sight lines)."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    C = np.asarray(cameras, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(P), bool)
    if not len(P) or not len(C):
        return out
    q0 = np.broadcast_to(pa + t_from_m * u, P.shape)
    q1 = pa + np.outer(np.asarray(t_points, dtype=np.float64), u)
    for cam in C:
        out |= segment_distances(np.broadcast_to(cam, P.shape), P, q0, q1) > radius_m
    return out
