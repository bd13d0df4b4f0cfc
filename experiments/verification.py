"""The real test with verified planning (issue 17): reconstruct, plan on the reconstruction, let the
twin verify the best grasps on the reconstruction, execute the chosen one on the TRUE pile.

For each twin scan (:func:`experiments.real_test.prepare_case`: seeds ``--seed`` + k, kept in and reused
from ``--work-dir``) and objective, side by side on the same pile:

* ``truth-planned``: the network alone on the truth's render (the real test's reference);
* ``network``: the network alone on the reconstruction (what the field stack sent before);
* ``verify K=k``: :class:`planner.verify.Verifier` with ``k`` candidates on the reconstruction, no
  perturbed copies; ``verify K=k +C copies``: the same with ``C`` perturbed copies of the
  reconstruction (per-log sigmas from the reconstruction report's fit classes,
  :func:`planner.pile_copies.perturbation_for_fits`).

A verification that finds no successful grasp counts as a failure (the field stack would not send).
Trials on the reconstruction are shared between the variants of a pile (the K=4 candidates are the
first of the K=16 ones; a trial is deterministic), so each is simulated once; a variant's
*planning time* is the network's planning wall time plus the wall time of every trial the variant
needed (as each was timed when it ran, one worker) plus making its perturbed copies - what one core
would spend. ``--timing`` measures real verification wall times with ``--workers`` processes instead.

The record (JSON) is written after every pile; re-running the same command resumes it (with more
``--piles`` it extends it) - with the same code only: its fitting and trial revisions are part of its
settings, so a record begun by other code is refused, never mixed. The full run (~1 CPU-minute a pile with f1 and f3; ``--workers`` piles at
once, each in its own process):

    .venv/bin/python bench/bench_verify.py --piles 500 --workers 2 --work-dir runs/verify-work \\
        --out runs/verify_real_test.json --md docs/results/verify/results.md --fig docs/results/verify/figure.png
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.measure import load_average, paired

FORMAT = "loggrasp.bench-verify"
VERSION = "1.0"


class CachedTwin:
    """``run_trial`` with the results of one pile kept: the same (pile copy, grasp, targets) is
    simulated once and later calls get the stored result (with the wall time it took then)."""

    def __init__(self) -> None:
        from synth.physics.trial import run_trial

        self.run_trial = run_trial
        self.cache: dict = {}
        self.keep: list = []  # the pile copies, alive while their id() is a key

    def __call__(self, pile, grasp, targets, cfg):
        key = (id(pile), grasp.x_m, grasp.y_m, grasp.phi_rad, grasp.width_m, tuple(targets))
        if key not in self.cache:
            self.keep.append(pile)
            self.cache[key] = self.run_trial(pile, grasp, targets, cfg)
        return self.cache[key]


def pile_rows(case, net, objectives, ks, copies) -> list[dict]:
    """Every variant on one prepared case (see the module docstring): one row per objective."""
    # Over 80 lines on purpose: the variants share one plan, one set of truth executions (memoised in
    # on_truth) and one verifier per copy count; apart they would pass that shared state around.
    from experiments.real_test import execute_on_truth
    from planner.errors import PlannerError
    from planner.inference import Objective, plan
    from reconstruct.report import log_end_sigmas
    from planner.pile_copies import PerturbationConfig, perturbation_for_fits
    from planner.verify import Verifier, VerifyConfig

    executed: dict = {}

    def on_truth(grasp, targets) -> dict:
        if any(t is None for t in targets):
            return {"success": False, "outcome": "unmatched_target", "grasped": [], "cos_beta": math.nan}
        key = (grasp.x_m, grasp.y_m, grasp.phi_rad, grasp.width_m, tuple(targets))
        if key not in executed:
            executed[key] = execute_on_truth(case.truth, grasp, tuple(targets))
        return executed[key]

    twin = CachedTwin()
    piles, copies_s, copies_cpu = None, 0.0, 0.0
    if case.recon is not None:
        fits = [lg.get("fit", "scan") for lg in (case.report or {}).get("logs", [])]
        pert = PerturbationConfig(copies=copies, seed=case.seed)
        if len(fits) == case.recon.n_logs:
            pert = perturbation_for_fits(fits, pert, log_end_sigmas(case.report))
        t, c0 = time.perf_counter(), time.process_time()
        piles = Verifier(VerifyConfig(perturbation=pert, workers=1)).piles(case.recon)
        copies_s, copies_cpu = time.perf_counter() - t, time.process_time() - c0
    rows = []
    for kind in objectives:
        obj = Objective(kind=kind)
        row = {**case.base_row(), "objective": kind, "recon_error": case.recon_error, "copies_s": copies_s,
               "variants": {}}
        t, c0 = time.perf_counter(), time.process_time()
        try:
            best_t = plan(case.obs_truth, net, obj, top_k=1, pile=case.truth).best
        except PlannerError as exc:
            best_t, row["truth_plan_error"] = None, str(exc)
        if best_t is None:  # no reference on this pile: left out of the paired comparison
            rows.append(row)
            continue
        row["variants"]["truth-planned"] = {"targets": list(best_t.targets), "plan_s": time.perf_counter() - t,
                                            "plan_cpu_s": time.process_time() - c0,
                                            **on_truth(best_t.grasp, list(best_t.targets))}
        fail = {"success": False, "grasped": [], "cos_beta": math.nan}
        p_r = None
        c0 = time.process_time()
        if case.obs_recon is not None:
            try:
                p_r = plan(case.obs_recon, net, obj, pile=case.recon)
            except PlannerError as exc:
                row["recon_plan_error"] = str(exc)
        if p_r is None or p_r.best is None:
            why = case.recon_error and "recon_error" or "no_grasp"
            for name in ["network"] + [v for k in ks for v in (f"verify K={k}", f"verify K={k} +{copies} copies")]:
                row["variants"][name] = {**fail, "outcome": why, "plan_s": 0.0, "plan_cpu_s": 0.0}
            rows.append(row)
            continue
        plan_cpu = time.process_time() - c0
        g, targets = case.recon_to_truth(p_r.best.grasp, p_r.best.targets)
        row["variants"]["network"] = {"targets": targets, "plan_s": p_r.elapsed_s, "plan_cpu_s": plan_cpu,
                                      **on_truth(g, targets)}
        for k in ks:
            for c in (0, copies) if copies else (0,):
                name = f"verify K={k}" + (f" +{c} copies" if c else "")
                cfg = VerifyConfig(k=k, workers=1, time_budget_s=None,
                                   perturbation=PerturbationConfig(copies=c, seed=case.seed))
                v = Verifier(cfg, twin).verify(p_r, case.recon, obj, piles=piles[: c + 1])
                trials = [t for cand in v.candidates for t in cand.trials if t.result is not None]
                entry = {"plan_s": p_r.elapsed_s + sum(t.result.wall_time_s for t in trials) + (copies_s if c else 0.0),
                         "plan_cpu_s": plan_cpu + sum(t.result.cpu_time_s for t in trials) + (copies_cpu if c else 0.0),
                         "trials": len(trials), "trial_cpu_s": sum(t.result.cpu_time_s for t in trials),
                         "checked": [[cand.rank, cand.status, cand.outcome, cand.successes] for cand in v.candidates]}
                if v.chosen is None:
                    entry.update({**fail, "outcome": "refused", "targets": []})
                else:
                    g, targets = case.recon_to_truth(v.chosen.planned.grasp, v.chosen.planned.targets)
                    entry.update({"rank": v.chosen.rank, "targets": targets, **on_truth(g, targets)})
                row["variants"][name] = entry
        rows.append(row)
    return rows


# -- piles in worker processes -------------------------------------------------------------------
_NET: dict = {}


def _net(model: str):
    """The planner network of ``model``, loaded once per process (one torch thread: piles run in parallel)."""
    if _NET.get("model") != model:
        import torch

        from planner.inference import load_planner

        torch.set_num_threads(1)
        _NET.update(model=model, net=load_planner(model, device="cpu"))
    return _NET["net"]


def one_pile(seed: int, model: str, work_dir: str, logs, obstacles, objectives, ks, copies,
             n_float: int = 2) -> list[dict]:
    """Every variant on twin scan ``seed`` (made or reused in ``work_dir``); a failure is a row saying so."""
    from experiments.real_test import RealTestConfig, prepare_case

    net = _net(model)
    try:
        case = prepare_case(seed, work_dir, net.config, RealTestConfig(logs=tuple(logs), obstacles=tuple(obstacles),
                                                                        n_float=n_float))
        return pile_rows(case, net, objectives, ks, copies)
    except Exception as exc:  # a pile the generator or the twin could not make: said, not hidden
        return [{"seed": seed, "failure": f"{type(exc).__name__}: {exc}"}]


# -- the record ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class VerifyBenchConfig:
    """What :func:`run` measures: twin scans ``seed`` .. ``seed + piles - 1`` with ``logs`` and
    ``obstacles`` (inclusive ranges), each objective, verification with each K of ``ks`` (with and
    without ``copies`` perturbed copies), ``n_float`` RTK float ends per survey."""

    piles: int = 40  # twin scans [-]
    seed: int = 700_000  # first scan seed [-]
    logs: tuple[int, int] = (3, 6)  # logs per pile, inclusive range [-]
    obstacles: tuple[int, int] = (0, 2)  # obstacles per pile, inclusive range [-]
    objectives: tuple[str, ...] = ("f1", "f3")
    ks: tuple[int, ...] = (4, 8, 16)  # candidates the verifier tries [-]
    copies: int = 3  # perturbed copies in the '+copies' variants [-]; 0 = none
    n_float: int = 2  # RTK float ends per survey [-]
    model: str | None = None  # checkpoint; None = the shipped one
    workers: int = 1  # piles at once, each in its own process [-]

    def __post_init__(self) -> None:
        if self.piles < 1 or self.workers < 1 or self.copies < 0 or self.n_float < 0:
            raise ValueError(f"piles and workers must be >= 1, copies and n_float >= 0; got {self}")
        if not self.ks or min(self.ks) < 1:
            raise ValueError(f"every K must be >= 1, got {self.ks}")


def write_record(path: Path, rec: dict) -> None:
    """The record as JSON, atomically (NaN as in Python's json)."""
    from synth.common.files import atomic_write_bytes

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, json.dumps(rec, indent=1, default=float).encode())


