"""Rows of twin evaluations compared on the piles they share: each row's success, and every row's
difference from the first with its 95 % interval (paired over the same piles, so the piles' own
difficulty cancels). A row is ``FOLDER:PLANNER`` (a ``loggrasp eval`` results folder and a planner
name in it); the rows may come from different folders as long as they ran on the same seeds.

    .venv/bin/python -m experiments.paired_rows docs/results/eval-v3-verify:unet-f3 \\
        docs/results/eval-v3-views:unet-f3-views8k2 docs/results/eval-v3-verify:unet-f3-verify8
"""

from __future__ import annotations

import argparse
import functools
import json
import math
from pathlib import Path

import numpy as np

from experiments.measure import paired

PileKey = tuple[int, int, bool]  # (seed, logs, obstacles): a record's pile (the seed makes it; its index k in
# the cell depends on --seed-base, so runs from another --seed-base pair on the piles they share)


@functools.lru_cache(maxsize=8)
def _records(folder: Path) -> tuple[dict, ...]:
    """Every record of an eval folder, read once however many rows come from it."""
    return tuple(r for f in sorted(Path(folder, "records").glob("*.json")) for r in json.loads(f.read_text()))


def read_row(folder: Path, planner: str) -> dict[PileKey, dict]:
    """The records of ``planner`` in an eval folder, by pile. ``ValueError`` when it has none."""
    rows = {(int(r["seed"]), int(r["n_logs"]), bool(r["obstacles"])): r
            for r in _records(Path(folder)) if r["planner"] == planner}
    if not rows:
        raise ValueError(f"no records of planner {planner!r} in {folder}/records (see its results.md for the names)")
    return rows


def compare(rows: dict[str, dict[PileKey, dict]]) -> list[dict]:
    """Per row (in order) on the piles every row has: success, logs per success, beta, and the
    difference from the first row [pp] with its 95 % interval."""
    common = sorted(set.intersection(*(set(r) for r in rows.values())))
    if not common:
        raise ValueError("the rows share no pile: were they run on the same seeds (--seed-base, --per-cell)?")
    ok = {name: np.array([r[k]["outcome"] == "success" for k in common], dtype=float) for name, r in rows.items()}
    first = next(iter(ok.values()))
    out = []
    for name, r in rows.items():
        wins = [r[k] for k in common if r[k]["outcome"] == "success"]
        logs = float(np.mean([len(w["grasped"]) for w in wins])) if wins else math.nan
        betas = [math.degrees(math.acos(min(1.0, w["cos_beta"]))) for w in wins if w.get("cos_beta") is not None]
        d, lo, hi = paired(first, ok[name])
        out.append({"row": name, "piles": len(common), "success": 100 * ok[name].mean(), "logs": logs,
                    "beta_deg": float(np.mean(betas)) if betas else math.nan, "diff_pp": d, "ci_pp": (lo, hi),
                    "plan_s_median": float(np.median([r[k].get("plan_s") or 0.0 for k in common]))})
    return out


def markdown(table: list[dict]) -> str:
    lines = ["| row | piles | success | logs / success | β_avg | vs the first row [pp] (95 % CI) | plan s (median) |",
             "|---|---|---|---|---|---|---|"]
    for i, t in enumerate(table):
        diff = "-" if i == 0 else f"{t['diff_pp']:+.1f} ({t['ci_pp'][0]:+.1f}..{t['ci_pp'][1]:+.1f})"
        lines.append(f"| {t['row']} | {t['piles']} | {t['success']:.1f} % | {t['logs']:.2f} | {t['beta_deg']:.1f}° "
                     f"| {diff} | {t['plan_s_median']:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rows", nargs="+", metavar="FOLDER:PLANNER", help="the first row is the reference")
    a = ap.parse_args(argv)
    rows = {}
    for item in a.rows:
        folder, sep, planner = item.rpartition(":")
        if not sep or not folder or not planner:
            ap.error(f"a row is FOLDER:PLANNER, got {item!r}")
        try:
            rows[item] = read_row(Path(folder), planner)
        except ValueError as exc:
            ap.error(str(exc))
    try:
        print(markdown(compare(rows)))
    except ValueError as exc:
        ap.error(str(exc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
