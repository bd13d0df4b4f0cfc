"""Does planning clear of the obstacles the observation shows pay? The product's planner with and without
:attr:`planner.constraints.Constraints.clear_obstacles`, paired on fresh obstacle piles.

On every pile (the evaluation's obstacle cells, 2-7 logs, seeds from ``--seed-base``) both planners choose a
grasp per objective. Where they choose the same grasp on the same targets the outcome is the same (a twin trial
is a pure function of pile, grasp and targets) and nothing is tried; where they differ, both choices are tried
exactly. One record file per pile, written whole, so a stopped run resumes where it was. The summary, per
objective: the piles, the choices the switch changed, how many of those succeeded without and with it, and the
paired difference over all piles with its 95 % interval (:func:`experiments.measure.paired`)::

    .venv/bin/python -m experiments.obstacle_clearance --per-cell 40 --seed-base 980000000 \\
        --ranker planner/weights/ranker.safetensors --out runs/obstacle-clearance
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from experiments.measure import paired

OBJECTIVES = ("f1", "f3")
ROWS = ("as_is", "clear")  # the product's planner without and with clear_obstacles


def _choice(fn, obs, pile) -> dict | None:
    c = fn(obs, pile)
    return None if c is None else {"grasp": c[0].to_dict(), "targets": [int(t) for t in c[1]]}


def pile_record(task, planners: dict, eval_cfg) -> dict:
    """Both rows' choice per objective on pile ``task`` and, where they differ, both tried exactly."""
    from planner.evaluate import eval_scene
    from synth.geometry.grasp import Grasp
    from synth.physics.trial import TrialConfig, run_trial

    pile, obs = eval_scene(task, eval_cfg)
    trial_cfg = TrialConfig.preset(eval_cfg.trial)
    n_logs, _, k, seed = task
    rec = {"seed": seed, "n_logs": n_logs, "k": k}
    for obj in OBJECTIVES:
        a, b = (_choice(planners[(obj, row)], obs, pile) for row in ROWS)
        entry = {"as_is": a, "clear": b, "changed": a != b}
        if a != b:
            for row, c in (("as_is", a), ("clear", b)):
                entry[f"{row}_outcome"] = ("no_grasp" if c is None else
                                           run_trial(pile, Grasp(**c["grasp"]), c["targets"], trial_cfg).outcome.value)
        rec[obj] = entry
    return rec


def run(out_dir: str | Path, per_cell: int, seed_base: int, model: str, ranker: str | None) -> list[dict]:
    """Every pile's record (resumed from ``out_dir/records``), one process."""
    from planner.evaluate import EvalConfig
    from planner.planners import unet_planner
    from synth.common.files import atomic_write_text

    cfg = EvalConfig(obstacles=(True,), per_cell=per_cell, seed_base=seed_base)
    planners = {(obj, row): unet_planner(model, obj, ranker=ranker, clear_obstacles=row == "clear")
                for obj in OBJECTIVES for row in ROWS}
    folder = Path(out_dir, "records")
    folder.mkdir(parents=True, exist_ok=True)
    records = []
    for i, task in enumerate(cfg.tasks()):
        path = folder / f"{task[3]}.json"
        if not path.is_file():
            atomic_write_text(path, json.dumps(pile_record(task, planners, cfg)))
            print(f"{i + 1}/{len(cfg.tasks())} piles", flush=True)
        records.append(json.loads(path.read_text()))
    return records


def summarise(records: list[dict]) -> dict:
    """Per objective: piles, changed choices, their successes without / with the switch, the paired difference
    over all piles [pp] with its 95 % interval, and the targets of the changed choices that succeeded."""
    out = {}
    for obj in OBJECTIVES:
        entries = [r[obj] for r in records]
        changed = [e for e in entries if e["changed"]]
        a = [int(e.get("as_is_outcome") == "success") for e in entries]  # unchanged: 0 and 0, a tie
        b = [int(e.get("clear_outcome") == "success") for e in entries]
        d, lo, hi = paired(a, b) if entries else (float("nan"),) * 3
        logs = {row: [len(e[row]["targets"]) for e in changed if e.get(f"{row}_outcome") == "success"] for row in ROWS}
        out[obj] = {"piles": len(entries), "changed": len(changed), "as_is_successes": sum(a), "clear_successes": sum(b),
                    "difference_pp": d, "ci95_pp": (lo, hi),
                    "logs_per_success_changed": {row: float(np.mean(v)) if v else float("nan") for row, v in logs.items()}}
    return out


def markdown(summary: dict) -> str:
    lines = ["| objective | piles | choices changed | successes among them: as is / clear | paired difference [pp] "
             "(95 % CI) | logs per success among them: as is / clear |", "|---|---|---|---|---|---|"]
    for obj, s in summary.items():
        lp = s["logs_per_success_changed"]
        lines.append(f"| {obj} | {s['piles']} | {s['changed']} | {s['as_is_successes']} / {s['clear_successes']} | "
                     f"{s['difference_pp']:+.1f} ({s['ci95_pp'][0]:+.1f}..{s['ci95_pp'][1]:+.1f}) | "
                     f"{lp['as_is']:.2f} / {lp['clear']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    from planner.checkpoint import DEFAULT_MODEL

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the records (resumable) and summary.json")
    ap.add_argument("--per-cell", type=int, default=40, help="piles per obstacle cell (2-7 logs)")
    ap.add_argument("--seed-base", type=int, default=980_000_000, help="the piles' first seed")
    ap.add_argument("--model", default=str(DEFAULT_MODEL))
    ap.add_argument("--ranker", default=None, help="the ranker the product re-ranks with")
    a = ap.parse_args(argv)
    if a.per_cell < 1:
        ap.error(f"--per-cell must be >= 1, got {a.per_cell}")
    for flag, path in (("--model", a.model), ("--ranker", a.ranker)):
        if path is not None and not Path(path).is_file():
            ap.error(f"{flag}: no file {path}")
    summary = summarise(run(a.out, a.per_cell, a.seed_base, a.model, a.ranker))
    from synth.common.files import atomic_write_text

    atomic_write_text(Path(a.out, "summary.json"), json.dumps(summary, indent=1))
    print(markdown(summary))


if __name__ == "__main__":
    main()
