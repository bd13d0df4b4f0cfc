"""Verified planning: the twin tries the network's best grasps on the pile before one is chosen.

A :class:`planner.inference.Plan` ranks the best grasp of every target subset by the network's
quality ``q = f(u, tau, b)``. :func:`verify_plan` (or a reusable :class:`Verifier`, which keeps its
worker processes between plans) takes the ``k`` best of them that are worth trying (distinct
subsets or positions, :func:`select_candidates`), runs each as a twin trial on the pile the plan was
made on (:func:`synth.physics.trial.run_trial`, the same trial code as data generation and evaluation) and
chooses, among those whose trial succeeded, the best by the objective computed from what the trial
*measured* (:func:`measured_quality`: the logs actually held for tau, the measured cos beta, rounded
to ``BALANCE_STEP``, for b, u = 1). In the field that pile is the reconstruction; its errors are
what the optional perturbed copies (:class:`PerturbationConfig`, :func:`perturb_pile`) are for:
each candidate whose trial on the pile as given succeeded is tried on the same few jittered copies
too, and the grasp that succeeds most often wins (then the measured objective, then the network's
rank: :func:`choose`).

Guarantees:

* **Deterministic.** Trials are history-free and the copies are drawn from ``PerturbationConfig.seed``
  in the calling process, so the same inputs give the same choice with any number of workers
  (without a time budget that runs out).
* **Never an unchecked grasp.** Only a candidate whose trials all ran can be chosen. With
  ``prune`` a candidate is skipped when even a perfect trial could not beat the grasp already
  verified (the choice is the same as trying everything); with a time budget no trial starts after
  the deadline (those running finish), and the result says which candidates were checked.
* **A typed refusal.** When no checked grasp succeeded :class:`Verification` has ``chosen=None``
  and says why (every candidate's outcome class); :meth:`Verification.require` turns that into
  :class:`NoVerifiedGrasp`.

Trials run in-process with one worker, else in a process pool (``spawn``, each worker ends with its
parent, :func:`synth.common.processes.exit_with_parent`).
"""

from __future__ import annotations

import heapq
import json
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from planner.errors import VerificationError
from planner.pile_copies import PerturbationConfig, check_pile, perturb_pile
from planner.inference import Objective, Plan, PlannedGrasp
from synth.common.formats import VersionedJson
from synth.geometry.grasp import Grasp
from synth.scene.pile import PileSpec
from synth.physics.trial import TrialConfig, TrialResult, run_trial

log = logging.getLogger(__name__)

VERIFY_FORMAT = "loggrasp.verification"
VERIFY_VERSION = "1.0"

#: ``trial_fn(pile, grasp, targets, trial_config) -> TrialResult``: the twin trial (``run_trial``)
#: or a stand-in with the same contract (tests). Must be picklable (a module-level function) for
#: more than one worker.
TrialFn = Callable[[PileSpec, Grasp, tuple, TrialConfig], TrialResult]

TRIAL_ERROR = "trial_error"  # outcome class of a trial whose simulation raised


VERIFICATION = VersionedJson(VERIFY_FORMAT, VERIFY_VERSION, "verification", VerificationError)


class VerificationBudgetError(VerificationError):
    """The time budget ran out before one candidate was checked; ``verification`` holds the trials
    that did run."""

    def __init__(self, verification: "Verification") -> None:
        budget = verification.config.time_budget_s
        super().__init__(f"the time budget of {budget:g} s ran out before any candidate was checked (a trial "
                         f"on every pile copy it needs); give a larger budget, fewer perturbed copies or more workers")
        self.verification = verification


class NoVerifiedGrasp(VerificationError):
    """No checked grasp succeeded in the twin; ``verification`` says what each one did."""

    def __init__(self, verification: "Verification") -> None:
        super().__init__(verification.reason)
        self.verification = verification


