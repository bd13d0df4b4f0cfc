"""The piles verification tries grasps on: a check that the twin can load the pile a plan was made
on, and perturbed copies of it (the reconstruction's uncertainty).

:func:`perturb_pile` draws copy ``k`` of a pile from :class:`PerturbationConfig` alone (every log
end and diameter jittered by normal noise, obstacles moved and scaled, logs pushed into each other
lifted clear in the twin); :func:`perturbation_for_fits` sets per-log sigmas from how the
reconstruction placed each log. :mod:`planner.verify` tries its candidates on these copies.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from planner.errors import VerificationError
from synth.scene.pile import LogSpec, PileSpec, rotate

if TYPE_CHECKING:
    from planner.inference import Plan

@dataclass(frozen=True)
class PerturbationConfig:
    """Perturbed copies of the pile (the reconstruction's uncertainty), tried besides the pile as given.

    Every log end moves by independent normal noise, the diameter changes by normal noise (the top
    diameter with it, in proportion), and every stump and rock moves sideways and scales. The
    defaults are the reconstruction's measured errors on 500 twin scans (docs/benchmarks-history.md,
    session 8: end points 1.7 cm median 3-D error, i.e. ~1.1 cm per axis; diameters 0.48 cm median
    absolute error, i.e. ~0.7 cm standard deviation). ``log_sigmas_m`` overrides the log
    figures per log (e.g. from the reconstruction report's fit class: a log seen only in part or
    hidden is far less certain). Copies are drawn from ``seed`` alone; a log pushed into another
    body is lifted clear of it (``max_lift_rounds``)."""

    copies: int = 0  # perturbed copies each candidate is tried on [-]; 0 = the pile as given only
    log_end_sigma_m: float = 0.011  # per axis (x, y), each log end [m]
    log_end_sigma_z_m: float = 0.011  # vertical, each log end [m]
    diameter_sigma_m: float = 0.007  # butt diameter [m]
    obstacle_sigma_m: float = 0.03  # stump / rock position, per axis (x, y) [m]
    obstacle_scale_sigma: float = 0.10  # stump / rock size, relative [-]
    log_sigmas_m: tuple[tuple[float, float], ...] | None = None  # per log: (end sigma, diameter sigma) [m]
    seed: int = 0  # [-]
    max_lift_rounds: int = 20  # rounds of lifting logs out of what they were pushed into [-]
    penetration_tolerance_m: float = 0.005  # interpenetration left as it is [m]

    def __post_init__(self) -> None:
        if not 0 <= self.copies <= 64:
            raise ValueError(f"copies must be in [0, 64], got {self.copies}")
        for name in ("log_end_sigma_m", "log_end_sigma_z_m", "diameter_sigma_m", "obstacle_sigma_m",
                     "obstacle_scale_sigma", "penetration_tolerance_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0 <= v <= 1.0):
                raise ValueError(f"{name} must be in [0, 1], got {v}")
        if self.log_sigmas_m is not None:
            for s in self.log_sigmas_m:
                if len(s) != 2 or not all(math.isfinite(v) and 0 <= v <= 1.0 for v in s):
                    raise ValueError(f"log_sigmas_m entries must be (end sigma, diameter sigma) in [0, 1] m, got {s}")
        if self.max_lift_rounds < 1:
            raise ValueError("max_lift_rounds must be >= 1")


#: Per-log uncertainty by how the reconstruction placed the log (its report's ``fit``): (end sigma
#: per axis, diameter sigma) [m]. "scan" and "partial" from the reconstruction's errors on 500 twin
#: scans (docs/benchmarks-history.md, session 8: partial logs 3.3 cm median end error, 1.57 cm median
#: diameter error); "hidden" (no scan points on the log) has no measurement: assumed.
FIT_SIGMAS_M = {"scan": (0.011, 0.007), "partial": (0.021, 0.023), "hidden": (0.03, 0.04)}


def perturbation_for_fits(fits: Sequence[str], base: PerturbationConfig | None = None,
                          end_sigmas_m: Sequence[float | None] | None = None) -> PerturbationConfig:
    """``base`` (default :class:`PerturbationConfig`) with per-log sigmas from how each log was
    placed (``FIT_SIGMAS_M``; an unknown class counts as "hidden", the least certain), and, with
    ``end_sigmas_m`` (per log: the reconstruction's own 1-sigma 3-D uncertainty of its less certain
    end [m], None where it gave none), each log's end sigma per axis at least that figure / sqrt 3
    (an end placed from an RTK float point, or pushed by the pile check, is decimetres unsure)."""
    base = base or PerturbationConfig()
    sig = [FIT_SIGMAS_M.get(f, FIT_SIGMAS_M["hidden"]) for f in fits]
    if end_sigmas_m is not None:
        if len(end_sigmas_m) != len(fits):
            raise ValueError(f"end_sigmas_m gives {len(end_sigmas_m)} logs but fits {len(fits)}")
        sig = [(max(e, min(1.0, s / math.sqrt(3.0))) if s is not None else e, d)
               for (e, d), s in zip(sig, end_sigmas_m)]
    return replace(base, log_sigmas_m=tuple(sig))


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of the smallest rotation taking unit vector ``a`` to ``b``."""
    v = np.cross(a, b)
    w = 1.0 + float(np.dot(a, b))
    if w < 1e-9:  # opposite: any perpendicular axis
        axis = np.cross(a, (1.0, 0.0, 0.0))
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, (0.0, 1.0, 0.0))
        q = np.array([*axis, 0.0])
    else:
        q = np.array([*v, w])
    return q / np.linalg.norm(q)


