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

``--compare claws`` pairs, both clear of obstacles, the footprint of the opening alone (the keep-out zones'
rectangle) against the claws' own (:attr:`planner.constraints.Constraints.claw_plate_m` and ``claw_width_m``
from the twin's grapple): the claws come down outside the opening, on plates 0.05 m thick and 0.22 m wide.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from experiments.measure import paired
from synth.geometry.grasp import RECT_WIDTH_M

OBJECTIVES = ("f1", "f3")
#: the two rows each comparison pairs, by ``--compare``: "switch", the product's planner without and with
#: clear_obstacles; "claws", with it, the obstacle footprint the opening alone against the claws' own footprint
#: (Constraints.claw_plate_m and claw_width_m from the twin's grapple, GrappleConfig)
COMPARISONS = {"switch": ("as_is", "clear"), "claws": ("clear", "claws")}
ROWS = COMPARISONS["switch"]


def row_constraints(row: str):
    """The planner's constraints of a row name."""
    from planner.constraints import Constraints
    from synth.physics.grapple import GrappleConfig

    if row == "as_is":
        return Constraints(clear_obstacles=False)
    if row == "clear":
        return Constraints(clear_obstacles=True, claw_plate_m=0.0, claw_width_m=RECT_WIDTH_M)
    if row == "claws":  # the product's default since docs/results/README.md, "obstacle-footprint"
        g = GrappleConfig()
        return Constraints(clear_obstacles=True, claw_plate_m=g.claw_thickness_m, claw_width_m=g.claw_width_m)
    raise ValueError(f"unknown row {row!r}; one of as_is, clear, claws")


def _choice(fn, obs, pile) -> dict | None:
    c = fn(obs, pile)
    return None if c is None else {"grasp": c[0].to_dict(), "targets": [int(t) for t in c[1]]}


def pile_record(task, planners: dict, eval_cfg, rows: tuple[str, str] = ROWS) -> dict:
    """Both rows' choice per objective on pile ``task`` and, where they differ, both tried exactly."""
    from planner.evaluate import eval_scene
    from synth.geometry.grasp import Grasp
    from synth.physics.trial import TrialConfig, run_trial

    pile, obs = eval_scene(task, eval_cfg)
    trial_cfg = TrialConfig.preset(eval_cfg.trial)
    n_logs, _, k, seed = task
    rec = {"seed": seed, "n_logs": n_logs, "k": k}
    for obj in OBJECTIVES:
        a, b = (_choice(planners[(obj, row)], obs, pile) for row in rows)
        entry = {rows[0]: a, rows[1]: b, "changed": a != b}
        if a != b:
            for row, c in zip(rows, (a, b)):
                entry[f"{row}_outcome"] = ("no_grasp" if c is None else
                                           run_trial(pile, Grasp(**c["grasp"]), c["targets"], trial_cfg).outcome.value)
        rec[obj] = entry
    return rec


def run(out_dir: str | Path, per_cell: int, seed_base: int, model: str, ranker: str | None,
        rows: tuple[str, str] = ROWS) -> list[dict]:
    """Every pile's record (resumed from ``out_dir/records``), one process."""
    from planner.evaluate import EvalConfig
    from planner.planners import unet_planner
    from synth.common.files import atomic_write_text

    cfg = EvalConfig(obstacles=(True,), per_cell=per_cell, seed_base=seed_base)
    planners = {(obj, row): unet_planner(model, obj, ranker=ranker, constraints=row_constraints(row))
                for obj in OBJECTIVES for row in rows}
    folder = Path(out_dir, "records")
    folder.mkdir(parents=True, exist_ok=True)
    records = []
    for i, task in enumerate(cfg.tasks()):
        path = folder / f"{task[3]}.json"
        if not path.is_file():
            atomic_write_text(path, json.dumps(pile_record(task, planners, cfg, rows)))
            print(f"{i + 1}/{len(cfg.tasks())} piles", flush=True)
        records.append(json.loads(path.read_text()))
    return records


def summarise(records: list[dict], rows: tuple[str, str] = ROWS) -> dict:
    """Per objective: piles, changed choices, their successes under each row, the paired difference (second
    row minus first) over all piles [pp] with its 95 % interval, and the targets of the changed choices that
    succeeded."""
    out = {}
    for obj in OBJECTIVES:
        entries = [r[obj] for r in records]
        changed = [e for e in entries if e["changed"]]
        a, b = ([int(e.get(f"{row}_outcome") == "success") for e in entries] for row in rows)  # unchanged: a tie
        d, lo, hi = paired(a, b) if entries else (float("nan"),) * 3
        logs = {row: [len(e[row]["targets"]) for e in changed if e.get(f"{row}_outcome") == "success"] for row in rows}
        out[obj] = {"piles": len(entries), "changed": len(changed), f"{rows[0]}_successes": sum(a),
                    f"{rows[1]}_successes": sum(b), "difference_pp": d, "ci95_pp": (lo, hi),
                    "logs_per_success_changed": {row: float(np.mean(v)) if v else float("nan") for row, v in logs.items()}}
    return out


def markdown(summary: dict, rows: tuple[str, str] = ROWS) -> str:
    names = " / ".join(r.replace("_", " ") for r in rows)
    lines = [f"| objective | piles | choices changed | successes among them: {names} | paired difference [pp] "
             f"(95 % CI) | logs per success among them: {names} |", "|---|---|---|---|---|---|"]
    for obj, s in summary.items():
        lp = s["logs_per_success_changed"]
        lines.append(f"| {obj} | {s['piles']} | {s['changed']} | {s[rows[0] + '_successes']} / "
                     f"{s[rows[1] + '_successes']} | {s['difference_pp']:+.1f} ({s['ci95_pp'][0]:+.1f}.."
                     f"{s['ci95_pp'][1]:+.1f}) | {lp[rows[0]]:.2f} / {lp[rows[1]]:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    from planner.checkpoint import DEFAULT_MODEL

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the records (resumable) and summary.json")
    ap.add_argument("--per-cell", type=int, default=40, help="piles per obstacle cell (2-7 logs)")
    ap.add_argument("--seed-base", type=int, default=980_000_000, help="the piles' first seed")
    ap.add_argument("--model", default=str(DEFAULT_MODEL))
    ap.add_argument("--ranker", default=None, help="the ranker the product re-ranks with")
    ap.add_argument("--compare", choices=sorted(COMPARISONS), default="switch",
                    help="switch: without and with clear_obstacles; claws: the opening's footprint against the claws'")
    a = ap.parse_args(argv)
    if a.per_cell < 1:
        ap.error(f"--per-cell must be >= 1, got {a.per_cell}")
    for flag, path in (("--model", a.model), ("--ranker", a.ranker)):
        if path is not None and not Path(path).is_file():
            ap.error(f"{flag}: no file {path}")
    rows = COMPARISONS[a.compare]
    summary = summarise(run(a.out, a.per_cell, a.seed_base, a.model, a.ranker, rows), rows)
    from synth.common.files import atomic_write_text

    atomic_write_text(Path(a.out, "summary.json"), json.dumps(summary, indent=1))
    print(markdown(summary, rows))


if __name__ == "__main__":
    main()