# -- configuration ------------------------------------------------------------------------------
@dataclass(frozen=True)
class VerifyConfig:
    """How many grasps the twin tries, for how long, on how many cores."""

    k: int = 8  # candidates tried at most [-] (the plan's best, distinct subsets or positions)
    time_budget_s: float | None = 10.0  # wall time for the trials [s]; None = no limit. No trial
    # starts after it; the ones running finish (a forwarder's grasp cycle is 10-20 s). Loading the
    # pile and making its perturbed copies (~0.1 s each) come before it
    workers: int = 0  # processes; 0 = all cores, 1 = in this process [-]
    trial: TrialConfig = field(default_factory=TrialConfig.fast)  # the twin trial's settings
    perturbation: PerturbationConfig = field(default_factory=PerturbationConfig)
    prune: bool = True  # skip a candidate that cannot beat the grasp already verified (same choice)
    min_separation_m: float = 0.05  # a candidate with the same targets as a better one is tried only if
    min_separation_rad: float = 0.09  # it lies this far from it, or turned this far (~5 deg) [m, rad]
    min_trial_s: float = 0.2  # the shortest a twin trial takes on one core (a one-log pile, fast preset);
    # a budget below it could never check anything [s]

    def __post_init__(self) -> None:
        if isinstance(self.k, bool) or not isinstance(self.k, (int, np.integer)) or self.k < 1:
            raise ValueError(f"k (grasps the twin tries) must be a whole number >= 1, got {self.k!r}")
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0 (0 = all cores), got {self.workers}")
        if not self.min_trial_s > 0:
            raise ValueError("min_trial_s must be > 0")
        if self.time_budget_s is not None and not self.time_budget_s >= self.min_trial_s:
            raise ValueError(f"time_budget_s {self.time_budget_s} s is too small for one twin trial (at least "
                             f"{self.min_trial_s} s); give more time or None for no limit")
        if self.min_separation_m < 0 or self.min_separation_rad < 0:
            raise ValueError("min_separation_m and min_separation_rad must be >= 0")

    def n_workers(self) -> int:
        return self.workers or os.cpu_count() or 1


# -- results ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TwinTrial:
    """One twin trial of a candidate: on the pile as given (``copy`` 0) or on perturbed copy ``copy``."""

    copy: int
    result: TrialResult | None  # None when the simulation raised
    error: str | None = None  # what it raised

    @property
    def outcome(self) -> str:
        return TRIAL_ERROR if self.result is None else self.result.outcome.value

    @property
    def success(self) -> bool:
        return self.result is not None and self.result.success

    def to_dict(self) -> dict:
        return {"copy": self.copy, "outcome": self.outcome, "error": self.error,
                "trial": None if self.result is None else self.result.to_dict()}


CHECKED, NOT_CHECKED, PRUNED = "checked", "not_checked", "pruned"


@dataclass(frozen=True)
class CandidateCheck:
    """One candidate grasp and what the twin made of it."""

    rank: int  # index in the plan (0 = the network's best)
    planned: PlannedGrasp
    trials: tuple[TwinTrial, ...]  # in copy order; copy 0 (the pile as given) first
    status: str  # "checked": every trial it needed ran; "not_checked": the time budget ran out first
    # (trials listed ran, but not all); "pruned": skipped, it could not beat the grasp verified
    copies: int = 0  # perturbed copies it was to be tried on [-]

    @property
    def checked(self) -> bool:
        return self.status == CHECKED

    @property
    def nominal(self) -> TwinTrial | None:
        """Its trial on the pile as given, if it ran."""
        return next((t for t in self.trials if t.copy == 0), None)

    @property
    def outcome(self) -> str:
        """Outcome class on the pile as given (``synth.physics.trial.Outcome`` value, ``trial_error``), or
        the status when that trial did not run."""
        t = self.nominal
        return self.status if t is None else t.outcome

    @property
    def verified(self) -> bool:
        """Checked, and its trial on the pile as given succeeded."""
        return self.checked and self.nominal is not None and self.nominal.success

    @property
    def successes(self) -> int:
        return sum(t.success for t in self.trials)

    @property
    def held(self) -> tuple[int, ...]:
        t = self.nominal
        return () if t is None or t.result is None else tuple(t.result.grasped)

    @property
    def cos_beta(self) -> float:
        t = self.nominal
        return math.nan if t is None or t.result is None else float(t.result.cos_beta)

    def to_dict(self) -> dict:
        return {"rank": self.rank, "targets": list(self.planned.targets), "grasp": self.planned.grasp.to_dict(),
                "quality": self.planned.quality, "status": self.status, "outcome": self.outcome,
                "held": list(self.held), "cos_beta": self.cos_beta, "successes": self.successes,
                "copies": self.copies, "trials": [t.to_dict() for t in self.trials]}


