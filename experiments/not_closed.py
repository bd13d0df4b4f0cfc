"""What the planners' NOT_CLOSED choices are, and what a change of the trial would make of them.

Every distinct choice (pile, targets, grasp) in a ``loggrasp eval`` folder whose trial ended
NOT_CLOSED is tried again in the twin — with the trial as it is (a check that the record
reproduces) or with ``--set FIELD=VALUE`` overrides of :class:`synth.physics.trial_spec.TrialConfig`
(e.g. ``max_closed_gap_m=0.6`` lifts whatever the claws closed on; ``inside_radius_frac=2`` lowers
the grapple deeper before closing). ``--successes N`` adds N of the folder's successful choices
(drawn at random) and ``--others`` its other failures, so that a change is judged on what it
breaks as well as on what it mends. Each row keeps the final tip gap, the lowering's stop reason
and the thinnest target's diameter.

    .venv/bin/python -m experiments.not_closed docs/results/eval-ranker-r1-970 --out REC.json \\
        [--set max_closed_gap_m=0.6] [--successes 60] [--others]
"""

from __future__ import annotations

import argparse
import collections
import json
import random
from dataclasses import fields, replace
from pathlib import Path


def choices(folder: Path) -> list[dict]:
    """The distinct choices of every planner in an eval folder: one per (pile, targets, grasp)."""
    out, seen = [], set()
    for f in sorted(Path(folder, "records").glob("*.json")):
        for r in json.loads(f.read_text()):
            if r.get("grasp") is None:
                continue
            g = r["grasp"]
            key = (r["seed"], tuple(r["targets"]), round(g["x_m"], 5), round(g["y_m"], 5), round(g["phi_rad"], 5))
            if key not in seen:
                seen.add(key)
                out.append(r)
    if not out:
        raise ValueError(f"no records with a grasp in {folder}/records")
    return out


def trial_config(preset: str, overrides: dict[str, float]):
    """The eval's trial preset with ``overrides`` (TrialConfig's numeric fields); ValueError names a wrong one."""
    from synth.physics.trial_spec import TrialConfig

    base = TrialConfig.careful() if preset == "careful" else TrialConfig.fast()
    numeric = {f.name for f in fields(TrialConfig) if isinstance(getattr(base, f.name), (int, float))}
    bad = sorted(set(overrides) - numeric)
    if bad:
        raise ValueError(f"--set {bad[0]}: not a numeric TrialConfig field (one of {', '.join(sorted(numeric))})")
    return replace(base, **overrides)


def select(rows: list[dict], successes: int, others: bool, seed: int) -> list[tuple[str, dict]]:
    """(tag, record): every NOT_CLOSED choice, ``successes`` successful ones at random, other failures."""
    nc = [("not_closed", r) for r in rows if r["outcome"] == "not_closed"]
    ok = [r for r in rows if r["outcome"] == "success"]
    random.Random(seed).shuffle(ok)
    rest = [("other", r) for r in rows if r["outcome"] not in ("success", "not_closed", "no_grasp")] if others else []
    return nc + [("success", r) for r in ok[:successes]] + rest


def rerun(conf: dict, picked: list[tuple[str, dict]], trial_cfg, progress=print) -> list[dict]:
    """Each picked choice tried again on its regenerated pile (``conf``: the eval's configuration, its
    eval.json's "config") with ``trial_cfg``."""
    from planner.evaluate import EvalConfig, eval_pile
    from synth.geometry.grasp import Grasp
    from synth.physics.trial import run_trial

    ecfg = EvalConfig(max_obstacles=int(conf["max_obstacles"]))
    piles, out = {}, []
    for i, (tag, r) in enumerate(picked):
        task = (int(r["n_logs"]), bool(r["obstacles"]), int(r["k"]), int(r["seed"]))
        if task not in piles:
            piles[task] = eval_pile(task, ecfg)
        pile = piles[task]
        res = run_trial(pile, Grasp(**r["grasp"]), tuple(r["targets"]), trial_cfg)
        out.append({"tag": tag, "seed": r["seed"], "planner": r["planner"], "n_targets": len(r["targets"]),
                    "width_m": r["grasp"]["width_m"], "was": r["outcome"], "now": res.outcome.value,
                    "final_gap_m": res.final_gap_m, "stop_reason": res.stop_reason,
                    "thinnest_target_m": min(pile.logs[t].diameter_m for t in r["targets"]),
                    "enclosed": list(res.enclosed), "cpu_s": res.cpu_time_s})
        progress(f"{i + 1}/{len(picked)} {r['seed']} {tag}: {r['outcome']} -> {res.outcome.value} "
                 f"(gap {res.final_gap_m:.2f} m, stop {res.stop_reason})")
    return out


def summary(rows: list[dict]) -> str:
    """Markdown: per tag, how many choices went from which outcome to which."""
    lines = ["| choices | was | now | count |", "|---|---|---|---|"]
    for (tag, was, now), n in sorted(collections.Counter((r["tag"], r["was"], r["now"]) for r in rows).items()):
        lines.append(f"| {tag} | {was} | {now} | {n} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="a loggrasp eval results folder (eval.json, records/)")
    ap.add_argument("--out", type=Path, required=True, help="the record to write (JSON)")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="a TrialConfig override (repeatable)")
    ap.add_argument("--successes", type=int, default=0, help="successful choices to add, drawn at random")
    ap.add_argument("--others", action="store_true", help="add the other failures")
    ap.add_argument("--seed", type=int, default=0, help="the draw of the successful choices")
    a = ap.parse_args(argv)
    try:
        overrides = {k: float(v) for k, v in (s.split("=", 1) for s in a.set)}
    except ValueError:
        ap.error(f"--set takes FIELD=NUMBER, got {a.set}")
    try:
        conf = json.loads(Path(a.folder, "eval.json").read_text())["config"]
        cfg = trial_config(conf.get("trial", "fast"), overrides)
        picked = select(choices(a.folder), a.successes, a.others, a.seed)
    except (OSError, KeyError, ValueError) as e:
        ap.error(str(e))
    rows = rerun(conf, picked, cfg)
    from synth.common.files import atomic_write_bytes

    atomic_write_bytes(a.out, json.dumps({"folder": str(a.folder), "overrides": overrides, "successes": a.successes,
                                          "others": a.others, "seed": a.seed, "rows": rows}, indent=1).encode())
    print(summary(rows))


if __name__ == "__main__":
    main()
