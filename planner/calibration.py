"""U made comparable across target subsets: P(success) = sigmoid(slope * logit(u) + offset[tau]).

The network's U is trained per pixel (positive pixels weighted by ``u_pos_weight``), so it ranks
pixels of one subset well but is no probability, and its level differs by subset size: on fresh
twin piles a single log's best grasp with U 0.99 succeeded far less often than a bundle's with
the same U (docs/model.md). The objectives compare U *across* subsets, so the planner maps U to
the success rate measured in the twin for that subset size before scoring. A monotone map per
size never changes which pixel of a subset is best (f1), only which subset wins.

A calibration is fitted (:func:`fit_calibration`) on trials of the model's own best grasps on
fresh piles (:mod:`experiments.calibration`) and stored beside the checkpoint as
``<model>.calibration.json`` (format ``loggrasp.u_calibration``), tied to the checkpoint's sha256;
:func:`planner.inference.load_planner` reads it when it is there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from planner.errors import CheckpointError
from synth.common.formats import VersionedJson

CALIBRATION_FORMAT = VersionedJson("loggrasp.u_calibration", "1.0", "U calibration", CheckpointError,
                                   fix="refit the calibration with this loggrasp (experiments.calibration fit)")
U_EPS = 1e-6  # U is clipped to [eps, 1 - eps] before its logit [-]


def calibration_path(model_path: str | Path) -> Path:
    """Where a checkpoint's calibration lives: ``model.safetensors`` -> ``model.calibration.json``."""
    p = Path(model_path)
    return p.with_name(p.name.removesuffix(".safetensors") + ".calibration.json")


def logit(u) -> np.ndarray:
    u = np.clip(np.asarray(u, dtype=np.float64), U_EPS, 1.0 - U_EPS)
    return np.log(u) - np.log1p(-u)


