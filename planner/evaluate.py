"""Evaluation in the twin, the paper's protocol: fresh piles, one grasp per pile, tried in physics.

Every planner is a *function* ``plan_fn(observation, pile) -> (Grasp, targets) | None`` (None =
the planner declines), so the U-Net (any objective), the baselines and the oracle go through the
same piles, the same trials and the same tables:

* ``unet``: :func:`planner.inference.plan` with a checkpoint and an objective (f1, f2, f3);
* ``random``: a random target subset, a random pixel of its mask, random angle and width;
* ``geometric``: a rule-based planner that sees only the render and the log masks (PCA axes);
* ``oracle``: the data generator's ground-truth candidates (exact geometry) verified in
  simulation before the graded trial — an upper bound;
* ``unet`` with ``verify_k`` > 0: the U-Net's plan checked by :mod:`planner.verify` — its ``k``
  best grasps tried in the twin on a *perturbed copy* of the test pile (the reconstruction's
  measured errors, :class:`planner.pile_copies.PerturbationConfig`), never on the test pile itself
  (that would be the oracle); the graded trial then runs on the test pile.

With ``EvalConfig.field_error`` (:class:`synth.physics.perturb.PositioningError`) every planner's
chosen grasp is also executed as the crane would execute it — moved by one draw of the field's
positioning error, the same draw for every planner on a pile (paired) — and each planner gets a
second row, ``<name> (field)``, from those trials: the paper's protocol executes the grasp exactly.

Test piles are drawn from seeds ``seed_base + cell * 100_000 + k`` with ``seed_base`` far from the
training data's seeds. Planners are named by picklable specs so that workers (local processes or a
Dask cluster) build them once each.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Callable, Literal

import numpy as np

from planner.subsets import SubsetPolicy
from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, Grasp
from synth.physics.perturb import PositioningError

EVAL_FORMAT_VERSION = "1.0"
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

    @property
    def name(self) -> str:
        if self.label:
            return self.label
        if self.kind != "unet":
            return self.kind
        how = f"-cap{self.max_subsets}" if self.max_subsets else ""
        if self.views > 1:
            how += f"-views{self.views}" + (f"k{self.view_spread_k:g}" if self.view_spread_k else "")
        if self.verify_k:
            copies = f"x{self.verify_copies}" if self.verify_copies else ""
            return f"unet-{self.objective}{how}-verify{self.verify_k}{copies}"
        return f"unet-{self.objective}{how}"

    def subset_policy(self) -> SubsetPolicy:
        """The subsets this row plans with."""
        return SubsetPolicy(mode="fit", max_subsets=self.max_subsets) if self.max_subsets else SubsetPolicy()


@dataclass(frozen=True)
class EvalConfig:
    logs: tuple[int, ...] = (2, 3, 4, 5, 6, 7)  # pile sizes [-]
    obstacles: tuple[bool, ...] = (True, False)  # cells with / without obstacles
    per_cell: int = 100  # piles per (size, obstacles) cell [-]
    max_obstacles: int = 7  # obstacle count drawn from 1..max in "yes" cells [-]
    seed_base: int = 900_000_000  # far from training seeds [-]
    size_px: int = 128  # render size; must match the model [px]
    trial: Literal["fast", "careful"] = "fast"  # trial preset
    oracle_max_trials: int = 40  # simulation budget of the oracle per pile [-]
    field_error: PositioningError | None = None  # the field row's positioning error; None = no field row

    def __post_init__(self) -> None:
        if not self.logs or min(self.logs) < 1 or max(self.logs) > 16:
            raise ValueError(f"pile sizes must be in [1, 16], got {self.logs}")
        if self.per_cell < 1:
            raise ValueError(f"per_cell must be >= 1, got {self.per_cell}")
        if self.trial not in ("fast", "careful"):
            raise ValueError(f"trial must be 'fast' or 'careful', got {self.trial!r}")

    def cells(self) -> list[tuple[int, bool]]:
        return [(n, ob) for ob in self.obstacles for n in self.logs]

    def tasks(self) -> list[tuple[int, bool, int, int]]:
        """(n_logs, obstacles, k, seed) for every test pile."""
        out = []
        for ci, (n, ob) in enumerate(self.cells()):
            for k in range(self.per_cell):
                out.append((n, ob, k, self.seed_base + (n * 2 + int(ob)) * 100_000 + k))
        return out


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
                 view_spread_k: float = 0.0) -> PlanFn:
    """The network's best grasp among the subsets ``subsets`` keeps (default: every subset), its maps
    averaged over ``views`` dihedral test-time views."""
    import torch

    from planner.inference import Objective, load_planner, plan

    torch.set_num_threads(1)
    net = load_planner(model, views=views, view_spread_k=view_spread_k)
    obj = Objective(kind=objective)

    def plan_fn(obs, pile):
        result = plan(obs, net, obj, top_k=1, pile=pile, subsets=subsets)
        if result.best is None:
            return None
        return result.best.grasp, tuple(result.best.targets)
    return plan_fn


def verified_planner(plan_all: Callable[[object, object], object], objective: str, k: int, copies: int = 0,
                     trial_preset: str = "fast", trial_fn=None) -> PlanFn:
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

    obj = Objective(kind=objective)
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
                          view_spread_k: float = 0.0) -> PlanFn:
    import torch

    from planner.inference import Objective, load_planner, plan

    torch.set_num_threads(1)
    net = load_planner(model, views=views, view_spread_k=view_spread_k)
    obj = Objective(kind=objective)
    return verified_planner(lambda obs, pile: plan(obs, net, obj, pile=pile, subsets=subsets), objective, k, copies,
                            trial_preset)


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
            views = dict(views=spec.views, view_spread_k=spec.view_spread_k)
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


# -- one pile -----------------------------------------------------------------------------------
@dataclass
class Record:
    planner: str
    n_logs: int
    obstacles: bool
    k: int
    seed: int
    outcome: str  # synth.physics.trial.Outcome value, or "no_grasp"
    targets: list[int] = field(default_factory=list)
    grasped: list[int] = field(default_factory=list)
    cos_beta: float = float("nan")
    grasp: dict | None = None
    plan_s: float = 0.0
    trial_s: float = 0.0
    field: dict | None = None  # with a field error: the same grasp executed moved by it (outcome, grasped, cos_beta, grasp)


FIELD_SUFFIX = " (field)"  # the field row of a planner is named by its name and this


def field_trial(pile, grasp: Grasp, targets, error: PositioningError, trial_cfg) -> dict:
    """``grasp`` executed with the field's positioning error: one draw keyed by the pile's seed
    alone, so every planner's grasp on a pile is moved by the same offset and turn."""
    from synth.physics.perturb import grasp_rng, perturbed_grasps
    from synth.physics.trial import run_trial

    (moved,) = perturbed_grasps(grasp, error, 1, grasp_rng(int(pile.seed or 0), "eval-field"))
    r = run_trial(pile, moved, targets, trial_cfg)
    return {"outcome": r.outcome.value, "grasped": [int(t) for t in r.grasped], "cos_beta": float(r.cos_beta),
            "grasp": moved.to_dict()}


