"""Outcome labels: what every stored trial says about the grasp centre it tried.

A store chunk keeps, per target subset, every trial Algorithm 1 ran (:func:`synth.data.dataset._trial_row`:
the grasp ``g``, its outcome ``o``, cos β ``b``, the logs held ``h``), successes and failures alike.
The accepted-grasp maps (:func:`synth.data.maps.encode_grasps`) use only the accepted ones; this
module turns *all* of them into a success value per tried grasp and into training targets where a
failed centre is a negative, an untried pixel is weighted low, and a subset whose trials hit the
cap (Algorithm 1 stopped with candidates left) does not count its untried pixels as negatives.

A trial's success value (:func:`trial_success`) is, by the first key present:

* ``p`` — a success fraction in [0, 1] (robust labels: the grasp re-tried under the field's
  positioning error, :mod:`synth.physics.perturb`);
* ``r`` — the grasp's repeats under the field's positioning error (robust labels,
  :func:`synth.data.robust.repeat_rows`: ``[x, y, phi, width, outcome]`` each): their share of
  ``"success"`` (the exact trial ``o`` is not counted, as in the robust labels' fraction);
* ``o`` — one outcome: 1 for ``"success"``, 0 for anything else.

In a shard the trials of a subset are rows of :data:`TRIAL_COLUMNS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: columns of a shard's ``trials`` array (one row per stored trial)
TRIAL_COLUMNS = ("x_m", "y_m", "phi_rad", "width_m", "success", "cos_beta")
#: target channels of the outcome recipe: the five maps, then the per-pixel BCE weight of U
OUTCOME_CHANNELS = ("C", "S", "W", "U", "B", "U_weight")
_CENTRE_DECIMALS = 6  # trials at the same (x, y, phi) to 1 µm / 1 µrad are one centre (Algorithm 1's widening)


@dataclass(frozen=True)
class OutcomeLabelConfig:
    """BCE weights of U per pixel kind in the outcome recipe."""

    tried_weight: float = 1.0  # pixels in a tried grasp's region (label: its success value) [-]
    untried_weight: float = 0.05  # other pixels of a subset whose candidates were all tried or that had none (label 0) [-]
    capped_untried_weight: float = 0.0  # other pixels of a subset whose trials hit the cap: not proven negatives [-]

    def __post_init__(self) -> None:
        for k in ("tried_weight", "untried_weight", "capped_untried_weight"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"outcome label {k} must be a finite number >= 0, got {v!r}")
        if not self.tried_weight > 0:
            raise ValueError("outcome label tried_weight must be > 0 (the tried centres are the labels)")


def trial_success(row: dict) -> float:
    """The success value in [0, 1] of one stored trial (see the module doc); ValueError for a row
    that has none or a value outside [0, 1]."""
    if row.get("p") is not None:
        p = float(row["p"])
    elif row.get("r"):
        reps = [rep[-1] if isinstance(rep, (list, tuple)) else rep for rep in row["r"]]
        p = sum(1 for o in reps if o == "success") / len(reps)
    elif row.get("o") is not None:
        p = 1.0 if row["o"] == "success" else 0.0
    else:
        raise ValueError(f"a stored trial carries no outcome ('p', 'r' or 'o'): {sorted(row)}")
    if not (math.isfinite(p) and 0.0 <= p <= 1.0):
        raise ValueError(f"a trial's success fraction must be in [0, 1], got {p}")
    return p


def trial_array(trials: Sequence[dict]) -> np.ndarray:
    """Stored trial rows -> ``(n, 6)`` float64 array of :data:`TRIAL_COLUMNS` (cos β NaN when unknown)."""
    out = np.empty((len(trials), len(TRIAL_COLUMNS)), dtype=np.float64)
    for i, t in enumerate(trials):
        x, y, phi, w = (float(v) for v in t["g"])
        b = t.get("b")
        out[i] = (x, y, phi, w, trial_success(t), float("nan") if b is None else float(b))
    return out


def merge_centres(trials: np.ndarray) -> np.ndarray:
    """One row per tried centre: Algorithm 1 tries a successful grasp again wider at the same
    (x, y, φ); the network chooses the width, so a centre is worth its best width — the row with
    the highest success value (ties: the later, i.e. the wider retry). Order of first appearance kept."""
    trials = np.asarray(trials, dtype=np.float64).reshape(-1, len(TRIAL_COLUMNS))
    best: dict[tuple, int] = {}
    for i, row in enumerate(trials):
        key = tuple(np.round(row[:3], _CENTRE_DECIMALS))
        j = best.get(key)
        if j is None or row[4] >= trials[j, 4]:
            best[key] = i
    first = {}
    for i, row in enumerate(trials):
        first.setdefault(tuple(np.round(row[:3], _CENTRE_DECIMALS)), i)
    return trials[[best[k] for k in sorted(best, key=first.get)]]


def outcome_targets(grid, trials: np.ndarray, capped: bool, config: OutcomeLabelConfig = OutcomeLabelConfig()) -> np.ndarray:
    """The outcome recipe's targets ``(6, H, W)`` float32 (:data:`OUTCOME_CHANNELS`) of one subset
    from its stored ``trials`` (:func:`trial_array` rows) and whether they hit the cap: C, S, W, U,
    B from the nearest tried centre (:func:`synth.data.maps.encode_outcomes`, U = its success
    value), then the BCE weight of U — ``tried_weight`` on tried regions, elsewhere
    ``capped_untried_weight`` for a capped subset, else ``untried_weight`` (label 0)."""
    from synth.data.maps import encode_outcomes
    from synth.geometry.grasp import Grasp

    rows = merge_centres(trials)
    grasps = [Grasp(float(x), float(y), float(p), float(w)) for x, y, p, w, _, _ in rows]
    maps, tried = encode_outcomes(grid, grasps, rows[:, 4], rows[:, 5])
    weight = np.full(tried.shape, config.capped_untried_weight if capped else config.untried_weight, np.float32)
    weight[tried] = config.tried_weight
    return np.concatenate([maps, weight[None]]).astype(np.float32)
