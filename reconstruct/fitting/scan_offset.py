"""Two matchings of the survey to the scan compared with the scan pose's error as what it is: one offset of the
whole scan, not an error of its own at every survey point (:func:`matching_chi2`).

The matching (:mod:`reconstruct.fitting.matching`) prices each point's distance from a scan log with the scan
pose's uncertainty (``FuseConfig.pose_sigma_m``, 4 cm) added to the point's own (1-2 cm for an RTK fixed point),
as if every point had its own pose error. That is the right width for finding a point's scan log, but it
makes two matchings hard to tell apart: in a packed pile, where logs lie 15-20 cm apart, a log's RTK fixed
points 8 cm to one side of a ridge and a neighbour's 9 cm to the other cost about the same, although the first
is where every other log of the scan is offset to and the second is not. Judged as one offset, each matching
gets its own best offset (a weighted least-squares fit of its points' distances across their scan logs, with
the pose's prior), and its chi^2 is the points' distances after that offset, each by its own sigma and the scan
log's axis sigma, plus the offset's own prior chi^2 (a profile likelihood). Only the across-log component is
fitted: along the logs the pose error keeps its width (a ridge's end says little about the pose)."""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from reconstruct.fitting.fuse_config import FuseConfig
from reconstruct.fitting.scan_logs import ScanLog
from reconstruct.fitting.survey_points import SurveyEnd


def _normal(log: ScanLog) -> np.ndarray:
    """The unit normal of a scan log's axis in top view."""
    d = (log.end_m - log.start_m)[:2]
    u = d / max(float(np.linalg.norm(d)), 1e-9)
    return np.array([-u[1], u[0]])


def fit_offset(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], ids: Sequence[str],
               scan_logs: Sequence[ScanLog], pick: Sequence[int | None], cfg: FuseConfig) -> np.ndarray:
    """The horizontal offset [m] (survey minus scan) that best explains a matching's points across their scan
    logs: weighted least squares over the points within the gate of their scan log (each by its own sigma and
    the axis sigma), with the pose's prior (zero, ``pose_sigma_m``) so that an offset along parallel logs, which
    their points cannot see, stays at zero."""
    A = np.eye(2) / cfg.pose_sigma_m ** 2
    b = np.zeros(2)
    for i, j in enumerate(pick):
        if j is None:
            continue
        n = _normal(scan_logs[j])
        for e in survey[ids[i]]:
            if e is None:
                continue
            lat = float((e.position_m[:2] - scan_logs[j].start_m[:2]) @ n)
            wide = math.hypot(e.sigma_h_m, math.hypot(cfg.pose_sigma_m, cfg.axis_sigma_m))
            if abs(lat) > cfg.gate_sigma * wide:
                continue  # a point this matching calls wrong says nothing about the pose
            w = 1.0 / (e.sigma_h_m ** 2 + cfg.axis_sigma_m ** 2)
            A += w * np.outer(n, n)
            b += w * lat * n
    return np.linalg.solve(A, b)


def matching_chi2(survey: Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]], ids: Sequence[str],
                  scan_logs: Sequence[ScanLog], pick: Sequence[int | None], none_cost: np.ndarray,
                  cfg: FuseConfig, match_cost, wrong_point_chi2: float) -> float:
    """A matching's summed chi^2 with one offset for the whole scan (see the module docstring): the matched
    logs' costs by ``match_cost(ends, log, cfg, offset)`` after the matching's own best offset, the logs matched
    to nothing at ``none_cost``, and the offset's prior chi^2; a log with every point beyond the gate after the
    offset at ``wrong_point_chi2`` a point (what the matching charges a point it calls wrong)."""
    o = fit_offset(survey, ids, scan_logs, pick, cfg)
    total = float(o @ o) / cfg.pose_sigma_m ** 2
    for i, j in enumerate(pick):
        if j is None:
            total += float(none_cost[i])
            continue
        # a log whose every point the offset leaves beyond the gate costs what calling each of them wrong costs
        n_pts = sum(e is not None for e in survey[ids[i]])
        total += min(match_cost(survey[ids[i]], scan_logs[j], cfg, o)[0], n_pts * wrong_point_chi2)
    return total
