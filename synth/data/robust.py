"""Robust labels: a grasp is accepted for how likely it is to work where the crane really stands.

Algorithm 1 (:func:`synth.data.candidates.reduce_candidates`) accepts the first candidate that
succeeds once, exactly where it was asked for. A real crane stands a few centimetres off
(:class:`synth.physics.perturb.PositioningError`), so a grasp that only works exactly is a
lottery ticket as a training label. With :class:`RobustLabels`, a grasp that succeeded exactly is
tried again ``repeats`` times, each moved by a draw of the field's positioning error; it is
accepted only when at least ``min_fraction`` of those succeed, and every repeat is stored with it
(the store keeps outcomes, so labels can be re-derived without re-simulating).

Repeats stop as soon as the verdict is decided (three successes of four accept, two failures
refuse): a sequential test that saves about a quarter of the repeats. A label's success fraction
is over the repeats that ran, which are stored with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

from synth.data.candidates import _succeeded as _ok
from synth.geometry.grasp import Grasp
from synth.physics.perturb import PositioningError, grasp_rng, perturbed_grasps


@dataclass(frozen=True)
class RobustLabels:
    """How accepted grasps are confirmed under the field's positioning error.

    The default error, σ 2 cm per horizontal axis and 2° of rotator angle, is the field chain's:
    RTK-fixed log ends ±1–2 cm, the reconstruction's end error (median 1.6 cm on the default
    survey, docs/benchmarks.md) and the crane's own joint sensing, combined; 2° is what a
    rotator with an angle sensor holds under load. Four repeats at a 0.75 threshold refuse a
    grasp after two failures and keep one that fails at most once.
    """

    repeats: int = 4  # perturbed re-tries per exactly successful grasp [-]; 0 = the paper's labels
    error: PositioningError = field(default_factory=PositioningError)
    min_fraction: float = 0.75  # accept when at least this share of the repeats succeeds [-]

    def __post_init__(self) -> None:
        if not isinstance(self.repeats, int) or not 0 <= self.repeats <= 64:
            raise ValueError(f"robust label repeats must be an integer in [0, 64], got {self.repeats!r}")
        if not (isinstance(self.min_fraction, (int, float)) and 0.0 <= self.min_fraction <= 1.0):
            raise ValueError(f"robust label min_fraction must be in [0, 1], got {self.min_fraction!r}")
        if not isinstance(self.error, PositioningError):
            raise ValueError(f"robust label error must be a PositioningError, got {type(self.error).__name__}")

    @property
    def enabled(self) -> bool:
        return self.repeats > 0

    def needed(self) -> int:
        """Successful repeats a grasp needs to be accepted."""
        return math.ceil(self.min_fraction * self.repeats - 1e-9)

    def to_dict(self) -> dict:
        return {"repeats": self.repeats, "error": self.error.to_dict(), "min_fraction": self.min_fraction}

    @staticmethod
    def from_dict(d: dict) -> "RobustLabels":
        try:
            return RobustLabels(int(d["repeats"]), PositioningError(**d["error"]), float(d["min_fraction"]))
        except (KeyError, TypeError) as e:
            raise ValueError(f"robust label settings {d!r} are incomplete: need repeats, error, min_fraction") from e


@dataclass(frozen=True)
class Confirmation:
    """The repeats of one grasp: each perturbed grasp with its trial result, and the verdict."""

    repeats: tuple[tuple[Grasp, object], ...]
    accepted: bool

    @property
    def successes(self) -> int:
        return sum(1 for _, r in self.repeats if _ok(r))

    @property
    def fraction(self) -> float:
        return self.successes / len(self.repeats) if self.repeats else float("nan")


def confirmer(labels: RobustLabels, simulate: Callable[[Grasp], object], seed: int,
              *keys: object) -> Callable[[Grasp], Confirmation]:
    """``confirm(grasp) -> Confirmation``: ``labels.repeats`` perturbed trials of ``grasp`` drawn from
    a generator keyed by ``(seed, *keys, grasp)``, stopping once the verdict is decided."""
    need = labels.needed()

    def confirm(g: Grasp) -> Confirmation:
        rng = grasp_rng(seed, *keys, round(g.x_m, 6), round(g.y_m, 6), round(g.phi_rad, 6), round(g.width_m, 6))
        done: list[tuple[Grasp, object]] = []
        wins = 0
        for q in perturbed_grasps(g, labels.error, labels.repeats, rng):
            r = simulate(q)
            done.append((q, r))
            wins += _ok(r)
            left = labels.repeats - len(done)
            if wins >= need or wins + left < need:
                break  # decided: the rest cannot change the verdict
        return Confirmation(tuple(done), wins >= need)

    return confirm


def repeat_rows(c: Confirmation) -> list[list]:
    """The stored form of a confirmation's repeats: ``[x, y, phi, width, outcome]`` each."""
    rows = []
    for q, r in c.repeats:
        o = getattr(getattr(r, "outcome", None), "value", None) or ("success" if _ok(r) else "failure")
        rows.append([q.x_m, q.y_m, q.phi_rad, q.width_m, o])
    return rows