def eval_scene(task: tuple[int, bool, int, int], cfg: EvalConfig):
    """The settled pile and its top-down observation (one render) of test pile ``task``
    (``EvalConfig.tasks``): a pure function of the task's seed and ``cfg``."""
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.physics.world import World

    n_logs, with_obst, _, seed = task
    rng = np.random.default_rng([seed, 77])
    n_obst = int(rng.integers(1, cfg.max_obstacles + 1)) if with_obst else 0
    pile, _ = generate_pile(seed, GenerationConfig(n_logs=n_logs, n_obstacles=n_obst))
    with World(pile) as world:
        obs = render_ortho(world, OrthoRenderConfig(size_px=cfg.size_px, n_renders=1), seed=seed)
    return pile, obs


def evaluate_pile(task: tuple[int, bool, int, int], specs: list[PlannerSpec], cfg: EvalConfig,
                  planners: dict[str, PlanFn] | None = None) -> list[dict]:
    """Generate test pile ``task``, let every planner choose one grasp, try each in the twin."""
    from synth.physics.trial import TrialConfig, run_trial

    n_logs, with_obst, k, seed = task
    pile, obs = eval_scene(task, cfg)
    trial_cfg = TrialConfig.preset(cfg.trial)
    out = []
    for spec in specs:
        fn = (planners or {}).get(spec.name) or build_planner(spec, cfg.trial, cfg.oracle_max_trials)
        t0 = time.perf_counter()
        choice = fn(obs, pile)
        t1 = time.perf_counter()
        rec = Record(planner=spec.name, n_logs=n_logs, obstacles=with_obst, k=k, seed=seed, outcome="no_grasp",
                     plan_s=t1 - t0)
        if choice is not None:
            grasp, targets = choice
            r = run_trial(pile, grasp, targets, trial_cfg)
            rec.outcome = r.outcome.value
            rec.targets = [int(t) for t in targets]
            rec.grasped = [int(t) for t in r.grasped]
            rec.cos_beta = float(r.cos_beta)
            rec.grasp = grasp.to_dict()
            if cfg.field_error is not None:
                rec.field = field_trial(pile, grasp, targets, cfg.field_error, trial_cfg)
            rec.trial_s = time.perf_counter() - t1
        elif cfg.field_error is not None:
            rec.field = {"outcome": "no_grasp", "grasped": [], "cos_beta": float("nan"), "grasp": None}
        out.append(asdict(rec))
    return out


