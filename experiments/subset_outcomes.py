"""How often the network's best grasp of a target subset succeeds in the twin, against its U and the
subset's size — and whether re-scoring subsets by a fitted success rate would choose better.

The objectives compare U *across* subsets (f1 takes the subset whose best pixel has the highest U),
but U is trained per pixel with positive pixels weighted (``u_pos_weight``), so it is no
probability. This harness measures it: on fresh piles (seeds apart from every test and training
pile) it plans every subset, takes the ``top_n`` best subsets by f1 and by f3, tries each one's
best grasp in the twin and keeps (pile, subset size, u, b, outcome) per trial, one record file per
pile (resumable). :func:`rescoring_check` then asks, with piles split in halves (fit on one, choose
on the other), whether a logistic map of (logit u, subset size) to success picks better grasps
than raw U does (docs/results/README.md, "subset-outcomes": it does not).

    .venv/bin/python -m experiments.subset_outcomes collect --model M --out runs/subset-outcomes --per-cell 20
    .venv/bin/python -m experiments.subset_outcomes sweep --model M --out runs/subset-sweep --per-cell 20
    .venv/bin/python -m experiments.subset_outcomes check runs/subset-outcomes --sweep runs/subset-sweep
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

SEED_BASE = 930_000_000  # these piles: apart from the test piles (900 M, 910 M) and the training seeds


@dataclass(frozen=True)
class CollectConfig:
    model: str  # checkpoint path
    per_cell: int = 20  # piles per (size, obstacles) cell [-]
    top_n: int = 4  # subsets tried per pile and objective (f1 order, f3 order; the union is tried) [-]
    seed_base: int = SEED_BASE

    def __post_init__(self) -> None:
        if self.per_cell < 1 or self.top_n < 1:
            raise ValueError(f"per_cell and top_n must be >= 1, got {self.per_cell}, {self.top_n}")


_NET: dict = {}  # this worker process's loaded planner, by checkpoint path


def _network(model: str):
    """The planner of ``model``, loaded once per worker process (one torch thread: workers share the cores)."""
    import torch

    from planner.inference import load_planner

    if model not in _NET:
        torch.set_num_threads(1)
        _NET[model] = load_planner(model)
    return _NET[model]


def collect_pile(task: tuple[int, bool, int, int], cfg: CollectConfig) -> list[dict]:
    """One pile: every subset planned, the best ``top_n`` by f1 and by f3 tried in the twin."""
    from planner.evaluate import EvalConfig, eval_scene
    from planner.inference import Objective, plan
    from synth.physics.trial import TrialConfig, run_trial

    pile, obs = eval_scene(task, EvalConfig(seed_base=cfg.seed_base))
    p = plan(obs, _network(cfg.model), Objective("f1"), pile=pile)
    f3 = Objective("f3")
    by_f3 = sorted(p.grasps, key=lambda g: -float(f3.quality(g.graspability, len(g.targets), g.balance)))
    tried = {g.targets: g for g in p.grasps[: cfg.top_n] + by_f3[: cfg.top_n]}
    trial = TrialConfig.preset("fast")
    out = []
    for rank, g in enumerate(sorted(tried.values(), key=lambda g: -g.graspability)):
        t0 = time.perf_counter()
        r = run_trial(pile, g.grasp, g.targets, trial)
        out.append({"seed": task[3], "n_logs": task[0], "obstacles": task[1], "tau": len(g.targets),
                    "targets": list(g.targets), "u": g.graspability, "b": g.balance, "rank_f1": rank,
                    "grasp": g.grasp.to_dict(), "outcome": r.outcome.value, "success": bool(r.success),
                    "cos_beta": float(r.cos_beta), "trial_s": time.perf_counter() - t0})
    return out


def collect(cfg: CollectConfig, out_dir: str | Path, workers: int = 2, fn=collect_pile) -> list[dict]:
    """Run (or resume) ``fn`` (:func:`collect_pile`, :func:`sweep_pile`) on every pile into
    ``out_dir/records``; returns every trial record."""
    from planner.evaluate import EvalConfig
    from synth.common.files import atomic_write_bytes
    from synth.common.runner import run_tasks

    out = Path(out_dir)
    (out / "records").mkdir(parents=True, exist_ok=True)
    meta = out / "collect.json"
    if meta.exists() and json.loads(meta.read_text()) != asdict(cfg):
        raise ValueError(f"{out} holds a collection with other parameters ({meta}); choose a new --out")
    atomic_write_bytes(meta, json.dumps(asdict(cfg), indent=1).encode())
    tasks = EvalConfig(seed_base=cfg.seed_base, per_cell=cfg.per_cell).tasks()
    todo = {t: (t, cfg) for t in tasks if not (out / "records" / f"{t[3]}.json").exists()}
    run_tasks(fn, todo, lambda t, recs: atomic_write_bytes(out / "records" / f"{t[3]}.json",
                                                                      json.dumps(recs).encode()), workers=workers)
    return read_records(out)


# the perturbation sweep: (what is changed, by how much) — width [m], shift along the closing axis [m], angle [deg]
SWEEP = (tuple(("width_m", d) for d in (-0.15, -0.10, -0.05, 0.0, 0.05, 0.10))
         + tuple(("shift_m", d) for d in (-0.10, -0.05, 0.05, 0.10)) + tuple(("angle_deg", d) for d in (-10, -5, 5, 10)))


def perturbed(grasp, kind: str, delta: float):
    """``grasp`` wider, shifted along its closing axis or turned by ``delta`` (:data:`SWEEP`)."""
    import math
    from dataclasses import replace

    from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M

    if kind == "width_m":
        return replace(grasp, width_m=float(min(max(grasp.width_m + delta, MIN_WIDTH_M), MAX_WIDTH_M)))
    if kind == "shift_m":
        return replace(grasp, x_m=grasp.x_m + delta * math.cos(grasp.phi_rad),
                       y_m=grasp.y_m + delta * math.sin(grasp.phi_rad))
    if kind == "angle_deg":
        return replace(grasp, phi_rad=grasp.phi_rad + math.radians(delta))
    raise ValueError(f"unknown perturbation {kind!r}: use one of {sorted({k for k, _ in SWEEP})}")


def sweep_pile(task: tuple[int, bool, int, int], cfg: CollectConfig) -> list[dict]:
    """The f1 choice of one pile tried as it is and perturbed by every entry of :data:`SWEEP`:
    is a failing grasp wrong in one direction (a bias a decoding offset would fix) or merely close
    to a boundary?"""
    from planner.evaluate import EvalConfig, eval_scene
    from planner.inference import Objective, plan
    from synth.physics.trial import TrialConfig, run_trial

    pile, obs = eval_scene(task, EvalConfig(seed_base=cfg.seed_base))
    best = plan(obs, _network(cfg.model), Objective("f1"), pile=pile, top_k=1).best
    trial = TrialConfig.preset("fast")
    out = []
    for kind, delta in SWEEP:
        r = run_trial(pile, perturbed(best.grasp, kind, delta), best.targets, trial)
        out.append({"seed": task[3], "n_logs": task[0], "obstacles": task[1], "tau": len(best.targets),
                    "u": best.graspability, "kind": kind, "delta": delta, "outcome": r.outcome.value,
                    "success": bool(r.success)})
    return out


def sweep_summary(records: list[dict]) -> dict:
    """Success per perturbation, and how many of the unperturbed failures each one turns to success."""
    base = {r["seed"]: r["success"] for r in records if r["kind"] == "width_m" and r["delta"] == 0.0}
    failed = {s for s, ok in base.items() if not ok}
    rows = {}
    for kind, delta in SWEEP:
        rs = [r for r in records if r["kind"] == kind and r["delta"] == delta]
        if rs:
            rows[f"{kind} {delta:+g}"] = {"success": float(np.mean([r["success"] for r in rs])),
                                         "rescued": sum(r["success"] for r in rs if r["seed"] in failed)}
    rescued_any = {r["seed"] for r in records if r["seed"] in failed and r["success"]}
    return {"piles": len(base), "failures": len(failed), "rescued_by_any": len(rescued_any), "rows": rows}


def read_records(out_dir: str | Path) -> list[dict]:
    return [r for f in sorted((Path(out_dir) / "records").glob("*.json")) for r in json.loads(f.read_text())]


def by_size(records: list[dict]) -> dict[int, dict]:
    """Per subset size: trials, success rate, and the top f1 choice's share and success rate."""
    out: dict[int, dict] = {}
    for tau in sorted({r["tau"] for r in records}):
        rs = [r for r in records if r["tau"] == tau]
        top = [r for r in rs if r["rank_f1"] == 0]
        out[tau] = {"trials": len(rs), "success": float(np.mean([r["success"] for r in rs])),
                    "f1_choices": len(top), "f1_choice_success": float(np.mean([r["success"] for r in top]))
                    if top else float("nan")}
    return out