@dataclass(frozen=True)
class Verification:
    """The verifier's answer: the chosen candidate (or None) and every candidate it considered."""

    chosen: CandidateCheck | None
    candidates: tuple[CandidateCheck, ...]  # in plan order
    objective: Objective
    config: VerifyConfig
    timed_out: bool  # the time budget ran out before every candidate was checked or pruned
    elapsed_s: float  # wall time of the verification [s]
    trial_cpu_s: float  # CPU time of all its trials (summed over workers) [s]
    chosen_quality: float = math.nan  # the chosen one's measured objective [-]

    @property
    def ok(self) -> bool:
        return self.chosen is not None

    @property
    def grasp(self) -> PlannedGrasp | None:
        return None if self.chosen is None else self.chosen.planned

    @property
    def checked(self) -> tuple[CandidateCheck, ...]:
        return tuple(c for c in self.candidates if c.checked)

    @property
    def reason(self) -> str:
        """One sentence: what was chosen, or why nothing was."""
        n, m = len(self.candidates), len(self.checked)
        if self.chosen is not None:
            c = self.chosen
            extra = (f", {c.successes} of {c.copies + 1} piles" if c.copies else "")
            return (f"verified: plan rank {c.rank + 1} (logs {list(c.planned.targets)}) succeeded in the twin{extra}, "
                    f"held {len(c.held)} logs, cos beta {c.cos_beta:.3f}; {m} of {n} candidates checked"
                    + (" before the time budget ran out" if self.timed_out else ""))
        parts = [f"#{c.rank + 1} {list(c.planned.targets)}: {c.outcome if c.checked else c.status}"
                 for c in self.candidates]
        if not self.candidates:
            return "the plan has no grasp to verify: do not send"
        head = ("no checked grasp succeeded in the twin" if m else "no candidate could be checked")
        tail = (f"; the time budget of {self.config.time_budget_s:g} s ran out after {m} of {n}"
                if self.timed_out else "")
        return f"{head} ({'; '.join(parts)}){tail}: do not send unless the operator chooses a grasp"

    def require(self) -> PlannedGrasp:
        """The chosen grasp; :class:`NoVerifiedGrasp` when there is none."""
        if self.chosen is None:
            raise NoVerifiedGrasp(self)
        return self.chosen.planned

    def to_dict(self) -> dict:
        return {"format": VERIFY_FORMAT, "format_version": VERIFY_VERSION, "ok": self.ok,
                "chosen_rank": None if self.chosen is None else self.chosen.rank,
                "chosen_quality": self.chosen_quality, "reason": self.reason, "timed_out": self.timed_out,
                "objective": self.objective.kind, "k": self.config.k, "copies": self.config.perturbation.copies,
                "log_sigmas_m": (None if self.config.perturbation.log_sigmas_m is None
                                 else [list(s) for s in self.config.perturbation.log_sigmas_m]),
                "time_budget_s": self.config.time_budget_s, "elapsed_s": self.elapsed_s,
                "trial_cpu_s": self.trial_cpu_s, "candidates": [c.to_dict() for c in self.candidates]}


# -- selection (pure) ---------------------------------------------------------------------------
def select_candidates(plan: Plan, k: int, min_separation_m: float = 0.05,
                      min_separation_rad: float = 0.09) -> list[tuple[int, PlannedGrasp]]:
    """The ``k`` best grasps of ``plan`` by its objective, worth trying: ``(rank, grasp)`` with
    ``rank`` the index in ``plan.grasps``. A grasp is skipped when a better one with the same
    targets lies within ``min_separation_m`` and ``min_separation_rad`` of it (the same trial twice);
    grasps of different subsets are always distinct (the twin judges them against other targets)."""
    order = sorted(range(len(plan.grasps)), key=lambda i: (-plan.grasps[i].quality, i))
    chosen: list[tuple[int, PlannedGrasp]] = []
    for i in order:
        g = plan.grasps[i]
        dup = False
        for _, h in chosen:
            if tuple(sorted(h.targets)) != tuple(sorted(g.targets)):
                continue
            d = math.hypot(g.grasp.x_m - h.grasp.x_m, g.grasp.y_m - h.grasp.y_m)
            a = abs((g.grasp.phi_rad - h.grasp.phi_rad + math.pi / 2) % math.pi - math.pi / 2)
            if d < min_separation_m and a < min_separation_rad:
                dup = True
                break
        if not dup:
            chosen.append((i, g))
        if len(chosen) == k:
            break
    return chosen


