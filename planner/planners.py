"""The planners an evaluation compares, as picklable specs and the functions they build.

Every planner is a function ``plan_fn(observation, pile) -> (Grasp, targets) | None`` (None = the
planner declines): the U-Net with an objective (optionally re-ranked by :mod:`planner.ranker`, or
checked by :mod:`planner.verify`), the random and geometric baselines and the oracle.
:mod:`planner.evaluate` describes each and runs them on the same piles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations
from typing import Callable, Literal

import numpy as np

from planner.inference import BALANCE_SOURCES, SIGMA_B
from planner.ranker import U_WEIGHT, check_u_weight
from planner.subsets import SubsetPolicy
from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, Grasp


PlanFn = Callable[[object, object], "tuple[Grasp, tuple[int, ...]] | None"]


@dataclass(frozen=True)
class PlannerSpec:
    """A picklable recipe for a planner function."""

    kind: Literal["unet", "random", "geometric", "oracle"]
    model: str | None = None  # checkpoint path for "unet"
    objective: Literal["f1", "f2", "f3"] = "f1"  # for "unet"
    label: str = ""
    verify_k: int = 0  # for "unet": grasps the twin tries on a perturbed copy of the pile (0 = no verification)
    verify_copies: int = 0  # ... and on this many further perturbed copies of that copy [-]
    max_subsets: int = 0  # for "unet": at most this many target subsets per plan, pre-selected by fit
    #                       (planner.subsets, "fit" mode); 0 = the default policy (every subset up to 127) [-]
    views: int = 1  # for "unet": dihedral test-time views averaged (planner.inference.Planner) [-]
    view_spread_k: float = 0.0  # ... and U lowered by this many times its spread over them [-]
    ranker: str | None = None  # for "unet": a ranker checkpoint (planner.ranker) that re-scores the plan's best
    #                            rerank_k grasps by f1 and by f3 and orders them by the objective with its p
    rerank_k: int = 4  # ... grasps re-scored per objective [-]
    ranker_u_weight: float = U_WEIGHT  # ... ordered by sigmoid(w logit U + (1 - w) logit p) with w this [-]
    sigma_b: float = SIGMA_B  # for "unet" with f3: the balance tolerance of Q (planner.inference.Objective) [cos beta]
    balance: str = "network"  # for "unet" with f3: what b is, "network" (its B map) or "hang" (planner.balance)
    precision: str = "auto"  # for "unet": the network's number format (planner.runtime.PRECISIONS)
    clear_obstacles: bool = True  # for "unet": no grasp whose claws' rectangle covers an obstacle the observation
    #                               shows (planner.constraints.Constraints.clear_obstacles; False: rows "-noclear")

    @property
    def name(self) -> str:
        if self.label:
            return self.label
        if self.kind != "unet":
            return self.kind
        how = f"-cap{self.max_subsets}" if self.max_subsets else ""
        if self.objective == "f3" and self.balance != "network":
            how += f"-{self.balance}"
        if self.objective == "f3" and self.sigma_b != SIGMA_B:
            how += f"-sb{self.sigma_b:g}"
        if self.precision != "auto":
            how += f"-{self.precision}"
        if not self.clear_obstacles:
            how += "-noclear"
        if self.views > 1:
            how += f"-views{self.views}" + (f"k{self.view_spread_k:g}" if self.view_spread_k else "")
        if self.ranker:
            how += f"-ranked{self.rerank_k}" + (f"u{self.ranker_u_weight:g}" if self.ranker_u_weight else "")
        if self.verify_k:
            copies = f"x{self.verify_copies}" if self.verify_copies else ""
            return f"unet-{self.objective}{how}-verify{self.verify_k}{copies}"
        return f"unet-{self.objective}{how}"

    def subset_policy(self) -> SubsetPolicy:
        """The subsets this row plans with."""
        return SubsetPolicy(mode="fit", max_subsets=self.max_subsets) if self.max_subsets else SubsetPolicy()


# -- planner functions ------------------------------------------------------------------------
def _target_union(instance: np.ndarray, targets) -> np.ndarray:
    return np.isin(instance, [t + 1 for t in targets])


def random_planner(seed: int = 0) -> PlanFn:
    def plan_fn(obs, pile):
        rng = np.random.default_rng([seed, int(getattr(pile, "seed", 0) or 0)])
        n = obs.n_logs
        targets = tuple(sorted(rng.choice(n, size=int(rng.integers(1, n + 1)), replace=False).tolist()))
        mask = _target_union(obs.instance, targets)
        if not mask.any():
            return None
        rows, cols = np.nonzero(mask)
        i = int(rng.integers(len(rows)))
        x, y = obs.grid.pixel_to_pile(rows[i], cols[i])
        return Grasp(float(x), float(y), float(rng.uniform(-math.pi / 2, math.pi / 2)),
                     float(rng.uniform(MIN_WIDTH_M, MAX_WIDTH_M))), targets
    return plan_fn


def geometric_planner(max_subset: int = 7, margin_m: float = 0.12, claw_m: float = 0.12) -> PlanFn:
    """Rule-based, image-only: log axes from the masks (PCA), grasp across the subset's mean axis
    at the union's centroid, as narrow as the union allows plus a margin; the claws' landing
    strips must show only ground or targets. Prefers more logs, then narrower grasps."""

    def axis_of(mask_xy: np.ndarray) -> np.ndarray:
        c = mask_xy - mask_xy.mean(axis=0)
        w, v = np.linalg.eigh(c.T @ c)
        a = v[:, -1]
        return a if a[0] >= 0 else -a

    def plan_fn(obs, pile):
        X, Y = obs.grid.pixel_centres()
        inst = obs.instance
        logs = [i for i in range(obs.n_logs) if (inst == i + 1).sum() >= 5]
        axes = {i: axis_of(np.stack([X[inst == i + 1], Y[inst == i + 1]], 1)) for i in logs}
        best = None
        for k in range(min(max_subset, len(logs)), 0, -1):
            for subset in combinations(logs, k):
                m = _target_union(inst, subset)
                pts = np.stack([X[m], Y[m]], 1)
                # mean axis (sign-aligned), grasp closes perpendicular to it
                a = np.sum([axes[i] * np.sign(axes[i] @ axes[subset[0]] or 1) for i in subset], axis=0)
                a /= np.linalg.norm(a) + 1e-12
                closing = np.array([-a[1], a[0]])
                centre = pts.mean(axis=0)
                across = (pts - centre) @ closing
                along = (pts - centre) @ a
                # grasp at the subset's middle along the axis, where all targets overlap
                width = float(across.max() - across.min()) + 2 * margin_m
                if width > MAX_WIDTH_M:
                    continue
                width = max(width, MIN_WIDTH_M)
                mid = centre + closing * (across.max() + across.min()) / 2 + a * float(np.median(along)) * 0.0
                # claw landing strips: beyond each side, claw_m deep, 0.3 m long along the axis
                ok = True
                for side in (-1, 1):
                    p = mid + closing * side * (width / 2 + claw_m / 2)
                    sel = (np.abs((X - p[0]) * closing[0] + (Y - p[1]) * closing[1]) < claw_m / 2) & \
                          (np.abs((X - p[0]) * a[0] + (Y - p[1]) * a[1]) < 0.15)
                    seen = set(np.unique(inst[sel]).tolist()) - {0} - {t + 1 for t in subset}
                    if seen:
                        ok = False
                        break
                if not ok:
                    continue
                phi = math.atan2(closing[1], closing[0])
                cand = (k, -width, Grasp(float(mid[0]), float(mid[1]), phi, float(width)), tuple(subset))
                if best is None or cand[:2] > best[:2]:
                    best = cand
            if best is not None:
                return best[2], best[3]
        return None
    return plan_fn


def oracle_planner(trial_preset: str = "fast", max_trials: int = 40) -> PlanFn:
    """Ground-truth candidates verified in simulation: largest subsets first, the first subset with a
    successful candidate wins (best balance among its successes). An upper bound, not a planner."""
    from synth.data.candidates import generate_candidates
    from synth.physics.trial import TrialConfig, run_trial

    cfg = TrialConfig.preset(trial_preset)

    def plan_fn(obs, pile):
        n = pile.n_logs
        budget = max_trials
        for k in range(n, 0, -1):
            successes = []
            for subset in combinations(range(n), k):
                cands = sorted(generate_candidates(pile, subset), key=lambda g: g.width_m)[:3]
                for g in cands:
                    if budget <= 0:
                        break
                    budget -= 1
                    r = run_trial(pile, g, subset, cfg)
                    if r.success:
                        successes.append((r.cos_beta, g, subset))
                        break
            if successes:
                _, g, subset = max(successes, key=lambda s: s[0])
                return g, tuple(subset)
            if budget <= 0:
                return None
        return None
    return plan_fn


def unet_planner(model: str, objective: str, subsets: SubsetPolicy = SubsetPolicy(), views: int = 1,
                 view_spread_k: float = 0.0, ranker: str | None = None, rerank_k: int = 4,
                 ranker_u_weight: float = U_WEIGHT, sigma_b: float = SIGMA_B, balance: str = "network",
                 precision: str = "auto", clear_obstacles: bool = True, constraints=None) -> PlanFn:
    """The network's best grasp among the subsets ``subsets`` keeps (default: every subset), its maps
    averaged over ``views`` dihedral test-time views, re-ranked by ``ranker`` when given; f3 with the
    balance tolerance ``sigma_b`` and the ``balance`` source; the network in ``precision``; with
    ``clear_obstacles``, no grasp on an obstacle the observation shows. ``constraints`` (a
    :class:`planner.constraints.Constraints`), when given, replaces ``Constraints(clear_obstacles=...)``."""
    plan_all = _unet_plan_all(model, objective, subsets, views, view_spread_k, ranker, rerank_k, keep=1,
                              ranker_u_weight=ranker_u_weight, sigma_b=sigma_b, balance=balance, precision=precision,
                              clear_obstacles=clear_obstacles, constraints=constraints)

    def plan_fn(obs, pile):
        result = plan_all(obs, pile)
        if result.best is None:
            return None
        return result.best.grasp, tuple(result.best.targets)
    return plan_fn


def _unet_plan_all(model: str, objective: str, subsets: SubsetPolicy, views: int, view_spread_k: float,
                   ranker: str | None, rerank_k: int, keep: int | None = None,
                   ranker_u_weight: float = U_WEIGHT, sigma_b: float = SIGMA_B,
                   balance: str = "network", precision: str = "auto", clear_obstacles: bool = True,
                   constraints=None) -> Callable[[object, object], object]:
    """``(obs, pile) -> Plan`` of every subset, best first (re-ranked by ``ranker`` when given), its
    best ``keep`` only when given (all of them go to the ranker)."""
    import torch

    from planner.constraints import Constraints
    from planner.inference import Objective, load_planner
    from planner.ranker import load_ranker, plan_reranked

    torch.set_num_threads(1)
    net = load_planner(model, precision=precision, views=views, view_spread_k=view_spread_k)
    obj = Objective(kind=objective, sigma_b=sigma_b, balance=balance)
    rk = load_ranker(ranker) if ranker else None
    constraints = Constraints(clear_obstacles=clear_obstacles) if constraints is None else constraints

    def plan_all(obs, pile):
        return plan_reranked(obs, net, obj, rk, constraints, top_k=keep,
                             rerank_k=rerank_k, u_weight=ranker_u_weight, pile=pile, subsets=subsets)
    return plan_all


def verified_planner(plan_all: Callable[[object, object], object], objective: str, k: int, copies: int = 0,
                     trial_preset: str = "fast", trial_fn=None, sigma_b: float = SIGMA_B,
                     balance: str = "network") -> PlanFn:
    """``plan_all(obs, pile) -> planner.inference.Plan`` (every subset's best grasp) checked by the
    verifier: its ``k`` best grasps are tried on a perturbed copy of the test pile (copy 1 of
    :func:`planner.pile_copies.perturb_pile` with the default sigmas, seeded by the pile's seed) and, with
    ``copies``, on that many perturbed copies of it; the chosen grasp, or None (declined) when none
    succeeded. Sequential and without a time budget, so that the evaluation is repeatable.
    ``trial_fn``: the twin trial (default :func:`synth.physics.trial.run_trial`)."""
    from planner.inference import Objective
    from planner.pile_copies import PerturbationConfig, perturb_pile
    from planner.verify import Verifier, VerifyConfig
    from synth.physics.trial import TrialConfig

    obj = Objective(kind=objective, sigma_b=sigma_b, balance=balance)
    trial = TrialConfig.preset(trial_preset)

    def plan_fn(obs, pile):
        result = plan_all(obs, pile)
        if not result.grasps:
            return None
        seed = int(pile.seed or 0)
        stand_in = perturb_pile(pile, PerturbationConfig(seed=2 * seed), 1, trial.physics)  # never the pile itself
        cfg = VerifyConfig(k=k, workers=1, time_budget_s=None, trial=trial,
                           perturbation=PerturbationConfig(copies=copies, seed=2 * seed + 1))
        v = Verifier(cfg, trial_fn).verify(result, stand_in, obj)
        return None if v.grasp is None else (v.grasp.grasp, tuple(v.grasp.targets))
    return plan_fn


def verified_unet_planner(model: str, objective: str, k: int, copies: int = 0, trial_preset: str = "fast",
                          subsets: SubsetPolicy = SubsetPolicy(), views: int = 1,
                          view_spread_k: float = 0.0, ranker: str | None = None, rerank_k: int = 4,
                          ranker_u_weight: float = U_WEIGHT, sigma_b: float = SIGMA_B,
                          balance: str = "network", precision: str = "auto", clear_obstacles: bool = True) -> PlanFn:
    plan_all = _unet_plan_all(model, objective, subsets, views, view_spread_k, ranker, rerank_k,
                              ranker_u_weight=ranker_u_weight, sigma_b=sigma_b, balance=balance, precision=precision,
                              clear_obstacles=clear_obstacles)
    return verified_planner(plan_all, objective, k, copies, trial_preset, sigma_b=sigma_b,
                            balance=balance)  # the plan's best k, in its order


_CACHE: dict[PlannerSpec, PlanFn] = {}


def build_planner(spec: PlannerSpec, trial_preset: str = "fast", oracle_max_trials: int = 40) -> PlanFn:
    if spec not in _CACHE:
        if spec.kind == "unet":
            if not spec.model:
                raise ValueError("a 'unet' planner needs a model checkpoint")
            if spec.verify_k < 0 or spec.verify_copies < 0 or spec.max_subsets < 0:
                raise ValueError(f"verify_k, verify_copies and max_subsets must be >= 0, got {spec.verify_k}, "
                                 f"{spec.verify_copies}, {spec.max_subsets}")
            from planner.inference import check_views

            check_views(spec.views, spec.view_spread_k)
            if spec.rerank_k < 1:
                raise ValueError(f"rerank_k must be >= 1, got {spec.rerank_k}")
            check_u_weight(spec.ranker_u_weight)
            if not spec.sigma_b > 0:
                raise ValueError(f"sigma_b (f3's balance tolerance) must be > 0, got {spec.sigma_b}")
            if spec.balance not in BALANCE_SOURCES:
                raise ValueError(f"balance must be one of {BALANCE_SOURCES}, got {spec.balance!r}")
            views = dict(views=spec.views, view_spread_k=spec.view_spread_k, ranker=spec.ranker,
                         rerank_k=spec.rerank_k, ranker_u_weight=spec.ranker_u_weight, sigma_b=spec.sigma_b,
                         balance=spec.balance, precision=spec.precision, clear_obstacles=spec.clear_obstacles)
            _CACHE[spec] = (verified_unet_planner(spec.model, spec.objective, spec.verify_k, spec.verify_copies,
                                                  trial_preset, spec.subset_policy(), **views) if spec.verify_k
                            else unet_planner(spec.model, spec.objective, spec.subset_policy(), **views))
        elif spec.kind == "random":
            _CACHE[spec] = random_planner()
        elif spec.kind == "geometric":
            _CACHE[spec] = geometric_planner()
        elif spec.kind == "oracle":
            _CACHE[spec] = oracle_planner(trial_preset, oracle_max_trials)
        else:
            raise ValueError(f"unknown planner kind {spec.kind!r}: use unet, random, geometric or oracle")
    return _CACHE[spec]