def run(cfg: VerifyBenchConfig, work_dir: Path, out: Path, progress=print) -> dict:
    """Measure (see the module docstring) into the record ``out`` (written after every pile; the same
    settings resume it, more ``piles`` extend it); twin scans kept in ``work_dir``."""
    from planner.checkpoint import DEFAULT_MODEL
    from reconstruct.fitting.fit import FIT_REVISION
    from synth.common.files import sha256_file
    from synth.common.runner import run_tasks
    from synth.physics.trial_spec import TRIAL_REVISION

    model = Path(cfg.model or DEFAULT_MODEL)
    config = {"piles": cfg.piles, "seed": cfg.seed, "logs": list(cfg.logs), "obstacles": list(cfg.obstacles),
              "objectives": list(cfg.objectives), "ks": list(cfg.ks), "copies": cfg.copies,
              "n_float": cfg.n_float, "model_sha256": sha256_file(model),
              # piles reconstructed or grasps tried by other code are another measurement: never mixed in
              "fit_revision": FIT_REVISION, "trial_revision": TRIAL_REVISION}
    same = {k: v for k, v in config.items() if k != "piles"}
    rec = {"format": FORMAT, "format_version": VERSION, "config": config, "rows": [], "loads": []}
    if out.exists():
        old = json.loads(out.read_text())
        if {k: v for k, v in old.get("config", {}).items() if k != "piles"} != same:
            raise ValueError(f"{out} holds another measurement (settings differ); choose another --out")
        rec["rows"], rec["loads"] = old["rows"], old.get("loads", [])
    done = {r["seed"] for r in rec["rows"]}
    work_dir.mkdir(parents=True, exist_ok=True)
    todo = [cfg.seed + k for k in range(cfg.piles) if cfg.seed + k not in done]
    progress(f"{len(done)} piles done, {len(todo)} to go; load {load_average('')}")
    job = (str(model), str(work_dir), cfg.logs, cfg.obstacles, cfg.objectives, cfg.ks, cfg.copies, cfg.n_float)
    t0 = time.perf_counter()
    finished = []

    def keep(seed: int, rows: list[dict]) -> None:
        finished.append(seed)
        rec["rows"] += rows
        rec["loads"].append({"seed": seed, "load": load_average(''), "since_start_s": time.perf_counter() - t0,
                             "workers": cfg.workers})
        rec["config"]["piles"] = max(cfg.piles, rec["config"].get("piles", 0))
        write_record(out, rec)
        progress(f"pile {len(finished)}/{len(todo)} seed {seed}: {time.perf_counter() - t0:.0f} s so far, "
                 f"load {load_average('')}")

    run_tasks(one_pile, {seed: (seed, *job) for seed in todo}, keep, workers=cfg.workers)
    return rec


