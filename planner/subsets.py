"""Which target subsets to evaluate.

Exhaustive: every non-empty subset of the visible logs (2^n - 1). For large piles that is too many
network passes, so :func:`feasible_subsets` keeps only subsets a grapple could close around at
all: every log of the subset must come within ``R = hypot(max_opening/2, rect_width/2)`` of one
common grasp centre (R is the radius of the circle around the grasp rectangle, so this never
drops a subset that one grasp rectangle could cover). For each log the distance map
``d_i(p)`` (metres from pixel p to the log's mask) is computed once; a subset S fits when
``r(S) = min_p max_{i in S} d_i(p) <= R``. The test is monotone (a superset of a subset that does
not fit does not fit either), so a depth-first enumeration prunes whole branches. It implies the
"adjacency graph" condition (every pair of logs within 2R of each other, hence connected).
When more subsets fit than ``max_subsets``, all single logs are kept and the budget is shared
round-robin across subset sizes, tightest ``r(S)`` first within each size.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from synth.geometry.grasp import MAX_WIDTH_M, RECT_WIDTH_M


@dataclass(frozen=True)
class SubsetPolicy:
    mode: Literal["auto", "exhaustive", "fit"] = "auto"  # "auto": exhaustive when 2^n-1 <= max_subsets, else "fit"; "exhaustive"; "fit"
    max_subsets: int = 127  # network passes per plan [-]
    max_opening_m: float = MAX_WIDTH_M  # grapple's maximum opening [m]
    rect_width_m: float = RECT_WIDTH_M  # grasp rectangle across the closing axis [m]
    max_logs_per_subset: int | None = None  # optional cap on |S| [-]
    enumeration_limit: int = 8192  # subsets examined before larger sizes are no longer enumerated [-]

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "exhaustive", "fit"):
            raise ValueError(f"subset mode must be 'auto', 'exhaustive' or 'fit', got {self.mode!r}")
        if self.max_subsets < 1:
            raise ValueError(f"max_subsets must be >= 1, got {self.max_subsets}")
        if self.max_opening_m <= 0 or self.rect_width_m < 0:
            raise ValueError("max_opening_m must be > 0 and rect_width_m >= 0")
        if self.max_logs_per_subset is not None and self.max_logs_per_subset < 1:
            raise ValueError("max_logs_per_subset must be >= 1 or None")

    @property
    def fit_radius_m(self) -> float:
        return math.hypot(self.max_opening_m / 2, self.rect_width_m / 2)


def all_subsets(logs: list[int], max_size: int | None = None) -> list[tuple[int, ...]]:
    """Every non-empty subset of ``logs`` (sorted tuples), smallest first."""
    k_max = len(logs) if max_size is None else min(max_size, len(logs))
    return [c for k in range(1, k_max + 1) for c in itertools.combinations(sorted(logs), k)]


def distance_maps(masks: dict[int, np.ndarray], pixel_m: float) -> dict[int, np.ndarray]:
    """Per log: distance [m] from every pixel to the nearest pixel of its mask (float32)."""
    from scipy.ndimage import distance_transform_edt

    return {i: (distance_transform_edt(~m) * pixel_m).astype(np.float32) for i, m in masks.items()}


def feasible_subsets(masks: dict[int, np.ndarray], pixel_m: float, policy: SubsetPolicy = SubsetPolicy(),
                     ) -> tuple[list[tuple[int, ...]], dict]:
    """Subsets that fit one grapple opening, capped at ``policy.max_subsets``.

    Enumerated level by level (1 log, 2 logs, ...); each subset carries the candidate centres
    where it still fits (a point that fails can never fit a superset), so the work shrinks as
    subsets grow. Enumeration stops after the level at which ``policy.enumeration_limit`` subsets
    are exceeded (``info["stopped_after_size"]``). When more subsets fit than the budget, the
    budget is shared round-robin across subset sizes, tightest ``r(S)`` first within a size, all
    single logs always kept. Returns ``(subsets, info)``."""
    logs = sorted(masks)
    dist = distance_maps(masks, pixel_m)
    # candidate centres on every `step`-th pixel: any point lies within step/sqrt(2) px of one, and
    # pixel-centre distances can be half a pixel long; both are added to R (distances are
    # 1-Lipschitz) so that no subset that fits is lost
    size = next(iter(masks.values())).shape[0]
    step = max(1, size // 64)
    slack = pixel_m * (step / math.sqrt(2) + 0.5)
    R = policy.fit_radius_m + slack
    d = {i: dist[i][::step, ::step].ravel() for i in logs}
    max_size = policy.max_logs_per_subset or len(logs)
    level = []
    for j, i in enumerate(logs):
        idx = np.flatnonzero(d[i] <= R)
        if len(idx):
            level.append(((i,), j, idx, d[i][idx]))
    found: list[tuple[float, tuple[int, ...]]] = [(float(m.min()), s) for s, _, _, m in level]
    stopped = None
    k = 1
    while level and k < max_size:
        if len(found) > policy.enumeration_limit:
            stopped = k
            break
        nxt = []
        for s, j0, idx, m in level:
            for j in range(j0 + 1, len(logs)):
                i = logs[j]
                m2 = np.maximum(m, d[i][idx])
                ok = m2 <= R
                if ok.any():
                    s2 = s + (i,)
                    nxt.append((s2, j, idx[ok], m2[ok]))
                    found.append((float(m2[ok].min()), s2))
        level = nxt
        k += 1
    n_fit = len(found)
    if n_fit > policy.max_subsets:
        by_size: dict[int, list] = {}
        for r, s in sorted(found):
            by_size.setdefault(len(s), []).append(s)
        keep = list(by_size.pop(1, []))
        queues = [by_size[k] for k in sorted(by_size)]
        pos = 0
        while len(keep) < policy.max_subsets and any(queues):
            q = queues[pos % len(queues)]
            if q:
                keep.append(q.pop(0))
            pos += 1
        keep = keep[: max(policy.max_subsets, len([s for s in keep if len(s) == 1]))]
    else:
        keep = [s for _, s in found]
    keep.sort(key=lambda s: (len(s), s))
    return keep, {"n_fit": n_fit, "n_kept": len(keep), "radius_m": policy.fit_radius_m,
                  "stopped_after_size": stopped}


def choose_subsets(masks: dict[int, np.ndarray], pixel_m: float, policy: SubsetPolicy = SubsetPolicy()):
    """Apply the policy: ``(subsets, info)`` where info["selection"] is "exhaustive" or "fit".

    Raises ``ValueError`` when "exhaustive" is asked for but 2^n - 1 exceeds ``max_subsets``."""
    n = len(masks)
    n_all = 2 ** n - 1
    if policy.max_logs_per_subset is not None:
        n_all = sum(math.comb(n, k) for k in range(1, min(n, policy.max_logs_per_subset) + 1))
    if policy.mode == "exhaustive" or (policy.mode == "auto" and n_all <= policy.max_subsets):
        if n_all > policy.max_subsets:
            raise ValueError(
                f"{n} logs give {n_all} target subsets, more than the budget of {policy.max_subsets}; "
                "use subset mode 'fit' (or 'auto') to pre-select the subsets a grapple can close around, "
                "or raise max_subsets"
            )
        return all_subsets(sorted(masks), policy.max_logs_per_subset), {"selection": "exhaustive", "n_possible": n_all}
    subsets, info = feasible_subsets(masks, pixel_m, policy)
    return subsets, {"selection": "fit", "n_possible": n_all, **info}