def _logit(u) -> np.ndarray:
    u = np.clip(np.asarray(u, dtype=np.float64), 1e-6, 1 - 1e-6)
    return np.log(u) - np.log1p(-u)


def _design(records: list[dict], max_size: int = 6) -> np.ndarray:
    """Features (logit u, one indicator per subset size; sizes above ``max_size`` share the last)."""
    x = np.zeros((len(records), 1 + max_size))
    x[:, 0] = _logit([r["u"] for r in records])
    x[np.arange(len(records)), np.clip([r["tau"] for r in records], 1, max_size)] = 1.0
    return x


def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 0.5, iterations: int = 50) -> np.ndarray:
    """Ridge-penalised logistic regression by Newton's method (the penalty keeps it finite)."""
    theta = np.zeros(x.shape[1])
    for _ in range(iterations):
        p = 0.5 * (1.0 + np.tanh(0.5 * (x @ theta)))
        step = np.linalg.solve((x * (p * (1 - p))[:, None]).T @ x + l2 * np.eye(len(theta)),
                               x.T @ (y - p) - l2 * theta)
        theta += step
        if np.abs(step).max() < 1e-10:
            break
    return theta


def rescoring_check(records: list[dict], repeats: int = 20, seed: int = 0) -> dict[str, dict]:
    """Success and logs per success of the choice among each pile's tried subsets, by raw U (f1),
    raw U x tau^(1/3) (f2), and the same with U replaced by the fitted success rate; the fit is made
    on half the piles and the choice judged on the other half, over ``repeats`` random halvings."""
    piles: dict[int, list[dict]] = defaultdict(list)
    for r in records:
        piles[r["seed"]].append(r)
    seeds = np.array(sorted(piles))
    rng = np.random.default_rng(seed)
    scores: dict[str, list] = defaultdict(list)

    def judge(name, test, score):
        chosen = [max(piles[s], key=score) for s in test]
        ok = [c for c in chosen if c["success"]]
        scores[name].append((len(ok) / len(chosen), float(np.mean([c["tau"] for c in ok])) if ok else np.nan))

    for _ in range(repeats):
        perm = rng.permutation(seeds)
        for fit_on, test in ((perm[: len(perm) // 2], perm[len(perm) // 2:]),
                             (perm[len(perm) // 2:], perm[: len(perm) // 2])):
            rs = [r for s in fit_on for r in piles[s]]
            theta = fit_logistic(_design(rs), np.array([r["success"] for r in rs], dtype=float))
            p = lambda r: float(1 / (1 + np.exp(-(_design([r]) @ theta)[0])))  # noqa: E731
            judge("f1 raw U", test, lambda r: r["u"])
            judge("f1 fitted", test, p)
            judge("f2 raw U", test, lambda r: r["u"] * r["tau"] ** (1 / 3))
            judge("f2 fitted", test, lambda r: p(r) * r["tau"] ** (1 / 3))
    def mean(values) -> float:
        values = [v for v in values if v == v]  # halvings without a success have no logs per success
        return float(np.mean(values)) if values else float("nan")

    return {k: {"success": mean(v[0] for v in vs), "logs_per_success": mean(v[1] for v in vs)} for k, vs in scores.items()}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect", help="plan and try the top subsets of fresh piles")
    c.add_argument("--model", required=True)
    c.add_argument("--out", required=True)
    c.add_argument("--per-cell", type=int, default=20)
    c.add_argument("--top-n", type=int, default=4)
    c.add_argument("--workers", type=int, default=2)
    w = sub.add_parser("sweep", help="the f1 choice of each pile perturbed (width, shift, angle) and tried")
    for flag, kw in (("--model", {"required": True}), ("--out", {"required": True}),
                     ("--per-cell", {"type": int, "default": 20}), ("--workers", {"type": int, "default": 2})):
        w.add_argument(flag, **kw)
    k = sub.add_parser("check", help="per-size success and the cross-validated re-scoring check")
    k.add_argument("records")
    k.add_argument("--sweep", help="a sweep's folder to summarise too")
    a = ap.parse_args(argv)
    if a.cmd == "sweep":
        recs = collect(CollectConfig(a.model, a.per_cell), a.out, a.workers, fn=sweep_pile)
        print(json.dumps(sweep_summary(recs), indent=1))
        return
    recs = (collect(CollectConfig(a.model, a.per_cell, a.top_n), a.out, a.workers) if a.cmd == "collect"
            else read_records(a.records))
    print(json.dumps({"trials": len(recs), "piles": len({r["seed"] for r in recs}), "by_size": by_size(recs),
                      "rescoring": rescoring_check(recs) if a.cmd == "check" else None,
                      "sweep": sweep_summary(read_records(a.sweep)) if getattr(a, "sweep", None) else None}, indent=1))


if __name__ == "__main__":
    main()