def _quat_mul(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    x1, y1, z1, w1 = q1
    x2, y2, z2, w2 = q2
    return np.array([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])


def _jitter_log(lg: LogSpec, rng: np.random.Generator, end_sigma: float, end_sigma_z: float,
                diameter_sigma: float) -> LogSpec:
    """``lg`` with both end centres moved by normal noise and its diameter changed (the top's in
    proportion), its axis turned with its ends and its underside kept where it was."""
    a, b = lg.endpoints_m()
    a = a + rng.normal(0.0, 1.0, 3) * (end_sigma, end_sigma, end_sigma_z)
    b = b + rng.normal(0.0, 1.0, 3) * (end_sigma, end_sigma, end_sigma_z)
    d = float(np.clip(lg.diameter_m + rng.normal(0.0, diameter_sigma), 0.04, 1.2))
    top = None if lg.top_diameter_m is None else float(np.clip(lg.top_diameter_m * d / lg.diameter_m, 0.02, d))
    new = replace(lg, diameter_m=d, top_diameter_m=top)
    axis = (b - a) / np.linalg.norm(b - a)
    q = _quat_mul(_rotation_between(lg.axis(), axis), np.asarray(lg.orientation, dtype=float))
    centre = (a + b) / 2
    centre[2] += (new.mean_diameter_m - lg.mean_diameter_m) / 2  # a thicker log's axis sits higher
    return replace(new, centre_m=tuple(float(v) for v in centre),
                   orientation=tuple(float(v) for v in q / np.linalg.norm(q)),
                   length_m=float(np.clip(np.linalg.norm(b - a), 0.3, 12.0)))


def _jitter_obstacles(pile: PileSpec, rng: np.random.Generator, sigma: float, scale_sigma: float):
    stumps = []
    for s in pile.stumps:
        dx, dy = rng.normal(0.0, sigma, 2)
        k = float(np.clip(1.0 + rng.normal(0.0, scale_sigma), 0.5, 1.5))
        top = float(np.clip(s.top_radius_m * k, 0.03, 1.0))
        stumps.append(replace(s, position_m=(s.position_m[0] + float(dx), s.position_m[1] + float(dy)),
                              height_m=float(np.clip(s.height_m * k, 0.05, 2.0)), top_radius_m=top,
                              bottom_radius_m=float(np.clip(s.bottom_radius_m * k, top, 1.0)),
                              roots=tuple(replace(r, length_m=r.length_m * k, radius_m=r.radius_m * k)
                                          for r in s.roots)))
    rocks = []
    for r in pile.rocks:
        dx, dy = rng.normal(0.0, sigma, 2)
        k = float(np.clip(1.0 + rng.normal(0.0, scale_sigma), 0.5, 1.5))
        v = np.asarray(r.vertices_m, dtype=float) * k
        # the rock's lowest point stays where it was (it rests on the ground)
        low = min(rotate(r.orientation, p)[2] for p in r.vertices_m)
        low_k = min(rotate(r.orientation, p)[2] for p in v)
        pos = (r.position_m[0] + float(dx), r.position_m[1] + float(dy), r.position_m[2] + float(low - low_k))
        rocks.append(replace(r, position_m=pos, vertices_m=tuple(tuple(float(c) for c in p) for p in v)))
    return tuple(stumps), tuple(rocks)


def _lift_out(pile: PileSpec, cfg: PerturbationConfig, physics) -> PileSpec | None:
    """Lift logs out of the bodies they were pushed into (the higher of two logs, a log out of the
    terrain or an obstacle), a few rounds in one world; None if still interpenetrating."""
    from synth.physics.world import World

    with World(pile, physics, visuals=False) as world:
        c = world.client
        names = {f"log {i}": i for i in range(pile.n_logs)}
        for _ in range(cfg.max_lift_rounds):
            bad = world.penetrations(cfg.penetration_tolerance_m)
            if not bad:
                poses = world.log_poses()
                return pile.with_logs(tuple(replace(lg, centre_m=tuple(float(v) for v in pose[:3]))
                                            for lg, pose in zip(pile.logs, poses)))
            z = world.log_poses()[:, 2]
            lift = np.zeros(pile.n_logs)
            for a, b, depth in bad:
                ia, ib = names.get(a), names.get(b)
                i = ib if ia is None else ia if ib is None else (ia if z[ia] >= z[ib] else ib)
                if i is not None:
                    lift[i] = max(lift[i], depth + cfg.penetration_tolerance_m / 2)
            for i in np.flatnonzero(lift):
                pos, orn = c.getBasePositionAndOrientation(world.log_ids[i])
                c.resetBasePositionAndOrientation(world.log_ids[i], (pos[0], pos[1], pos[2] + float(lift[i])), orn)
    return None


def perturb_pile(pile: PileSpec, cfg: PerturbationConfig, copy: int, physics=None, attempts: int = 5) -> PileSpec:
    """Perturbed copy number ``copy`` (>= 1) of ``pile`` (see :class:`PerturbationConfig`); a pure
    function of (pile, cfg, copy). Raises :class:`VerificationError` if no draw of ``attempts``
    gives a pile the twin can hold (logs off the patch, bodies that cannot be lifted apart)."""
    if copy < 1:
        raise ValueError("perturbed copies are numbered from 1 (0 is the pile as given)")
    if cfg.log_sigmas_m is not None and len(cfg.log_sigmas_m) != pile.n_logs:
        raise VerificationError(f"log_sigmas_m gives {len(cfg.log_sigmas_m)} logs but the pile has {pile.n_logs}")
    last = None
    for attempt in range(attempts):
        rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, copy, attempt]))
        logs = []
        for i, lg in enumerate(pile.logs):
            end_s, dia_s = (cfg.log_sigmas_m[i] if cfg.log_sigmas_m is not None
                            else (cfg.log_end_sigma_m, cfg.diameter_sigma_m))
            z_s = cfg.log_end_sigma_z_m * (end_s / cfg.log_end_sigma_m if cfg.log_end_sigma_m > 0 else 1.0)
            logs.append(_jitter_log(lg, rng, end_s, z_s, dia_s))
        stumps, rocks = _jitter_obstacles(pile, rng, cfg.obstacle_sigma_m, cfg.obstacle_scale_sigma)
        try:
            cand = replace(pile, logs=tuple(logs), stumps=stumps, rocks=rocks,
                           notes=(pile.notes + f" perturbed copy {copy}").strip())
        except ValueError as exc:  # a log end off the terrain patch: draw again
            last = str(exc)
            continue
        out = _lift_out(cand, cfg, physics)
        if out is not None:
            return out
        last = "bodies still interpenetrate after lifting"
    raise VerificationError(f"could not make perturbed copy {copy} of the pile in {attempts} draws ({last}); "
                            "lower the perturbation sigmas")