# -- the whole evaluation -------------------------------------------------------------------------
def run_evaluation(specs: list[PlannerSpec], cfg: EvalConfig, out_dir: str | Path, workers: int = 0,
                   engine: str = "local", address: str | None = None,
                   progress: Callable[[int, int], None] | None = None) -> dict:
    """Evaluate every planner on the same fresh piles; resumable (records per pile are appended
    to ``records/`` one file per pile, atomically); writes tables (Markdown + JSON) and a figure."""
    from synth.common.files import atomic_write_bytes, dumps_json
    from synth.common.runner import run_tasks

    if not specs:
        raise ValueError("no planner to evaluate")
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"planner names must be unique, got {names}")
    out = Path(out_dir)
    rec_dir = out / "records"
    rec_dir.mkdir(parents=True, exist_ok=True)
    from synth.physics.trial_spec import TRIAL_REVISION

    field = "" if cfg.field_error is None else f"+field{cfg.field_error.sigma_xy_m:g}m{cfg.field_error.sigma_phi_deg:g}deg"
    fingerprints = {s.name: _fingerprint(s) + field for s in specs}  # a record without this field row is made again
    params = {"format": "loggrasp.eval", "format_version": EVAL_FORMAT_VERSION, "config": asdict(cfg),
              "trial_revision": TRIAL_REVISION,
              "planners": [asdict(s) | {"model_sha256": fingerprints[s.name]} for s in specs]}
    pfile = out / "eval.json"
    if pfile.exists():
        # the same evaluation with more (or fewer) piles per cell reuses the records of the piles
        # both share (a pile's seed depends on its cell and index only)
        old = json.loads(pfile.read_text())
        if old.get("trial_revision") != TRIAL_REVISION:
            raise ValueError(f"{out} holds an evaluation made with trial revision {old.get('trial_revision', '<= 3')}, "
                             f"not {TRIAL_REVISION} (the twin's physics changed); choose a new --out")
        have = dict(old.get("config") or {})
        want = json.loads(json.dumps(asdict(cfg)))
        free = ("per_cell", "field_error")  # a field row added: its records are made again (their fingerprint)
        if {k: v for k, v in have.items() if k not in free} != {k: v for k, v in want.items() if k not in free}:
            raise ValueError(f"{out} holds an evaluation with another configuration (only --per-cell and "
                             "--field-error may change when it is resumed); choose a new --out")
    atomic_write_bytes(pfile, json.dumps(params, indent=1).encode())

    # resume per (pile, planner): a pile's record file keeps the planners it already has; a planner
    # missing from it, or a U-Net record made with another checkpoint (sha256), is (re)run on it
    tasks = cfg.tasks()
    kept: dict[int, list[dict]] = {}
    todo: list[tuple[tuple, list[PlannerSpec]]] = []
    for t in tasks:
        have = _read_records(rec_dir / f"{t[3]}.json")
        ok = {r["planner"]: r for r in have if r.get("model_sha256", "") == fingerprints.get(r["planner"])}
        missing = [s for s in specs if s.name not in ok]
        kept[t[3]] = [r for r in have if r["planner"] not in {s.name for s in missing}]
        if missing:
            todo.append((t, missing))
    done = len(tasks) - len(todo)
    if progress:
        progress(done, len(tasks))

    def finish(task, recs):
        nonlocal done
        for r in recs:
            r["model_sha256"] = fingerprints[r["planner"]]
        merged = {r["planner"]: r for r in kept[task[3]] + recs}
        order = [s.name for s in specs] + sorted(set(merged) - set(fingerprints))
        atomic_write_bytes(rec_dir / f"{task[3]}.json",
                           json.dumps([merged[n] for n in order if n in merged]).encode())
        done += 1
        if progress:
            progress(done, len(tasks))

    run_tasks(evaluate_pile, {t: (t, missing, cfg) for t, missing in todo}, finish, workers=workers, engine=engine,
              address=address)

    records = [r for t in tasks for r in _read_records(rec_dir / f"{t[3]}.json")]
    tables = summarise(records, cfg, names)
    atomic_write_bytes(out / "results.json", dumps_json(tables).encode())  # NaN (no piles, no successes): null
    atomic_write_bytes(out / "results.md", tables_markdown(tables, cfg).encode())
    try:
        draw_examples(records, cfg, out / "examples.png", names[0])
    except Exception as exc:  # a picture must not lose the numbers
        (out / "examples.err").write_text(str(exc))
    return tables


