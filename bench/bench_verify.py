"""The real test with verified planning (issue 17): reconstruct, plan on the reconstruction, let the
twin verify the best grasps on the reconstruction, execute the chosen one on the TRUE pile.

For each twin scan (:func:`experiments.real_test.prepare_case`: seeds ``--seed`` + k, kept in and reused
from ``--work-dir``) and objective, side by side on the same pile:

* ``truth-planned``: the network alone on the truth's render (the real test's reference);
* ``network``: the network alone on the reconstruction (what the field stack sent before);
* ``verify K=k``: :class:`planner.verify.Verifier` with ``k`` candidates on the reconstruction, no
  perturbed copies; ``verify K=k +C copies``: the same with ``C`` perturbed copies of the
  reconstruction (per-log sigmas from the reconstruction report's fit classes,
  :func:`planner.verify.perturbation_for_fits`).

A verification that finds no successful grasp counts as a failure (the field stack would not send).
Trials on the reconstruction are shared between the variants of a pile (the K=4 candidates are the
first of the K=16 ones; a trial is deterministic), so each is simulated once; a variant's
*planning time* is the network's planning wall time plus the wall time of every trial the variant
needed (as each was timed when it ran, one worker) plus making its perturbed copies - what one core
would spend. ``--timing`` measures real verification wall times with ``--workers`` processes instead.

The record (JSON) is written after every pile; re-running the same command resumes it (with more
``--piles`` it extends it). The full run (~1 CPU-minute a pile with f1 and f3; ``--workers`` piles at
once, each in its own process):

    .venv/bin/python bench/bench_verify.py --piles 500 --workers 2 --work-dir runs/verify-work \\
        --out runs/verify_real_test.json --md docs/results/verify/results.md --fig docs/results/verify/figure.png
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from experiments.measure import load_average

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
    from experiments.real_test import execute_on_truth
    from planner.errors import PlannerError
    from planner.inference import Objective, plan
    from reconstruct.pipeline import log_end_sigmas
    from planner.verify import PerturbationConfig, Verifier, VerifyConfig, perturbation_for_fits

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


def _init(model: str) -> None:
    import torch

    from planner.inference import load_planner
    from synth.common.processes import exit_with_parent

    exit_with_parent()
    torch.set_num_threads(1)
    _NET["net"] = load_planner(model, device="cpu")


def one_pile(seed: int, work_dir: str, logs, obstacles, objectives, ks, copies, n_float: int = 2) -> list[dict]:
    """Every variant on twin scan ``seed`` (made or reused in ``work_dir``); a failure is a row saying so."""
    from experiments.real_test import RealTestConfig, prepare_case

    net = _NET["net"]
    try:
        case = prepare_case(seed, work_dir, net.config, RealTestConfig(logs=tuple(logs), obstacles=tuple(obstacles),
                                                                        n_float=n_float))
        return pile_rows(case, net, objectives, ks, copies)
    except Exception as exc:  # a pile the generator or the twin could not make: said, not hidden
        return [{"seed": seed, "failure": f"{type(exc).__name__}: {exc}"}]


# -- the record ---------------------------------------------------------------------------------
def _write(path: Path, rec: dict) -> None:
    from synth.common.files import atomic_write_bytes

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, json.dumps(rec, indent=1, default=float).encode())


def run(args) -> dict:
    from planner.checkpoint import DEFAULT_MODEL
    from synth.common.files import sha256_file

    model = Path(args.model or DEFAULT_MODEL)
    config = {"piles": args.piles, "seed": args.seed, "logs": list(args.logs), "obstacles": list(args.obstacles),
              "objectives": list(args.objectives), "ks": list(args.ks), "copies": args.copies,
              "n_float": args.n_float, "model_sha256": sha256_file(model)}
    same = {k: v for k, v in config.items() if k != "piles"}
    rec = {"format": FORMAT, "format_version": VERSION, "config": config, "rows": [], "loads": []}
    if args.out.exists():
        old = json.loads(args.out.read_text())
        if {k: v for k, v in old.get("config", {}).items() if k != "piles"} != same:
            raise SystemExit(f"{args.out} holds another measurement (settings differ); choose another --out")
        rec["rows"], rec["loads"] = old["rows"], old.get("loads", [])
    done = {r["seed"] for r in rec["rows"]}
    args.work_dir.mkdir(parents=True, exist_ok=True)
    todo = [args.seed + k for k in range(args.piles) if args.seed + k not in done]
    print(f"{len(done)} piles done, {len(todo)} to go; load {load_average('')}", file=sys.stderr, flush=True)
    job = (str(args.work_dir), args.logs, args.obstacles, args.objectives, args.ks, args.copies, args.n_float)
    t0 = time.perf_counter()

    def keep(n: int, seed: int, rows: list[dict]) -> None:
        rec["rows"] += rows
        rec["loads"].append({"seed": seed, "load": load_average(''), "since_start_s": time.perf_counter() - t0,
                             "workers": args.workers})
        rec["config"]["piles"] = max(args.piles, rec["config"].get("piles", 0))
        _write(args.out, rec)
        print(f"pile {n}/{len(todo)} seed {seed}: {time.perf_counter() - t0:.0f} s so far, load {load_average('')}",
              file=sys.stderr, flush=True)

    if args.workers == 1:
        _init(str(model))
        for n, seed in enumerate(todo, 1):
            keep(n, seed, one_pile(seed, *job))
    elif todo:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn"), initializer=_init,
                                 initargs=(str(model),)) as pool:
            futures = {pool.submit(one_pile, seed, *job): seed for seed in todo}
            for n, f in enumerate(as_completed(futures), 1):
                keep(n, futures[f], f.result())
    return rec


# -- summary ------------------------------------------------------------------------------------
def paired(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """Difference of success rates b - a [pp] on the same piles, and its 95 % interval (standard
    error from the discordant piles, each count plus one half, as experiments.real_test.summarize)."""
    n = len(a)
    lo_b = float(((a == 1) & (b == 0)).sum()) + 0.5
    hi_c = float(((a == 0) & (b == 1)).sum()) + 0.5
    se = math.sqrt(max(lo_b + hi_c - (hi_c - lo_b) ** 2 / n, 0.0)) / n
    d = 100 * (b.mean() - a.mean())
    return d, d - 196 * se, d + 196 * se


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
        f"Command: `{command}`",
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
    for r in fails:
        lines.append(f"- seed {r['seed']}: {r['failure']}")
    return "\n".join(lines) + "\n"


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
def timing(args) -> list[dict]:
    """Planning + verification wall time on 6-7-log piles with ``--workers`` processes (a Verifier
    kept between piles, its workers started before the first), f3, no time budget."""
    import torch

    from experiments.real_test import RealTestConfig, prepare_case
    from planner.checkpoint import DEFAULT_MODEL
    from planner.inference import Objective, load_planner, plan
    from planner.verify import Verifier, VerifyConfig

    torch.set_num_threads(args.workers)
    net = load_planner(Path(args.model or DEFAULT_MODEL), device="cpu")
    cfg = RealTestConfig(logs=(7, 7), obstacles=tuple(args.obstacles))
    out = []
    for k in args.ks:
        with Verifier(VerifyConfig(k=k, workers=args.workers, time_budget_s=None)) as v:
            for n in range(args.timing):
                case = prepare_case(args.seed + 50_000 + n, args.work_dir, net.config, cfg)
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
                print(out[-1], file=sys.stderr, flush=True)
    return out


def main() -> None:
    from synth.common.ranges import parse_range

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--piles", type=int, default=40)
    ap.add_argument("--seed", type=int, default=700000)
    ap.add_argument("--logs", default="3-6")
    ap.add_argument("--obstacles", default="0-2")
    ap.add_argument("--objectives", default="f1,f3")
    ap.add_argument("--ks", default="4,8,16")
    ap.add_argument("--copies", type=int, default=3, help="perturbed copies in the '+copies' variants (0: none)")
    ap.add_argument("--model", default=None)
    ap.add_argument("--n-float", type=int, default=2,
                    help="RTK float ends per twin survey (2: the twin's default survey, as in the field; 0: all fixed)")
    ap.add_argument("--work-dir", type=Path, default=Path("runs/verify-work"))
    ap.add_argument("--out", type=Path, default=Path("runs/verify_real_test.json"))
    ap.add_argument("--md", type=Path, default=None, help="write the tables here")
    ap.add_argument("--fig", type=Path, default=None, help="draw success and time vs K here")
    ap.add_argument("--report-only", action="store_true", help="tables and figure from --out, nothing run")
    ap.add_argument("--timing", type=int, default=0, help="instead: real wall times on this many 7-log piles")
    ap.add_argument("--workers", type=int, default=1, help="processes (piles at once; with --timing: the verifier's)")
    args = ap.parse_args()
    args.logs, args.obstacles = parse_range(args.logs, "--logs"), parse_range(args.obstacles, "--obstacles")
    args.objectives = tuple(o.strip() for o in args.objectives.split(",") if o.strip())
    args.ks = tuple(int(k) for k in args.ks.split(","))
    if args.timing:
        rows = timing(args)
        _write(args.out.with_name(args.out.stem + "_timing.json"), {"rows": rows, "workers": args.workers})
        for k in args.ks:
            mine = [r for r in rows if r["k"] == k]
            if mine:
                print(f"K={k}: plan {np.median([r['plan_s'] for r in mine]):.2f} s + verify "
                      f"{np.median([r['verify_s'] for r in mine]):.2f} s median wall ({len(mine)} piles, "
                      f"{args.workers} workers), trials {np.mean([r['trials'] for r in mine]):.1f}")
        return
    rec = json.loads(args.out.read_text()) if args.report_only else run(args)
    command = "python " + " ".join(sys.argv)
    if args.md:
        args.md.parent.mkdir(parents=True, exist_ok=True)
        args.md.write_text(markdown(rec, command))
    if args.fig:
        figure(rec, args.fig)
    print(markdown(rec, command))


if __name__ == "__main__":
    main()