#: Measured cos beta is rounded to this before it is scored [-]: the twin's balance differs by less
#: between trials of the same load (f3's factor changes by < 0.2 % for 0.01 at sigma_b = 0.25), and a
#: candidate can then be skipped once one with as many logs balanced as well is verified.
BALANCE_STEP = 0.01


def measured_quality(objective: Objective, trial: TrialResult, balance_step: float = BALANCE_STEP) -> float:
    """The objective from what a successful trial measured: ``f(1, logs held, cos beta)`` with cos
    beta rounded to ``balance_step``; 0 for a failed one (u = 0)."""
    if not trial.success:
        return 0.0
    b = trial.cos_beta if math.isfinite(trial.cos_beta) else objective.b_opt
    if balance_step > 0:
        b = round(b / balance_step) * balance_step
    return float(objective.quality(1.0, float(len(trial.grasped)), float(b)))


def _key(c: CandidateCheck, objective: Objective) -> tuple:
    q = measured_quality(objective, c.nominal.result) if c.nominal is not None and c.nominal.result else 0.0
    return (c.successes, q, -c.rank)


def _upper_key(rank: int, planned: PlannedGrasp, copies: int, objective: Objective,
               nominal: TrialResult | None = None, successes: int = 0, left: int | None = None) -> tuple:
    """The best key candidate ``rank`` could still reach: every trial left a success and, before its
    trial on the pile as given, the targets held at the best balance."""
    if nominal is None:
        q = float(objective.quality(1.0, float(len(planned.targets)), objective.b_opt))
        return (copies + 1, q, -rank)
    return (successes + (copies if left is None else left), measured_quality(objective, nominal), -rank)


def choose(candidates: Sequence[CandidateCheck], objective: Objective) -> CandidateCheck | None:
    """Among the checked candidates whose trial on the pile as given succeeded: the one that
    succeeded on most piles (with perturbed copies), then the best measured objective
    (:func:`measured_quality` of that trial), then the network's rank. None when there is none."""
    ok = [c for c in candidates if c.verified]
    return max(ok, key=lambda c: _key(c, objective)) if ok else None


# -- running trials -----------------------------------------------------------------------------
def _run_one(trial_fn: TrialFn, pile: PileSpec, grasp: Grasp, targets: tuple, cfg: TrialConfig) -> TwinTrial:
    """One trial in a worker; a simulation that raises becomes a ``trial_error`` with its cause."""
    try:
        return TwinTrial(0, trial_fn(pile, grasp, targets, cfg))
    except Exception as exc:  # recorded with its cause, logged by the caller
        return TwinTrial(0, None, f"{type(exc).__name__}: {exc}")


class _Run:
    """One verification's trials, run as the schedule says until it is done or the deadline
    passes (then ``timed_out`` if trials were left); each finished trial is recorded in the
    schedule and its CPU time summed."""

    def __init__(self, trial_fn: TrialFn, cands: list[tuple[int, PlannedGrasp]], piles: list[PileSpec],
                 sched: "_Schedule", trial: TrialConfig, deadline: float) -> None:
        self.trial_fn, self.cands, self.piles, self.sched, self.trial = trial_fn, cands, piles, sched, trial
        self.deadline = deadline
        self.cpu_s = 0.0
        self.timed_out = False

    def _next(self) -> tuple[int, int] | None:
        """The next (candidate, copy) to try; None when none is left or the deadline has passed."""
        if time.perf_counter() >= self.deadline:
            self.timed_out = self.sched.has_work()
            return None
        return self.sched.next()

    def _args(self, task: tuple[int, int]) -> tuple:
        j, c = task
        pg = self.cands[j][1]
        return self.trial_fn, self.piles[c], pg.grasp, tuple(pg.targets), self.trial

    def _take(self, task: tuple[int, int], trial: TwinTrial) -> None:
        j, c = task
        trial = replace(trial, copy=c)
        if trial.error is not None:
            rank, pg = self.cands[j]
            log.warning("twin trial of plan rank %d (logs %s) on pile copy %d raised: %s",
                        rank + 1, list(pg.targets), c, trial.error)
        elif trial.result is not None:
            self.cpu_s += float(trial.result.cpu_time_s)
        self.sched.record(j, c, trial)

    def serial(self) -> None:
        while (task := self._next()) is not None:
            self._take(task, _run_one(*self._args(task)))

    def pooled(self, pool, workers: int) -> None:
        """Up to ``workers`` trials in flight in ``pool``; a new one starts as one finishes."""
        from concurrent.futures import FIRST_COMPLETED, wait

        inflight: dict = {}
        while True:
            while not self.timed_out and len(inflight) < workers and (task := self._next()) is not None:
                inflight[pool.submit(_run_one, *self._args(task))] = task
            if not inflight:  # nothing running and nothing (more) to start
                return
            done, _ = wait(list(inflight), return_when=FIRST_COMPLETED)
            for f in done:
                task = inflight.pop(f)
                try:
                    trial = f.result()
                except Exception as exc:  # the worker process died (not the trial: _run_one catches that)
                    raise VerificationError(f"a twin worker process failed ({type(exc).__name__}: {exc}); "
                                            "run with workers=1 to see the cause") from exc
                self._take(task, trial)