def _fingerprint(spec: PlannerSpec) -> str:
    """What a record must match to be reused: the checkpoint's sha256 for a U-Net, '' otherwise."""
    if spec.kind != "unet" or not spec.model:
        return ""
    from synth.common.files import sha256_file

    try:
        sha = sha256_file(Path(spec.model))
        if spec.views > 1:  # a record planned with other test-time views is made again, whatever its label
            sha += f"+views{spec.views}k{spec.view_spread_k:g}"
        if spec.verify_k:  # the verifier's version too: a record of another verifier is made again
            from planner.verify import VERIFY_VERSION

            return f"{sha}+verify-{VERIFY_VERSION}"
        return sha
    except OSError as exc:
        raise ValueError(f"cannot read the checkpoint {spec.model} of planner {spec.name!r}: {exc}") from exc


def _read_records(path: Path) -> list[dict]:
    if not path.exists():
        return []
    try:
        recs = json.loads(path.read_text())
        if not isinstance(recs, list) or not all(isinstance(r, dict) and "planner" in r for r in recs):
            raise ValueError("not a list of planner records")
    except ValueError as exc:
        raise ValueError(f"evaluation record {path} is corrupt ({exc}); delete it to evaluate that pile "
                         "again") from exc
    return recs


def _stats(recs: list[dict]) -> dict:
    n = len(recs)
    succ = [r for r in recs if r["outcome"] == "success"]
    betas = [math.degrees(math.acos(min(1.0, max(-1.0, r["cos_beta"])))) for r in succ if r["cos_beta"] == r["cos_beta"]]
    return {
        "piles": n,
        "success_rate": len(succ) / n if n else float("nan"),
        "avg_logs_success": float(np.mean([len(r["grasped"]) for r in succ])) if succ else 0.0,
        "avg_logs_all": float(np.mean([len(r["grasped"]) if r["outcome"] == "success" else 0 for r in recs])) if n else 0.0,
        "beta_avg_deg": float(np.mean(betas)) if betas else float("nan"),
        "failures": {k: sum(1 for r in recs if r["outcome"] == k) for k in sorted({r["outcome"] for r in recs}) if k != "success"},
    }


