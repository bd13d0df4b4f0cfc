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
from pathlib import Path
from typing import Callable, Literal

import numpy as np

from planner.inference import SIGMA_B
from planner.planners import PlanFn, PlannerSpec, build_planner
from synth.geometry.grasp import Grasp
from synth.physics.perturb import PositioningError

EVAL_FORMAT_VERSION = "1.0"


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


def eval_pile(task: tuple[int, bool, int, int], cfg: EvalConfig):
    """The settled pile of test pile ``task`` (``EvalConfig.tasks``): a pure function of the task's
    seed and ``cfg``."""
    from synth.scene.generate import GenerationConfig, generate_pile

    n_logs, with_obst, _, seed = task
    rng = np.random.default_rng([seed, 77])
    n_obst = int(rng.integers(1, cfg.max_obstacles + 1)) if with_obst else 0
    pile, _ = generate_pile(seed, GenerationConfig(n_logs=n_logs, n_obstacles=n_obst))
    return pile


def eval_scene(task: tuple[int, bool, int, int], cfg: EvalConfig):
    """The settled pile and its top-down observation (one render) of test pile ``task``
    (``EvalConfig.tasks``): a pure function of the task's seed and ``cfg``."""
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    seed = task[3]
    pile = eval_pile(task, cfg)
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
        want = {s.name: fingerprints[s.name] + _pile_tag(s, t) for s in specs}
        ok = {r["planner"]: r for r in have if r.get("model_sha256", "") == want.get(r["planner"])}
        missing = [s for s in specs if s.name not in ok]
        kept[t[3]] = [r for r in have if r["planner"] not in {s.name for s in missing}]
        if missing:
            todo.append((t, missing))
    done = len(tasks) - len(todo)
    if progress:
        progress(done, len(tasks))

    def finish(task, recs):
        nonlocal done
        tags = {s.name: _pile_tag(s, task) for s in specs}
        for r in recs:
            r["model_sha256"] = fingerprints[r["planner"]] + tags[r["planner"]]
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


def _precision_tag(spec: PlannerSpec) -> str:
    """The fingerprint's number format: '' where "auto" runs in a float format (the records made before
    the format was recorded), else the format, and an int8 calibration's hash."""
    from planner.inference import checkpoint_precision
    from planner.int8 import calibration_path
    from planner.runtime import INT8_PRECISIONS
    from synth.common.files import sha256_file

    runs = checkpoint_precision(spec.model, "cpu", spec.precision)
    if spec.precision == "auto" and runs not in INT8_PRECISIONS:
        return ""
    return f"+{runs}" + (f"-{sha256_file(calibration_path(spec.model))[:16]}" if runs in INT8_PRECISIONS else "")


def _pile_tag(spec: PlannerSpec, task: tuple[int, bool, int, int]) -> str:
    """The part of a record's fingerprint its pile decides: a U-Net planning clear of obstacles (the
    default) on a pile with obstacles, with the footprint it tests against them (``+clear``: the opening's
    rectangle; ``+claws``: the grapple's claws, planner.constraints.Constraints); on a pile without any the
    switch changes nothing, and the records made before it are kept."""
    if not (spec.kind == "unet" and spec.clear_obstacles and task[1]):
        return ""
    from planner.constraints import Constraints
    from synth.geometry.grasp import RECT_WIDTH_M

    c = Constraints()
    return "+clear" if (c.claw_plate_m, c.claw_width_m) == (0.0, RECT_WIDTH_M) else "+claws"


def _fingerprint(spec: PlannerSpec) -> str:
    """What a record must match to be reused: the checkpoint's sha256 for a U-Net, '' otherwise."""
    if spec.kind != "unet" or not spec.model:
        return ""
    from synth.common.files import sha256_file

    try:
        sha = sha256_file(Path(spec.model))
        if spec.objective == "f3" and spec.sigma_b != SIGMA_B:  # ... and with another balance tolerance
            sha += f"+sb{spec.sigma_b:g}"
        if spec.objective == "f3" and spec.balance == "hang":  # ... or the hang model (its offset and parameters)
            from planner.balance import HangModel

            sha += f"+hang-{HangModel().tag}"
        sha += _precision_tag(spec)
        if spec.views > 1:  # a record planned with other test-time views is made again, whatever its label
            sha += f"+views{spec.views}k{spec.view_spread_k:g}"
        if spec.ranker:  # ... and with another ranker or another number re-scored
            sha += f"+ranker{sha256_file(Path(spec.ranker))[:16]}k{spec.rerank_k}u{spec.ranker_u_weight:g}"
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