class _Schedule:
    """Which trial to run next: candidates in plan order, each first on the pile as given and, if
    that succeeded, on its perturbed copies; with ``prune``, a candidate whose best reachable key
    (:func:`_upper_key`) does not beat the best verified one is skipped."""

    def __init__(self, cands: list[tuple[int, PlannedGrasp]], copies: int, objective: Objective, prune: bool):
        self.cands, self.copies, self.objective, self.prune = cands, copies, objective, prune
        self.heap: list[tuple[int, int]] = [(j, 0) for j in range(len(cands))]  # (candidate, copy), sorted
        self.trials: list[dict[int, TwinTrial]] = [{} for _ in cands]
        self.pruned: set[int] = set()
        self.best: tuple | None = None  # key of the best verified candidate so far

    def _complete(self, j: int) -> bool:
        t = self.trials[j]
        return 0 in t and (not t[0].success or len(t) == self.copies + 1)

    def _prunable(self, j: int) -> bool:
        if not self.prune or self.best is None:
            return False
        rank, planned = self.cands[j]
        t = self.trials[j]
        if 0 not in t:
            bound = _upper_key(rank, planned, self.copies, self.objective)
        else:
            left = self.copies - sum(1 for c in t if c > 0)
            bound = _upper_key(rank, planned, self.copies, self.objective, t[0].result,
                               sum(x.success for x in t.values()), left)
        return self.best >= bound

    def next(self) -> tuple[int, int] | None:
        """The next trial to run, or None when nothing is left to try."""
        while self.heap:
            j, c = heapq.heappop(self.heap)
            if j in self.pruned:
                continue
            if self._prunable(j):
                self.pruned.add(j)
                continue
            return j, c
        return None

    def settle(self) -> None:
        """Mark every candidate left that cannot beat the best verified one as pruned (the rest stay
        not checked): for a verification stopped by its time budget."""
        for j, _ in self.heap:
            if j not in self.pruned and self._prunable(j):
                self.pruned.add(j)

    def has_work(self) -> bool:
        """Whether a trial is still worth running (without taking it)."""
        return any(j not in self.pruned and not self._prunable(j) for j, _ in self.heap)

    def record(self, j: int, c: int, trial: TwinTrial) -> None:
        self.trials[j][c] = trial
        if c == 0 and trial.success:
            for cc in range(1, self.copies + 1):
                heapq.heappush(self.heap, (j, cc))
        if self._complete(j) and self.trials[j][0].success:
            rank, _ = self.cands[j]
            key = (sum(x.success for x in self.trials[j].values()),
                   measured_quality(self.objective, self.trials[j][0].result), -rank)
            if self.best is None or key > self.best:
                self.best = key

    def checks(self) -> list[CandidateCheck]:
        out = []
        for j, (rank, planned) in enumerate(self.cands):
            t = tuple(self.trials[j][c] for c in sorted(self.trials[j]))
            status = CHECKED if self._complete(j) else PRUNED if j in self.pruned else NOT_CHECKED
            out.append(CandidateCheck(rank, planned, t, status, self.copies))
        return out


