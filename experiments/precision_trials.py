"""Paired twin trials of the planner in several number formats (bf16, int8, ...): the same piles, the
same trial code as the evaluation (:func:`planner.evaluate.evaluate_pile`), one planner per (precision,
objective), each chosen grasp tried once. A pile's records are written as soon as it is done, so a run
resumes; :func:`trials_markdown` pairs every precision with the first one.

    .venv/bin/python -m experiments.precision_trials --out DIR [--precisions bf16,int8,int8-bf16-top]
        [--per-cell 16] [--logs 5,6,7]
"""

from __future__ import annotations

import json
import random
from pathlib import Path

SEED_BASE = 950_000_000  # the piles of experiments.plan_choices and beyond (EvalConfig's seeds per cell)
BOOTSTRAP_DRAWS = 4000  # resamples of the paired differences for their 95 % interval [-]


def precision_trials(out_dir: str | Path, precisions=("bf16", "int8", "int8-bf16-top"), objectives=("f1", "f3"),
                     logs=(5, 6, 7), per_cell: int = 16, seed_base: int = SEED_BASE) -> Path:
    """Plan every pile of ``EvalConfig(logs, obstacles both ways, per_cell, seed_base)`` with the
    shipped model in each precision and objective and try each choice once; ``out_dir/pile-SEED.json``
    per pile (kept: a rerun skips it)."""
    from planner.checkpoint import DEFAULT_MODEL
    from planner.evaluate import EvalConfig, evaluate_pile
    from planner.inference import Objective, load_planner, plan
    from planner.planners import PlannerSpec
    from synth.common.files import atomic_write_bytes

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    planners = {p: load_planner(DEFAULT_MODEL, device="cpu", precision=p) for p in precisions}
    cfg = EvalConfig(logs=tuple(logs), obstacles=(False, True), per_cell=per_cell, seed_base=seed_base, trial="fast")
    specs, fns = [], {}
    for p in precisions:
        for obj in objectives:
            label = f"{p}/{obj}"
            specs.append(PlannerSpec("unet", model=str(DEFAULT_MODEL), objective=obj, label=label))

            def fn(obs, pile, p=p, obj=obj):
                r = plan(obs, planners[p], Objective(obj), pile=pile)
                return None if r.best is None else (r.best.grasp, tuple(r.best.targets))

            fns[label] = fn
    for task in cfg.tasks():
        path = out / f"pile-{task[3]}.json"
        if not path.exists():
            atomic_write_bytes(path, json.dumps(evaluate_pile(task, specs, cfg, planners=fns)).encode())
    return out


def read_trials(out_dir: str | Path) -> list[dict]:
    return [r for f in sorted(Path(out_dir).glob("pile-*.json")) for r in json.loads(f.read_text())]


def paired_rows(records: list[dict]) -> list[dict]:
    """Per (precision, objective): success, logs per success and, against the first precision on
    the same piles, piles won / lost and the paired difference [pp] with its bootstrap 95 % interval."""
    by = {(r["planner"], r["seed"]): r for r in records}
    piles = sorted({r["seed"] for r in records})
    labels = list(dict.fromkeys(r["planner"] for r in records))
    ref_prec = labels[0].split("/")[0]
    rows = []
    for label in labels:
        prec, obj = label.split("/")
        ok = [by[(label, s)]["outcome"] == "success" for s in piles]
        ref = [by[(f"{ref_prec}/{obj}", s)]["outcome"] == "success" for s in piles]
        logs = [len(by[(label, s)]["grasped"]) for s, o in zip(piles, ok) if o]
        diff = [int(a) - int(b) for a, b in zip(ok, ref)]
        rng = random.Random(0)
        boots = sorted(sum(rng.choice(diff) for _ in diff) / len(diff) for _ in range(BOOTSTRAP_DRAWS))
        rows.append({"precision": prec, "objective": obj, "piles": len(piles), "successes": sum(ok),
                     "logs_per_success": sum(logs) / max(len(logs), 1), "won": diff.count(1), "lost": diff.count(-1),
                     "diff_pp": 100 * sum(diff) / len(diff), "lo_pp": 100 * boots[int(0.025 * len(boots))],
                     "hi_pp": 100 * boots[int(0.975 * len(boots)) - 1], "reference": prec == ref_prec})
    return rows


def trials_markdown(rows: list[dict]) -> list[str]:
    lines = ["| precision | objective | success | logs / success | against the first: won / lost | paired pp (95 %) |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        pair = ("", "") if r["reference"] else (f"{r['won']} / {r['lost']}",
                                                f"{r['diff_pp']:+.1f} ({r['lo_pp']:+.1f}..{r['hi_pp']:+.1f})")
        lines.append(f"| {r['precision']} | {r['objective']} | {r['successes']}/{r['piles']} "
                     f"({100 * r['successes'] / r['piles']:.1f} %) | {r['logs_per_success']:.2f} | {pair[0]} | {pair[1]} |")
    return lines


if __name__ == "__main__":
    import argparse

    import torch

    ap = argparse.ArgumentParser(description="Paired twin trials of the planner in several precisions.")
    ap.add_argument("--out", required=True, help="folder of the per-pile records (a rerun resumes)")
    ap.add_argument("--precisions", default="bf16,int8,int8-bf16-top", help="the first is the reference")
    ap.add_argument("--per-cell", type=int, default=16, help="piles per (logs, obstacles) cell")
    ap.add_argument("--logs", default="5,6,7", help="pile sizes")
    a = ap.parse_args()
    torch.set_num_threads(1)
    out = precision_trials(a.out, tuple(a.precisions.split(",")), logs=tuple(int(n) for n in a.logs.split(",")),
                           per_cell=a.per_cell)
    print("\n".join(trials_markdown(paired_rows(read_trials(out)))))
