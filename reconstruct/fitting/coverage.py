"""Whether the scan can speak for the survey's end points: :func:`check_coverage`.

A surveyed end point within ``ReconstructConfig.max_endpoint_distance_m`` of a scan point is in the scanned
area. One farther out is either a log that leaves the scan (a pile wider than the pairs' footprint: the log is
seen, its end is not) or a point the scan cannot explain (a point of another pile, a wrong log id, a wrong scan
pose). The two are told apart by the log, not by the point: a log whose surveyed axis runs over the scanned
area for at least :attr:`CoverageConfig.seen_log_min_length_m` is in the scan, and its ends may lie outside
it. Such an end is placed from its survey point and, like every point, judged by the fit against the log's
seen part (its direction and where the scan puts the log); a correct RTK fixed point then never stops the
reconstruction for lying where the cameras did not look. The report lists these ends (:class:`OutsideEnd`).

What the scan could show of a log is also what its seen part is measured against: the matching takes a scan
log seen over less than ``FuseConfig.piece_share`` of its survey points' distance for a piece of a log hidden
under others, and sets its axis from the survey alone
(:func:`reconstruct.fitting.matching.a_piece_of_a_surveyed_log`); the share is of the part of the survey axis
over the scanned area (:attr:`Coverage.over_scan_share`), since a log is not hidden beyond the scan's edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from reconstruct.errors import RegistrationError
from reconstruct.fitting.fuse import SurveyEnd
from reconstruct.scan.plan import covering_plan_hint

SAMPLES_PER_GAP = 2  # the axis is sampled this many times per scan_gap_m, so no hole wider than it is stepped over
IMPRECISE_POINT_SIGMAS = 4.0  # an imprecise point is in the scanned area within this many of its radial sigmas


@dataclass(frozen=True)
class CoverageConfig:
    """When a surveyed end may lie outside the scanned area (module docstring)."""

    seen_log_min_length_m: float = 0.5  # a log whose surveyed axis runs this far over the scanned area is in
    # the scan, and its ends may lie outside it [m]: one cross-section chunk of the cylinder fit
    # (FitConfig.chunk_length_m), the least piece of log the fit places an axis on and so checks an end against
    scan_gap_m: float = 0.10  # a place on the axis this close (horizontally) to a scan point is over the
    # scanned area [m]: the stereo cloud samples the ground every centimetre or two, so this bridges its small
    # holes and reaches no further past its edge than a log's radius

    def __post_init__(self) -> None:
        for name in ("seen_log_min_length_m", "scan_gap_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"CoverageConfig.{name} must be > 0 m, got {getattr(self, name)}")


@dataclass(frozen=True)
class OutsideEnd:
    """A surveyed end outside the scanned area, admitted because its log is seen."""

    log_id: str
    end: str  # "a" or "b"
    distance_m: float  # horizontal distance to the nearest scan point [m]
    seen_length_m: float  # the length of the log's surveyed axis over the scanned area [m]

    def line(self) -> str:
        return (f"{self.log_id} end {self.end} lies {self.distance_m:.2f} m outside the scanned area; its log runs "
                f"{self.seen_length_m:.2f} m over it: the end is placed from its survey point, which the scan "
                "checks only through the log's seen part")

    def to_dict(self) -> dict:
        return {"log_id": self.log_id, "end": self.end, "distance_m": self.distance_m,
                "seen_length_m": self.seen_length_m}


@dataclass(frozen=True)
class Coverage:
    """:func:`check_coverage`'s answer."""

    distances_m: dict[str, list[float | None]]  # each end's horizontal distance to the nearest scan point [m]
    outside: tuple[OutsideEnd, ...]  # the ends beyond the limit whose logs are seen
    over_scan_share: dict[str, float]  # each two-point log's survey axis: the share of it over the scanned area [-]


def _position(e: Any) -> np.ndarray:
    return e.position_m if isinstance(e, SurveyEnd) else np.asarray(e, dtype=float)


def _limit_m(e: Any, limit_m: float) -> float:
    """How far from the scan an end point may lie and still be in the scanned area [m]."""
    if isinstance(e, SurveyEnd):
        return max(limit_m, IMPRECISE_POINT_SIGMAS * math.sqrt(2) * e.sigma_h_m)
    return limit_m


def seen_length_m(tree: Any, a_xy: np.ndarray, b_xy: np.ndarray, cfg: CoverageConfig) -> float:
    """The length of the horizontal segment ``a_xy``-``b_xy`` lying within ``cfg.scan_gap_m`` of a scan
    point (``tree``: a ``cKDTree`` of the scan's horizontal positions) [m]."""
    length = float(np.linalg.norm(np.asarray(b_xy) - np.asarray(a_xy)))
    n = max(2, math.ceil(length * SAMPLES_PER_GAP / cfg.scan_gap_m) + 1)
    s = np.linspace(0.0, 1.0, n)[:, None]
    d = tree.query(a_xy[None, :] * (1.0 - s) + b_xy[None, :] * s)[0]
    return float(np.mean(d <= cfg.scan_gap_m)) * length


def check_coverage(points_xy: np.ndarray, endpoints: dict[str, tuple[Any, Any]], limit_m: float,
                   cfg: CoverageConfig | None = None) -> Coverage:
    """Every end point (a :class:`~reconstruct.fitting.fuse.SurveyEnd`, a point, or None: not surveyed) against
    the scan's horizontal positions ``points_xy``: an end beyond ``limit_m`` (or four radial sigmas of an
    imprecise point) of every scan point is admitted when its log is seen (both ends surveyed, the axis
    between them at least ``cfg.seen_log_min_length_m`` over the scanned area), else a
    :class:`~reconstruct.errors.RegistrationError` naming the farthest such point."""
    from scipy.spatial import cKDTree

    cfg = cfg or CoverageConfig()
    tree = cKDTree(points_xy)
    distances: dict[str, list[float | None]] = {}
    shares: dict[str, float] = {}
    outside, worst = [], []
    for log_id, ends in endpoints.items():
        distances[log_id] = [None if e is None else float(tree.query(_position(e)[:2])[0]) for e in ends]
        seen = 0.0
        if all(e is not None for e in ends):
            a, b = _position(ends[0])[:2], _position(ends[1])[:2]
            seen = seen_length_m(tree, a, b, cfg)
            length = float(np.linalg.norm(b - a))
            shares[log_id] = min(1.0, seen / length) if length > 0 else 1.0
        far = [(d, end, e) for d, end, e in zip(distances[log_id], "ab", ends)
               if d is not None and d > _limit_m(e, limit_m)]
        if not far:
            continue
        if seen >= cfg.seen_log_min_length_m:
            outside += [OutsideEnd(log_id, end, d, seen) for d, end, _ in far]
        else:
            worst += [(d, log_id, end, _position(e)) for d, end, e in far]
    if worst:
        worst.sort(key=lambda w: w[0], reverse=True)
        dist, log_id, end, p = worst[0]
        raise RegistrationError(
            f"GNSS point of log {log_id!r} end {end!r} (site E {p[0]:.2f} m, N {p[1]:.2f} m) is {dist:.2f} m "
            f"from the nearest scan point (limit {limit_m} m); {len(worst)} end point(s) lie outside the "
            f"scanned area on logs the scan does not see (less than {cfg.seen_log_min_length_m} m of their "
            "surveyed axis over it). Check the log id and the scan pose, or scan the whole pile"
            + covering_plan_hint(endpoints)
        )
    return Coverage(distances, tuple(outside), shares)
