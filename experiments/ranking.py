"""Does U rank? The within-pile AUC and the calibration of the network's U on held-out piles.

A planner chooses one grasp per pile, so what matters is whether U orders the grasps *of one pile*:
on every pile, every subset is planned, the ``top_n`` best subsets by f1 and by f3 are tried in the
twin (the union, ~5 grasps; :func:`experiments.subset_outcomes.collect_pile`, one record file per
pile, resumable), and from those trials:

* **within-pile AUC**: over the piles with at least one success and one failure among the tried
  grasps, the share of (success, failure) pairs of the same pile in which the success has the
  higher U (ties count half), pooled over all pairs;
* **calibration**: the tried grasps binned by predicted U, each bin's mean U beside its observed
  success rate, and the expected calibration error (bin-size-weighted mean gap) and Brier score;
* **the choice**: the success of f1's and f3's top grasp, and of the best tried grasp (any success
  among them: what a perfect ranker of these grasps would reach).

Piles come from seeds ``seed_base`` on (default 930,000,000, subset-outcomes' piles; 940,000,000 for
fresh ones — both apart from every test and training pile).
``run`` writes ``ranking.json`` (format ``loggrasp.ranking``) and ``ranking.md`` beside the records;
``summarise`` computes the same from an existing folder of records (e.g. docs/results/subset-outcomes);
each also says whether the B head predicts the successful grasps' tilt (:func:`balance_agreement`)::

    .venv/bin/python -m experiments.ranking run --model M --out docs/results/ranking-v3 --per-cell 4 --workers 2
    .venv/bin/python -m experiments.ranking summarise docs/results/subset-outcomes
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

from experiments.subset_outcomes import SEED_BASE, CollectConfig, collect, read_records
from planner.errors import PlannerError
from synth.common.formats import VersionedJson

RANKING = VersionedJson("loggrasp.ranking", "1.0", "ranking record", ValueError)
#: edges of the calibration bins of predicted U [-] (the shipped model's U lies mostly in 0.9-1.0)
CALIBRATION_EDGES = (0.0, 0.5, 0.8, 0.9, 0.95, 0.98, 0.99, 1.0)


def _by_pile(records: list[dict]) -> dict[int, list[dict]]:
    piles: dict[int, list[dict]] = {}
    for r in records:
        piles.setdefault(int(r["seed"]), []).append(r)
    return piles


def within_pile_auc(records: list[dict], key: str = "u") -> dict:
    """Pooled within-pile AUC of ``key`` (see the module doc): ``auc`` (NaN with no mixed pile),
    ``pairs`` and ``piles`` (the mixed piles that give pairs)."""
    concordant, pairs, piles = 0.0, 0, 0
    for recs in _by_pile(records).values():
        s = np.array([r[key] for r in recs if r["success"]], dtype=np.float64)
        f = np.array([r[key] for r in recs if not r["success"]], dtype=np.float64)
        if not len(s) or not len(f):
            continue
        diff = s[:, None] - f[None, :]
        concordant += float((diff > 0).sum() + 0.5 * (diff == 0).sum())
        pairs += diff.size
        piles += 1
    return {"auc": concordant / pairs if pairs else float("nan"), "pairs": pairs, "piles": piles}


def calibration(records: list[dict], edges=CALIBRATION_EDGES, key: str = "u") -> dict:
    """Tried grasps binned by predicted ``key``: per bin its range, count, mean prediction and
    observed success rate; the expected calibration error and the Brier score over all of them."""
    u = np.array([r[key] for r in records], dtype=np.float64)
    ok = np.array([bool(r["success"]) for r in records], dtype=np.float64)
    rows, gap = [], 0.0
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        m = (u >= lo) & ((u < hi) if i < len(edges) - 2 else (u <= hi))
        n = int(m.sum())
        mean_u = float(u[m].mean()) if n else float("nan")
        rate = float(ok[m].mean()) if n else float("nan")
        if n:
            gap += n * abs(mean_u - rate)
        rows.append({"lo": lo, "hi": hi, "n": n, "mean_u": mean_u, "success": rate})
    n = len(u)
    return {"bins": rows, "ece": gap / n if n else float("nan"),
            "brier": float(np.mean((u - ok) ** 2)) if n else float("nan")}


def choices(records: list[dict], key: str = "u") -> dict:
    """Success of f1's top grasp, of f3's top grasp (f3 = u tau^(1/3) exp(-(b - 1)^2 / 0.25^2), u read
    from ``key``) and of the best tried grasp, over the piles."""
    from planner.inference import Objective

    f3 = Objective("f3")
    piles = _by_pile(records)
    top_f1 = [max(recs, key=lambda r: r[key])["success"] for recs in piles.values()]
    top_f3 = [max(recs, key=lambda r: float(f3.quality(r[key], r["tau"], r["b"])))["success"] for recs in piles.values()]
    n = len(piles)
    return {"piles": n, "f1_success": float(np.mean(top_f1)) if n else float("nan"),
            "f3_success": float(np.mean(top_f3)) if n else float("nan"),
            "best_tried_success": float(np.mean([any(r["success"] for r in recs) for recs in piles.values()]))
            if n else float("nan")}


def paired_choices(records: list[dict], a: str = "u", b: str = "p") -> dict:
    """Per objective, on how many piles the choice by ``b`` succeeds where the choice by ``a`` fails
    (``wins``) and the other way round (``losses``): the same tried grasps, paired."""
    from planner.inference import Objective

    f3 = Objective("f3")
    out = {}
    for obj in ("f1", "f3"):
        def top(recs, key):
            return max(recs, key=(lambda r: r[key]) if obj == "f1" else
                       (lambda r: float(f3.quality(r[key], r["tau"], r["b"]))))["success"]
        pairs = [(top(recs, a), top(recs, b)) for recs in _by_pile(records).values()]
        out[obj] = {"wins": sum(y and not x for x, y in pairs), "losses": sum(x and not y for x, y in pairs)}
    return out


def ranking_metrics(records: list[dict], key: str = "u") -> dict:
    """Every measure of the module doc from the trial records, of the score ``key`` ("u": the network's
    U; "p": a ranker's probability, :func:`rescore`)."""
    if not records:
        raise ValueError("no trial records to measure; run the collection first")
    return {"trials": len(records), "key": key, "auc": within_pile_auc(records, key),
            "calibration": calibration(records, key=key), "choice": choices(records, key)}


def balance_agreement(records: list[dict], key: str = "b") -> dict:
    """Does the B head predict the tilt? Over the successful grasps with a measured cos(beta): the
    predicted tilt (``key``, a cos(beta)) against the twin's, in degrees: means, mean absolute error and
    Spearman's rank correlation (f3 can only prefer better-balanced grasps where it is well above 0)."""
    from scipy.stats import spearmanr

    pairs = [(r[key], r["cos_beta"]) for r in records if r.get("success") and r.get("cos_beta") is not None
             and r.get(key) is not None]
    if len(pairs) < 3:
        return {"n": len(pairs), "pred_mean_deg": math.nan, "true_mean_deg": math.nan, "mae_deg": math.nan,
                "spearman": math.nan}
    pred, true = (np.degrees(np.arccos(np.clip(np.array(v, float), -1.0, 1.0))) for v in zip(*pairs))
    rho = spearmanr(pred, true)[0] if np.ptp(pred) > 0 and np.ptp(true) > 0 else math.nan
    return {"n": len(pairs), "pred_mean_deg": float(pred.mean()), "true_mean_deg": float(true.mean()),
            "mae_deg": float(np.abs(pred - true).mean()), "spearman": float(rho)}


def balance_markdown(a: dict, who: str) -> str:
    return (f"- balance, {who}: over {a['n']} successful grasps predicted beta {a['pred_mean_deg']:.1f} deg against "
            f"the twin's {a['true_mean_deg']:.1f} deg, mean absolute error {a['mae_deg']:.1f} deg, Spearman "
            f"{a['spearman']:.3f}")


def _pct(v: float) -> str:
    return "-" if v != v else f"{v * 100:.1f} %"


def ranking_markdown(m: dict, what: str, score: str | None = None) -> str:
    """The record ``m`` as a page; ``score`` names the measured score (default: from ``m["key"]``)."""
    a, c = m["auc"], m["choice"]
    score = score or {"u": "U", "p": "the ranker's p"}.get(m.get("key", "u"), m.get("key", "u"))
    lines = [f"# Ranking of {score} — {what}\n",
             f"{c['piles']} piles, {m['trials']} tried grasps (the top subsets by f1 and by f3 per pile).\n",
             f"- within-pile AUC of {score}: **{a['auc']:.3f}** ({a['pairs']} success/failure pairs on {a['piles']} piles "
             "with both)",
             f"- success of the choice: f1 {_pct(c['f1_success'])}, f3 {_pct(c['f3_success'])}; best tried grasp "
             f"{_pct(c['best_tried_success'])}",
             f"- calibration: ECE {m['calibration']['ece']:.3f}, Brier {m['calibration']['brier']:.3f}\n",
             f"| predicted {score} | grasps | mean {score} | observed success |", "|---|---|---|---|"]
    for b in m["calibration"]["bins"]:
        mean_u = "-" if b["mean_u"] != b["mean_u"] else f"{b['mean_u']:.3f}"
        lines.append(f"| [{b['lo']:g}, {b['hi']:g}{']' if b['hi'] == 1.0 else ')'} | {b['n']} | {mean_u} | "
                     f"{_pct(b['success'])} |")
    return "\n".join(lines) + "\n"


def run(model: str, out_dir: str | Path, per_cell: int, top_n: int = 4, workers: int = 2,
        seed_base: int = SEED_BASE) -> dict:
    """Collect (or resume) the trials of ``per_cell`` piles per cell and write the ranking record."""
    from synth.common.files import atomic_write_bytes, sha256_file

    cfg = CollectConfig(model=str(model), per_cell=per_cell, top_n=top_n, seed_base=seed_base)
    records = collect(cfg, out_dir, workers)
    m = ranking_metrics(records)
    out = Path(out_dir)
    from synth.physics.trial_spec import TRIAL_REVISION

    RANKING.write(out / "ranking.json", {"collect": asdict(cfg), "model_sha256": sha256_file(Path(model)),
                                         "trial_revision": TRIAL_REVISION, **m})
    atomic_write_bytes(out / "ranking.md", ranking_markdown(m, f"`{Path(model).name}`, seeds from {seed_base}").encode())
    return m


def rescore(records_dir: str | Path, ranker: str | Path | None = None, out: str | Path | None = None,
            model: str | Path | None = None) -> list[dict]:
    """The records of ``records_dir`` with ``p``, another scorer's value of each tried grasp on its
    pile's observation (the scene made again from the pile's seed): a ranker's success probability
    (``ranker``) or a U-Net's U at the grasp's centre (``model``, e.g. a model trained on outcome labels
    scoring the shipped model's grasps); written to ``out`` (one JSON list) when given."""
    from planner.evaluate import EvalConfig, eval_scene
    from synth.common.files import atomic_write_bytes
    from synth.geometry.grasp import Grasp

    if (ranker is None) == (model is None):
        raise ValueError("give exactly one scorer: --ranker or --model")
    collect_json = Path(records_dir) / "collect.json"
    if not collect_json.is_file():
        raise ValueError(f"{records_dir} has no collect.json: give the folder `ranking run --out` wrote "
                         "(not its records/ sub-folder)")
    if ranker is not None:
        from planner.ranker import load_ranker

        score = load_ranker(ranker).score
    else:
        from planner.inference import load_planner, maps_at

        pl = load_planner(model, device="cpu")

        def score(obs, grasps, targets):
            u, b = maps_at(obs, pl, grasps, targets)
            return [(ui, bi) for ui, bi in zip(u, b)]
    seed_base = json.loads(collect_json.read_text())["seed_base"]
    records = read_records(records_dir)
    for seed, recs in sorted(_by_pile(records).items()):
        _, obs = eval_scene((recs[0]["n_logs"], bool(recs[0]["obstacles"]), 0, seed), EvalConfig(seed_base=seed_base))
        p = score(obs, [Grasp(**{k: r["grasp"][k] for k in ("x_m", "y_m", "phi_rad", "width_m")}) for r in recs],
                  [r["targets"] for r in recs])
        for r, pi in zip(recs, p):
            if model is None:
                r["p"] = float(pi)
            else:  # the rescoring model's U, and its balance cos(beta) as b_p
                r["p"], r["b_p"] = float(pi[0]), float(pi[1])
    if out is not None:
        atomic_write_bytes(Path(out), json.dumps(records).encode())
    return records


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="plan and try the top subsets of held-out piles, then measure")
    r.add_argument("--model", required=True)
    r.add_argument("--out", required=True)
    r.add_argument("--per-cell", type=int, default=4, help="piles per (size 2-7, obstacles yes/no) cell")
    r.add_argument("--top-n", type=int, default=4)
    r.add_argument("--workers", type=int, default=2)
    r.add_argument("--seed-base", type=int, default=SEED_BASE, help="first pile seed (apart from test and training)")
    s = sub.add_parser("summarise", help="measure an existing folder of trial records")
    s.add_argument("records")
    q = sub.add_parser("rescore", help="score a folder's tried grasps with a ranker (or another U-Net's U) and "
                                         "measure that score, p")
    q.add_argument("records")
    who = q.add_mutually_exclusive_group(required=True)
    who.add_argument("--ranker", help="a ranker checkpoint (loggrasp train-ranker)")
    who.add_argument("--model", dest="scorer_model", help="a U-Net checkpoint: its U at each tried grasp's centre")
    q.add_argument("--out", default=None, help="write the records with p here (JSON)")
    a = ap.parse_args(argv)
    if a.cmd == "run":
        m = run(a.model, a.out, a.per_cell, a.top_n, a.workers, a.seed_base)
        what, score = a.out, None
    elif a.cmd == "rescore":
        try:
            records = rescore(a.records, a.ranker, a.out, model=a.scorer_model)
        except (ValueError, PlannerError) as exc:
            ap.error(str(exc))
        m = ranking_metrics(records, key="p")
        who = f"ranker {a.ranker}" if a.ranker else f"model {a.scorer_model}"
        what, score = f"{a.records}, {who}", "the ranker's p" if a.ranker else "the rescoring model's U"
        for obj, wl in paired_choices(records).items():
            print(f"- {obj}: the {who}'s choice succeeds where the records' U's fails on {wl['wins']} piles, fails "
                  f"where it succeeds on {wl['losses']}")
    else:
        m = ranking_metrics(read_records(a.records))
        what, score = a.records, None
    print(ranking_markdown(m, what, score))
    recs = records if a.cmd == "rescore" else read_records(a.records if a.cmd != "run" else a.out)
    print(balance_markdown(balance_agreement(recs), "the records' own B"))
    if a.cmd == "rescore" and a.scorer_model:
        print(balance_markdown(balance_agreement(recs, key="b_p"), "the rescoring model's B"))
    if not math.isfinite(m["auc"]["auc"]):
        print("no pile had both a success and a failure among its tried grasps: the AUC is undefined")


if __name__ == "__main__":
    main()