# -- summary ------------------------------------------------------------------------------------
def summarise(rec: dict) -> dict:
    out = {}
    for kind in rec["config"]["objectives"]:
        rows = [r for r in rec["rows"] if r.get("objective") == kind and "truth-planned" in r.get("variants", {})]
        if not rows:
            continue
        names = list(rows[0]["variants"])
        s = {name: np.array([bool(r["variants"][name]["success"]) for r in rows], dtype=float) for name in names}
        table = {}
        for name in names:
            vs = [r["variants"][name] for r in rows]
            succ = [v for v in vs if v["success"]]
            betas = [math.degrees(math.acos(min(1.0, max(-1.0, v["cos_beta"])))) for v in succ
                     if v.get("cos_beta") is not None and math.isfinite(v["cos_beta"])]
            times = [v.get("plan_s", 0.0) for v in vs]
            times7 = [v.get("plan_s", 0.0) for v, r in zip(vs, rows) if r["n_logs"] >= 6]
            cpus = [v.get("plan_cpu_s", 0.0) for v in vs]
            cpus6 = [v.get("plan_cpu_s", 0.0) for v, r in zip(vs, rows) if r["n_logs"] >= 6]
            fails: dict = {}
            for v in vs:
                if not v["success"]:
                    fails[v.get("outcome", "?")] = fails.get(v.get("outcome", "?"), 0) + 1
            table[name] = {
                "piles": len(rows), "success": float(s[name].mean()),
                "logs_per_success": float(np.mean([len(v["grasped"]) for v in succ])) if succ else math.nan,
                "beta_deg": float(np.mean(betas)) if betas else math.nan,
                "plan_s_median": float(np.median(times)), "plan_s_p90": float(np.percentile(times, 90)),
                "plan_s_median_6logs": float(np.median(times7)) if times7 else math.nan,
                "plan_cpu_s_median": float(np.median(cpus)), "plan_cpu_s_p90": float(np.percentile(cpus, 90)),
                "plan_cpu_s_mean": float(np.mean(cpus)),
                "plan_cpu_s_median_6logs": float(np.median(cpus6)) if cpus6 else math.nan,
                "trials_mean": float(np.mean([v.get("trials", 0) for v in vs])),
                "vs_network_pp": paired(s["network"], s[name]), "vs_truth_pp": paired(s["truth-planned"], s[name]),
                "failures": fails,
            }
        out[kind] = table
    return out