@dataclass(frozen=True)
class Calibration:
    """``P = sigmoid(slope * logit(u) + offsets[min(tau, len(offsets)) - 1])``."""

    model_sha256: str  # the checkpoint it was fitted for
    slope: float  # on logit(u) [-], > 0 (the map must keep U's order within a subset)
    offsets: tuple[float, ...]  # per subset size 1, 2, ...; the last one also serves larger sizes [-]
    n_trials: int = 0  # trials it was fitted on [-]
    fitted_on: dict = field(default_factory=dict)  # where the trials came from (seeds, piles)

    def __post_init__(self) -> None:
        if not (self.slope > 0 and math.isfinite(self.slope)):
            raise ValueError(f"slope must be a finite number > 0 (a monotone map), got {self.slope}")
        if not self.offsets or not all(math.isfinite(o) for o in self.offsets):
            raise ValueError(f"offsets must be finite numbers, one per subset size, got {self.offsets}")

    def probability(self, u, tau) -> np.ndarray:
        """Calibrated success probability (float32) of U ``u`` for subsets of ``tau`` logs
        (``tau`` broadcasts against ``u``, e.g. shape (N, 1, 1) for N subsets)."""
        idx = np.clip(np.asarray(tau, dtype=np.int64), 1, len(self.offsets)) - 1
        z = self.slope * logit(u) + np.asarray(self.offsets, dtype=np.float64)[idx]
        return (0.5 * (1.0 + np.tanh(0.5 * z))).astype(np.float32)

    def to_dict(self) -> dict:
        return {"model_sha256": self.model_sha256, "slope": self.slope, "offsets": list(self.offsets),
                "n_trials": self.n_trials, "fitted_on": self.fitted_on}

    def write(self, path: str | Path) -> Path:
        return CALIBRATION_FORMAT.write(path, self.to_dict())

    @classmethod
    def read(cls, path: str | Path) -> "Calibration":
        d = CALIBRATION_FORMAT.read(path)
        try:
            return cls(str(d["model_sha256"]), float(d["slope"]), tuple(float(o) for o in d["offsets"]),
                       int(d.get("n_trials", 0)), dict(d.get("fitted_on") or {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f"{path}: not a valid U calibration ({exc}); refit it") from exc

    def summary(self) -> str:
        sizes = ", ".join(f"{i + 1}{'+' if i == len(self.offsets) - 1 else ''}: {o:+.2f}"
                          for i, o in enumerate(self.offsets))
        return f"U calibration on {self.n_trials} trials: slope {self.slope:.3f}, offsets by subset size {sizes}"


def load_calibration(model_path: str | Path, model_sha256: str) -> Calibration | None:
    """The calibration beside ``model_path``, or None when there is none; :class:`CheckpointError`
    when it belongs to another checkpoint."""
    path = calibration_path(model_path)
    if not path.is_file():
        return None
    cal = Calibration.read(path)
    if cal.model_sha256 != model_sha256:
        raise CheckpointError(f"{path} was fitted for checkpoint sha256 {cal.model_sha256[:12]}…, not for "
                              f"{Path(model_path).name} ({model_sha256[:12]}…); refit it or remove it")
    return cal


def fit_calibration(trials: list[dict], model_path: str | Path, max_size: int = 6, ridge: float = 1.0,
                    fitted_on: dict | None = None) -> Calibration:
    """Logistic regression of ``success`` on logit(``u``) with one offset per subset size ``tau``
    (sizes above ``max_size`` share the last), the offsets pulled towards their mean by ``ridge``
    (sizes with few trials). ``trials``: dicts with ``u``, ``tau``, ``success``."""
    from synth.common.files import sha256_file

    if len(trials) < 20:
        raise ValueError(f"need at least 20 trials to fit a calibration, got {len(trials)}")
    x = logit([t["u"] for t in trials])
    size = np.clip([int(t["tau"]) for t in trials], 1, max_size) - 1
    y = np.array([bool(t["success"]) for t in trials], dtype=np.float64)
    theta = _fit_logistic(x, size, y, max_size, ridge)
    slope = float(theta[0])
    if slope <= 0:
        raise ValueError(f"U does not predict success on these trials (slope {slope:.3f} <= 0); "
                         "collect more trials or check the model")
    return Calibration(sha256_file(model_path), slope, tuple(float(o) for o in theta[1:]), len(trials),
                       dict(fitted_on or {}))


def _fit_logistic(x: np.ndarray, size: np.ndarray, y: np.ndarray, n_sizes: int, ridge: float,
                  iterations: int = 100) -> np.ndarray:
    """Newton's method with step halving on the penalised log-likelihood; theta = (slope,
    offset_1..offset_n). The offsets are pulled towards their mean by ``ridge``, the slope towards 1
    by a weak 1e-3 (separable data would otherwise send it to infinity)."""
    design = np.zeros((len(x), 1 + n_sizes))
    design[:, 0] = x
    design[np.arange(len(x)), 1 + size] = 1.0
    pen = np.zeros((1 + n_sizes, 1 + n_sizes))
    pen[0, 0] = 1e-3
    pen[1:, 1:] = ridge * (np.eye(n_sizes) - 1.0 / n_sizes)  # ridge * sum (o_i - mean o)^2
    prior = np.zeros(1 + n_sizes)
    prior[0] = 1.0

    def objective(theta: np.ndarray) -> float:
        z = design @ theta
        d = theta - prior
        return float(np.sum(y * z - np.logaddexp(0.0, z)) - 0.5 * d @ pen @ d)

    theta = prior.copy()
    value = objective(theta)
    for _ in range(iterations):
        p = 0.5 * (1.0 + np.tanh(0.5 * (design @ theta)))  # the logistic function, without overflow
        grad = design.T @ (y - p) - pen @ (theta - prior)
        hess = (design * (p * (1 - p))[:, None]).T @ design + pen + 1e-9 * np.eye(len(theta))
        step = np.linalg.solve(hess, grad)
        t = 1.0
        while t > 1e-6 and objective(theta + t * step) < value - 1e-12:
            t /= 2
        theta, last = theta + t * step, value
        value = objective(theta)
        if abs(value - last) < 1e-10:
            break
    return theta
