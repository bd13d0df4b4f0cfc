"""Small measuring helpers the benches share: the machine's load (every timing is reported with
it) and percentiles of possibly empty samples."""

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