def markdown(rec: dict, command: str) -> str:
    cfg = rec["config"]
    piles = sorted({r["seed"] for r in rec["rows"]})
    fails = [r for r in rec["rows"] if "failure" in r]
    loads = [x["load"] for x in rec.get("loads", [])]
    lines = [
        "# Verified planning: the real test with the twin checking the network's best grasps",
        "",
        f"{len(piles)} twin scans (seeds {cfg['seed']}..{max(piles) if piles else '-'}, {cfg['logs'][0]}-{cfg['logs'][1]} logs, "
        f"{cfg['obstacles'][0]}-{cfg['obstacles'][1]} obstacles, 2x2 pairs, "
        + (f"{cfg['n_float']} RTK float ends per survey, reconstructed with --allow-float" if cfg.get("n_float") else "RTK fixed")
        + "), reconstructed; the shipped "
        f"model (sha256 {cfg['model_sha256'][:12]}) plans on the reconstruction; the verifier tries its best grasps "
        "on the reconstruction (and on perturbed copies of it); the chosen grasp is executed on the TRUE pile. "
        "A refusal (no grasp succeeded in the twin) counts as a failure. Planning time = the network's planning "
        "time + the time of every trial the verification needed, one worker (each trial timed when it ran) + "
        "making the perturbed copies; wall times under the load stated, CPU times of that one process.",
        "",
        f"Command: `{command}`" + (f" (fitting revision {cfg['fit_revision']}, trial revision {cfg['trial_revision']})"
                                   if "fit_revision" in cfg else ""),
        f"Load average (1/5/15 min) after each pile: first {loads[0] if loads else '?'}, last {loads[-1] if loads else '?'}; "
        f"piles the generator or the twin could not make: {len(fails)}.",
        "",
    ]
    for kind, table in summarise(rec).items():
        lines += [f"## {kind}", "",
                  "| planner | piles | success | vs network [pp] (95 % CI) | vs truth-planned [pp] (95 % CI) | "
                  "logs / success | β [deg] | plan wall s median | p90 | plan CPU s median | mean | p90 | CPU s median, "
                  "6-log piles | trials / pile | failures |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for name, t in table.items():
            d1, l1, h1 = t["vs_network_pp"]
            d2, l2, h2 = t["vs_truth_pp"]
            f = ", ".join(f"{k} {v}" for k, v in sorted(t["failures"].items()))
            lines.append(f"| {name} | {t['piles']} | {100 * t['success']:.1f} % | {d1:+.1f} [{l1:+.1f}, {h1:+.1f}] | "
                         f"{d2:+.1f} [{l2:+.1f}, {h2:+.1f}] | {t['logs_per_success']:.2f} | {t['beta_deg']:.1f} | "
                         f"{t['plan_s_median']:.1f} | {t['plan_s_p90']:.1f} | {t['plan_cpu_s_median']:.1f} | "
                         f"{t['plan_cpu_s_mean']:.1f} | "
                         f"{t['plan_cpu_s_p90']:.1f} | {t['plan_cpu_s_median_6logs']:.1f} | "
                         f"{t['trials_mean']:.1f} | {f} |")
        lines.append("")
    lines += _reconstructed_only(rec)
    for r in fails:
        lines.append(f"- seed {r['seed']}: {r['failure']}")
    return "\n".join(lines) + "\n"


def _reconstructed_only(rec: dict) -> list[str]:
    """The same planners on the piles whose reconstruction the stack did not refuse: what planning and
    verification do given a pile, apart from how often there is none (every planner but the truth-planned
    one fails on a refused pile)."""
    refused = {r["seed"] for r in rec["rows"] if r.get("recon_error")}
    kept = dict(rec, rows=[r for r in rec["rows"] if r["seed"] not in refused])
    if not refused or not kept["rows"]:
        return []
    n_all = len({r["seed"] for r in rec["rows"]})
    lines = [f"## On the piles reconstructed ({n_all - len(refused)} of {n_all}; {len(refused)} refused: "
             f"{100 * len(refused) / n_all:.1f} %)", "",
             "| objective | planner | piles | success | vs truth-planned [pp] (95 % CI) | logs / success | β [deg] |",
             "|---|---|---|---|---|---|---|"]
    for kind, table in summarise(kept).items():
        for name, t in table.items():
            d, lo, hi = t["vs_truth_pp"]
            lines.append(f"| {kind} | {name} | {t['piles']} | {100 * t['success']:.1f} % | {d:+.1f} [{lo:+.1f}, {hi:+.1f}] | "
                         f"{t['logs_per_success']:.2f} | {t['beta_deg']:.1f} |")
    return lines + [""]


def figure(rec: dict, path: Path) -> None:
    """Success vs K and planning time vs K, per objective, with and without perturbed copies."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tables = summarise(rec)
    ks, copies = rec["config"]["ks"], rec["config"]["copies"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    colours = {"f1": "tab:blue", "f2": "tab:green", "f3": "tab:red"}
    for kind, t in tables.items():
        col = colours.get(kind, "black")
        for c, style in ((0, "-o"), (copies, "--s")) if copies else ((0, "-o"),):
            names = [f"verify K={k}" + (f" +{c} copies" if c else "") for k in ks]
            lab = f"{kind}, verified" + (f" + {c} perturbed copies" if c else "")
            axes[0].plot(ks, [100 * t[n]["success"] for n in names], style, color=col, label=lab,
                         alpha=0.6 if c else 1.0)
            axes[1].plot(ks, [t[n]["plan_cpu_s_mean"] for n in names], style, color=col, label=lab,
                         alpha=0.6 if c else 1.0)
        axes[0].axhline(100 * t["network"]["success"], ls=":", color=col, label=f"{kind}, network alone")
        axes[0].axhline(100 * t["truth-planned"]["success"], ls="-.", lw=0.8, color=col,
                        label=f"{kind}, network on the truth")
        axes[1].axhline(t["network"]["plan_cpu_s_mean"], ls=":", color=col, label=f"{kind}, network alone")
    axes[0].set(xlabel="K (grasps the twin tries)", ylabel="success on the true pile [%]",
                title=f"success, {tables and next(iter(tables.values()))['network']['piles']} twin scans")
    axes[1].set(xlabel="K (grasps the twin tries)", ylabel="planning CPU time per pile, mean [s]",
                title="planning time, one core (CPU)")
    for ax in axes:
        ax.set_xscale("log", base=2)
        ax.set_xticks(ks, [str(k) for k in ks])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


# -- real wall times ------------------------------------------------------------------------------
def timing(cfg: VerifyBenchConfig, n_piles: int, work_dir: Path, progress=print) -> list[dict]:
    """Planning + verification wall time on ``n_piles`` 7-log piles with ``cfg.workers`` processes (a
    Verifier kept between piles, its workers started before the first), f3, no time budget."""
    import torch

    from experiments.real_test import RealTestConfig, prepare_case
    from planner.checkpoint import DEFAULT_MODEL
    from planner.inference import Objective, load_planner, plan
    from planner.verify import Verifier, VerifyConfig

    torch.set_num_threads(cfg.workers)
    net = load_planner(Path(cfg.model or DEFAULT_MODEL), device="cpu")
    scans = RealTestConfig(logs=(7, 7), obstacles=tuple(cfg.obstacles))
    out = []
    for k in cfg.ks:
        with Verifier(VerifyConfig(k=k, workers=cfg.workers, time_budget_s=None)) as v:
            for n in range(n_piles):
                case = prepare_case(cfg.seed + 50_000 + n, work_dir, net.config, scans)
                if case.recon is None:
                    continue
                t0 = time.perf_counter()
                p = plan(case.obs_recon, net, Objective("f3"), pile=case.recon)
                t1 = time.perf_counter()
                res = v.verify(p, case.recon, Objective("f3"))
                t2 = time.perf_counter()
                out.append({"k": k, "seed": case.seed, "n_logs": case.recon.n_logs, "plan_s": t1 - t0,
                            "verify_s": t2 - t1, "trials": sum(len(c.trials) for c in res.candidates),
                            "ok": res.ok, "load": load_average('')})
                progress(out[-1])
    return out
