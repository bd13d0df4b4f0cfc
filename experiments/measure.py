"""Small measuring helpers the benches share: the machine's load (every timing is reported with
it), percentiles of possibly empty samples, the paired difference's standard error."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def load_average(prefix: str = "load average ") -> str:
    """The 1/5/15-minute load average as ``/proc/loadavg`` gives it, e.g. ``"load average 2.10
    1.95 1.80"``; ``"?"`` for the numbers where the file cannot be read."""
    try:
        return prefix + " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return prefix + "?"


def percentile(values, q: float) -> float:
    """The ``q``-th percentile of ``values`` [0-100]; NaN for no values."""
    return float(np.percentile(np.asarray(values, dtype=float), q)) if len(values) else math.nan


def paired_se(a, b) -> float:
    """Standard error of the difference of success rates ``mean(b) - mean(a)`` over the same piles
    (0/1 arrays): from the discordant piles, each count plus one half (Agresti-Min style: no false
    certainty when few piles disagree)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    n = len(a)
    only_a = float(((a == 1) & (b == 0)).sum()) + 0.5
    only_b = float(((a == 0) & (b == 1)).sum()) + 0.5
    return math.sqrt(max(only_a + only_b - (only_b - only_a) ** 2 / n, 0.0)) / n


def paired(a, b) -> tuple[float, float, float]:
    """Difference of success rates ``mean(b) - mean(a)`` [pp] over the same piles (0/1 arrays), and its
    95 % interval (standard error: :func:`paired_se`)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    se = paired_se(a, b)
    d = 100 * (b.mean() - a.mean())
    return d, d - 196 * se, d + 196 * se
