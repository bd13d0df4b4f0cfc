"""The scan's offset from the survey as a state of the joint matching (issue 37, step 2).

Matching runs on the scan pose as given (the crane's RTK/IMU camera pose, or the coarse placement from the
survey), before the registration refines it against the matched logs. That pose's error is one offset shared
by every survey point, not an error of each point alone: a few centimetres across a packed pile put every
point between two ridges at once, and points scored one by one then fit neighbours' ridges as well as their
own. So the assignment is made at the likeliest offset: the offset ``d`` that minimises the assignment's cost
with the survey moved by ``d`` plus its Gaussian prior ``|d|^2 / (2 sigma^2)`` (sigma: the pose's uncertainty
while matching, :class:`~reconstruct.fitting.fuse_config.FuseConfig` ``pose_sigma_m``), found on a grid
across the prior's reach and refined from the best grid points.
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np
from scipy.optimize import minimize

from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.survey_points import SurveyEnd

#: the grid's best points the search refines from [-]
REFINE_STARTS = 3
#: the refinement stops when a step changes the offset by less than this [m] or the cost by less than this [nats]
REFINE_TOL_M = 1e-3
REFINE_TOL_NATS = 1e-3

Survey = Mapping[str, tuple[SurveyEnd | None, SurveyEnd | None]]


def shifted(survey: Survey, offset_m: np.ndarray) -> dict[str, tuple[SurveyEnd | None, SurveyEnd | None]]:
    """The survey with every point moved by ``offset_m`` (3,) [m]."""
    T = np.eye(4)
    T[:3, 3] = offset_m
    return {k: tuple(None if e is None else e.moved(T) for e in ends) for k, ends in survey.items()}


def pose_offset(cost_at: Callable[[np.ndarray], float], sigma_m: float, cfg: JointConfig) -> np.ndarray:
    """The offset (3,) [m] that minimises ``cost_at(offset)`` (the assignment's cost with the survey moved by it
    [nats]) plus the offset's Gaussian prior of ``sigma_m`` per axis."""

    def total(d: np.ndarray) -> float:
        return float(cost_at(d)) + 0.5 * float(d @ d) / sigma_m ** 2

    reach = cfg.match_pose_reach_sigmas * sigma_m
    steps = np.arange(-reach, reach + 0.5 * cfg.match_pose_step_m, cfg.match_pose_step_m)
    grid = [np.array([x, y, 0.0]) for x in steps for y in steps if x * x + y * y <= reach * reach]
    scored = sorted(((total(d), i) for i, d in enumerate(grid)), key=lambda t: t[0])
    best_d, best_c = np.zeros(3), total(np.zeros(3))
    for c0, i in scored[:REFINE_STARTS]:
        simplex = grid[i] + np.vstack([np.zeros(3), 0.5 * cfg.match_pose_step_m * np.eye(3)])
        r = minimize(total, grid[i], method="Nelder-Mead",
                     options={"initial_simplex": simplex, "xatol": REFINE_TOL_M, "fatol": REFINE_TOL_NATS})
        d, c = (r.x, float(r.fun)) if r.fun < c0 else (grid[i], c0)
        if c < best_c:
            best_d, best_c = np.asarray(d, dtype=float), c
    return best_d
