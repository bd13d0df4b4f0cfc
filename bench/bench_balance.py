"""Balance of the twin's grasps: the distribution of β (the grapple's angle from vertical after the
lift) over the grasps Algorithm 1 accepts and over admissible off-centre grasps.

For each 4-log pile (seeds ``--seed0`` ..) and each of its 15 target subsets: the geometric
candidates (:func:`synth.data.candidates.generate_candidates`) are reduced by Algorithm 1
(:func:`synth.data.candidates.reduce_candidates`, at most ``--max-trials`` trials, the data set's
setting) with :func:`synth.physics.trial.run_trial` — the *accepted* grasps; and the two admissible
candidates farthest from the targets' centre of mass along the logs are tried as well — the
*off-centre* grasps. Writes a JSON record (resumed pile by pile) and, with ``--png``, a histogram.

    .venv/bin/python bench/bench_balance.py --piles 8 --out runs/balance_after.json
    .venv/bin/python bench/bench_balance.py --plot runs/balance_before.json runs/balance_after.json \
        --labels before,after --png docs/img/balance_hist.png
"""

from __future__ import annotations

import argparse
import json
import math
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np


def _offset_along_m(pile, targets, grasp) -> float:
    """Distance [m] from the grasp centre to the targets' centre of mass, along their mean axis."""
    cen = np.mean([pile.logs[i].centre_m[:2] for i in targets], axis=0)
    axes = []
    for i in targets:
        a, b = pile.logs[i].endpoints_m()
        d = (b - a)[:2]
        d = d / np.linalg.norm(d)
        axes.append(d if not axes or np.dot(d, axes[0]) >= 0 else -d)
    ax = np.mean(axes, axis=0)
    ax /= np.linalg.norm(ax)
    return abs(float(np.dot(np.array([grasp.x_m, grasp.y_m]) - cen, ax)))


def bench_pile(seed: int, max_trials: int, n_off: int) -> dict:
    """Accepted and off-centre grasps of one 4-log pile: per grasp its β [deg] and offset [m]
    (``max_trials`` 0 skips Algorithm 1: off-centre grasps only)."""
    from itertools import combinations

    from synth.data.candidates import generate_candidates, reduce_candidates
    from synth.errors import GenerationError
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.physics.trial import TrialConfig, run_trial

    try:
        pile, _ = generate_pile(seed, GenerationConfig(n_logs=4, n_obstacles=0))
    except GenerationError as exc:
        return {"seed": seed, "failed": str(exc)}
    cfg = TrialConfig.fast()
    rows = {"accepted": [], "off_centre": [], "subsets": 0, "negatives": 0, "trials": 0}
    for k in range(1, 5):
        for T in combinations(range(4), k):
            cands = generate_candidates(pile, T)
            rows["subsets"] += 1
            if max_trials > 0:
                rng = np.random.default_rng([seed, *T])
                res = reduce_candidates(cands, lambda g: run_trial(pile, g, T, cfg), rng=rng, max_trials=max_trials)
                rows["negatives"] += int(not res.accepted)
                rows["trials"] += res.n_trials
                for g, r in res.accepted:
                    rows["accepted"].append(_row(pile, T, g, r))
            far = sorted(cands, key=lambda g: -_offset_along_m(pile, T, g))[:n_off]
            for g in far:
                r = run_trial(pile, g, T, cfg)
                rows["trials"] += 1
                if r.outcome.ok:
                    rows["off_centre"].append(_row(pile, T, g, r))
    return {"seed": seed, **rows}


def _row(pile, T, g, r) -> dict:
    beta = math.degrees(math.acos(min(1.0, max(-1.0, r.cos_beta))))
    return {"targets": list(T), "beta_deg": beta, "offset_m": _offset_along_m(pile, T, g), "width_m": g.width_m}


def run(args) -> None:
    out = Path(args.out)
    rec = json.loads(out.read_text()) if out.exists() else {"piles": []}
    done = {p["seed"] for p in rec["piles"]}
    todo = [s for s in range(args.seed0, args.seed0 + args.piles) if s not in done]
    from synth.common.processes import exit_with_parent

    with ProcessPoolExecutor(max_workers=args.workers, initializer=exit_with_parent) as pool:
        for res in pool.map(bench_pile, todo, [args.max_trials] * len(todo), [args.off] * len(todo)):
            rec["piles"].append(res)
            tmp = out.with_suffix(".tmp")
            tmp.write_text(json.dumps(rec, indent=1))
            os.replace(tmp, out)
            print(f"pile {res['seed']}: {len(res.get('accepted', []))} accepted, "
                  f"{len(res.get('off_centre', []))} off-centre successes", flush=True)
    print(json.dumps(summary(rec), indent=1))


def summary(rec: dict) -> dict:
    piles = [p for p in rec["piles"] if "failed" not in p]
    s = {"piles": len(piles), "subsets": sum(p["subsets"] for p in piles),
         "negatives": sum(p["negatives"] for p in piles), "trials": sum(p["trials"] for p in piles)}
    s["negative_fraction"] = s["negatives"] / max(1, s["subsets"])
    for kind in ("accepted", "off_centre"):
        b = np.array([r["beta_deg"] for p in piles for r in p[kind]])
        s[kind] = {"n": int(b.size), "beta_mean_deg": float(b.mean()) if b.size else None,
                   "beta_median_deg": float(np.median(b)) if b.size else None,
                   "beta_p90_deg": float(np.percentile(b, 90)) if b.size else None}
    return s


def plot(paths: list[str], labels: list[str], png: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=False)
    bins = np.arange(0, 31, 1.0)
    for ax, kind, title in zip(axes, ("accepted", "off_centre"),
                               ("grasps Algorithm 1 accepted", "admissible off-centre grasps (successes)")):
        for path, label in zip(paths, labels):
            rec = json.loads(Path(path).read_text())
            b = [r["beta_deg"] for p in rec["piles"] if "failed" not in p for r in p[kind]]
            ax.hist(np.clip(b, 0, 30), bins=bins, alpha=0.55, label=f"{label} (n={len(b)}, mean {np.mean(b):.1f}°)")
        for ref, name in ((12, "paper f1 12°"), (6, "paper f3 6°")):
            ax.axvline(ref, color="k", lw=0.8, ls="--")
            ax.text(ref + 0.3, ax.get_ylim()[1] * 0.9, name, fontsize=8)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("balance angle β after the lift [deg]")
        ax.set_ylabel("grasps")
        ax.legend(fontsize=8)
    fig.suptitle("Twin balance on 4-log piles (fast trial preset)", fontsize=11)
    fig.tight_layout()
    fig.savefig(png, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--piles", type=int, default=8)
    ap.add_argument("--seed0", type=int, default=910000)
    ap.add_argument("--max-trials", type=int, default=16, help="Algorithm 1's cap; 0 = off-centre grasps only")
    ap.add_argument("--off", type=int, default=2, help="off-centre candidates tried per subset")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default="runs/balance.json")
    ap.add_argument("--plot", nargs="*", help="records to draw instead of running")
    ap.add_argument("--labels", default="")
    ap.add_argument("--png", default=None)
    args = ap.parse_args()
    if args.plot:
        plot(args.plot, args.labels.split(",") if args.labels else args.plot, args.png or "balance.png")
        return
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    run(args)


if __name__ == "__main__":
    main()