def check_pile(plan: "Plan", pile: PileSpec | None, physics=None) -> None:
    """:class:`VerificationError` unless ``pile`` is a pile the twin can load and holds every
    target log of ``plan``."""
    if pile is None:
        raise VerificationError("verification needs the pile the plan was made on (a synth.scene.pile.PileSpec: "
                                "in the field the reconstruction); plan with pile=... and pass it")
    if not isinstance(pile, PileSpec):
        raise VerificationError(f"verification needs a synth.scene.pile.PileSpec, got {type(pile).__name__}")
    top = max((max(g.targets) for g in plan.grasps if g.targets), default=-1)
    if top >= pile.n_logs:
        raise VerificationError(f"the plan targets log {top} but the pile has {pile.n_logs} logs: it was made on "
                                "another pile; verify on the pile the plan was made on")
    check_twin_loads(pile, physics)


def check_twin_loads(pile: PileSpec, physics=None) -> None:
    """:class:`VerificationError` unless the twin can build a world of ``pile`` (e.g. a rock
    whose vertices are flat has no hull); the message keeps the cause's first line."""
    from synth.physics.world import World

    try:
        with World(pile, physics, visuals=False):
            pass
    except Exception as exc:
        first = (str(exc).strip().splitlines() or [""])[0]
        first = first if len(first) <= 160 else first[:157] + "..."
        raise VerificationError(f"the twin cannot load the pile ({type(exc).__name__}: {first}); check the pile "
                                "file (loggrasp synth render PILE)") from exc