def summarise(records: list[dict], cfg: EvalConfig, names: list[str]) -> dict:
    if cfg.field_error is not None:  # each planner's field row: its records with the field trial's result
        names = [*names, *(n + FIELD_SUFFIX for n in names)]
        records = records + [{**r, **r["field"], "planner": r["planner"] + FIELD_SUFFIX}
                             for r in records if r.get("field")]
    by = {}
    for name in names:
        mine = [r for r in records if r["planner"] == name]
        cells = {}
        for n, ob in cfg.cells():
            cells[f"{n}-{'yes' if ob else 'no'}"] = _stats([r for r in mine if r["n_logs"] == n and r["obstacles"] == ob])
        rows = {("yes" if ob else "no"): _stats([r for r in mine if r["obstacles"] == ob]) for ob in cfg.obstacles}
        by[name] = {"total": _stats(mine), "rows": rows, "cells": cells}
    field = None if cfg.field_error is None else cfg.field_error.to_dict()
    return {"format": "loggrasp.eval-results", "format_version": EVAL_FORMAT_VERSION, "field_error": field,
            "planners": by}


def tables_markdown(tables: dict, cfg: EvalConfig) -> str:
    piles = f"{cfg.per_cell} pile{'' if cfg.per_cell == 1 else 's'}"
    lines = [f"# Evaluation in the twin\n\n{piles} per cell, one grasp per pile, trial preset "
             f"`{cfg.trial}`, seeds from {cfg.seed_base}. Avg. logs = logs held in successful grasps "
             "(the paper's 'average number of grasped logs'); β_avg over successful grasps.\n"]
    if cfg.field_error is not None:
        lines.append(f"Rows '{FIELD_SUFFIX.strip()}': the same chosen grasp executed with the crane's positioning "
                     f"error, {cfg.field_error.label()} (one draw per pile, the same for every planner).\n")
    for name, t in tables["planners"].items():
        lines.append(f"\n## Table 1 — {name}: success / avg. grasped logs\n")
        lines.append("| obstacles | " + " | ".join(f"{n} logs" for n in cfg.logs) + " | total |")
        lines.append("|---|" + "---|" * (len(cfg.logs) + 1))
        for ob in cfg.obstacles:
            row = [f"{t['cells'][f'{n}-' + ('yes' if ob else 'no')]['success_rate'] * 100:.0f}%/"
                   f"{t['cells'][f'{n}-' + ('yes' if ob else 'no')]['avg_logs_success']:.1f}" for n in cfg.logs]
            tot = t.get("rows", {}).get("yes" if ob else "no", t["total"])  # that row's piles
            lines.append(f"| {'yes' if ob else 'no'} | " + " | ".join(row) +
                         f" | {tot['success_rate'] * 100:.0f}%/{tot['avg_logs_success']:.1f} |")
        if len(cfg.obstacles) > 1:
            lines.append("| all | " + " | ".join("" for _ in cfg.logs) +
                         f" | {t['total']['success_rate'] * 100:.0f}%/{t['total']['avg_logs_success']:.1f} |")
    lines.append("\n## Table 2 — planners and objectives\n")
    lines.append("| planner | success | avg. grasped logs | β_avg | piles |")
    lines.append("|---|---|---|---|---|")
    for name, t in tables["planners"].items():
        s = t["total"]
        lines.append(f"| {name} | {s['success_rate'] * 100:.0f}% | {s['avg_logs_success']:.1f} | "
                     f"{s['beta_avg_deg']:.0f}° | {s['piles']} |")
    lines.append("\n## Failures\n")
    kinds = sorted({k for t in tables["planners"].values() for k in t["total"]["failures"]})
    if not kinds:
        lines.append("No failures.")
    else:
        lines.append("| planner | " + " | ".join(kinds) + " |")
        lines.append("|---|" + "---|" * len(kinds))
        for name, t in tables["planners"].items():
            lines.append(f"| {name} | " + " | ".join(str(t["total"]["failures"].get(k, 0)) for k in kinds) + " |")
    return "\n".join(lines).replace("nan%", "-").replace("/nan", "/-").replace("nan°", "-") + "\n"


def draw_examples(records: list[dict], cfg: EvalConfig, path: Path, planner: str, n: int = 4) -> None:
    """Example successes (top row) and failures (bottom row) of ``planner``
    (:func:`planner.pictures.draw_examples`)."""
    from planner.pictures import draw_examples as draw

    draw(records, cfg, path, planner, n=n)