class Verifier:
    """Verified planning with worker processes kept between plans. Use as a context manager
    (``close`` is safe twice); :meth:`verify` is the verification of one plan."""

    def __init__(self, config: VerifyConfig | None = None, trial_fn: TrialFn | None = None) -> None:
        """``trial_fn``: the twin trial, :func:`synth.physics.trial.run_trial` when None."""
        self.config = config or VerifyConfig()
        self.trial_fn = trial_fn or run_trial
        self._pool = None

    def _executor(self):
        if self._pool is None:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            from synth.common.processes import exit_with_parent

            self._pool = ProcessPoolExecutor(max_workers=self.config.n_workers(), mp_context=mp.get_context("spawn"),
                                             initializer=exit_with_parent)
        return self._pool

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __enter__(self) -> "Verifier":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def piles(self, pile: PileSpec) -> list[PileSpec]:
        """The pile as given, then its perturbed copies (:func:`perturb_pile`)."""
        pc = self.config.perturbation
        return [pile] + [perturb_pile(pile, pc, c, self.config.trial.physics) for c in range(1, pc.copies + 1)]

    def verify(self, plan: Plan, pile: PileSpec | None, objective: Objective,
               piles: Sequence[PileSpec] | None = None) -> Verification:
        """Try the plan's best grasps on ``pile`` (the pile the plan was made on) and choose one; see
        the module docstring. ``objective``: the plan's (it ranks the candidates and scores what the
        trials measured). ``piles``: the pile and its perturbed copies when made already
        (:meth:`piles`). Raises :class:`VerificationError` for unusable input."""
        cfg = self.config
        t0 = time.perf_counter()
        if not isinstance(plan, Plan):
            raise VerificationError(f"verification needs a planner.inference.Plan, got {type(plan).__name__}")
        check_pile(plan, pile, cfg.trial.physics)
        cands = select_candidates(plan, cfg.k, cfg.min_separation_m, cfg.min_separation_rad)
        piles = list(piles) if piles is not None else self.piles(pile)
        if len(piles) != cfg.perturbation.copies + 1:
            raise VerificationError(f"got {len(piles)} piles for {cfg.perturbation.copies} perturbed copies")
        # the budget is the trials' (loading the pile and making its copies come before it)
        deadline = math.inf if cfg.time_budget_s is None else time.perf_counter() + cfg.time_budget_s
        sched = _Schedule(cands, cfg.perturbation.copies, objective, cfg.prune)
        run = _Run(self.trial_fn, cands, piles, sched, cfg.trial, deadline)
        workers = min(cfg.n_workers(), max(1, len(cands) * (cfg.perturbation.copies + 1)))
        if workers == 1:
            run.serial()
        else:
            run.pooled(self._executor(), workers)
        cpu, timed_out = run.cpu_s, run.timed_out
        sched.settle()
        checks = sched.checks()
        chosen = choose(checks, objective)
        q = math.nan if chosen is None else measured_quality(objective, chosen.nominal.result)
        result = Verification(chosen, tuple(checks), objective, cfg, timed_out, time.perf_counter() - t0, cpu, q)
        if timed_out and not result.checked:
            raise VerificationBudgetError(result)
        return result


def read_verification(path) -> dict:
    """A verification as written from :meth:`Verification.to_dict` (e.g. a trial record's
    ``plan/verification.json``); format and major version checked."""
    return VERIFICATION.read(path)


_TIMES = ("wall_time_s", "cpu_time_s")  # what differs from run to run in a trial's record


def trial_differences(recorded: dict, replayed: dict) -> list[str]:
    """Every trial of the ``recorded`` verification (:meth:`Verification.to_dict`) that the
    ``replayed`` one does not reproduce bit for bit (all fields but the wall and CPU times), named
    ``"rank R copy C: why"``; ``[]`` when each is identical. The replay may have checked more
    candidates (e.g. without the time budget the record ran under)."""

    def trials(v: dict) -> dict:
        out = {}
        for c in v.get("candidates", []):
            for t in c.get("trials", []):
                d = dict(t)
                if d.get("trial") is not None:
                    d["trial"] = {k: x for k, x in d["trial"].items() if k not in _TIMES}
                out[(c["rank"], t["copy"])] = json.dumps(d, sort_keys=True)
        return out

    old, new = trials(recorded), trials(json.loads(json.dumps(replayed)))
    diffs = []
    for key in sorted(old):
        if key not in new:
            diffs.append(f"rank {key[0] + 1} copy {key[1]}: not run again")
        elif new[key] != old[key]:
            diffs.append(f"rank {key[0] + 1} copy {key[1]}: another result")
    return diffs


def verify_plan(plan: Plan, pile: PileSpec | None, objective: Objective, config: VerifyConfig | None = None,
                trial_fn: TrialFn | None = None) -> Verification:
    """One verification (:meth:`Verifier.verify`) with its own workers, closed afterwards."""
    with Verifier(config, trial_fn) as v:
        return v.verify(plan, pile, objective)
