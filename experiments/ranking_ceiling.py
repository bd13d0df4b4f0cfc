"""How well could a scorer order the network's own grasps? A reference for the ranker's within-pile AUC.

Each grasp of an on-policy round (:mod:`planner.onpolicy`) was tried exactly and ``repeats`` times
moved by the crane's positioning error. The repeats' success share is what a scorer would know that
judged each grasp's robustness perfectly but never saw the exact trial; its within-pile AUC against
the exact outcome (the label the evaluation judges) is what a ranker reaches that learnt each grasp's
robustness from its geometry perfectly (it could only go further by predicting the exact trial
itself). Near 0.5 the outcome is a lottery and no ranker can order it; near 1 the outcome is a
property of the grasp and a ranker's shortfall is the ranker's.

    .venv/bin/python -m experiments.ranking_ceiling data/rounds/r0 data/rounds/r1 data/rounds/r2

``--rescored FILE`` measures a scorer the same way instead: the records ``experiments.ranking rescore --out``
writes, ``--key`` (the ranker's ``p``, or the network's ``u``) against each tried grasp's outcome.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from planner.ranker_train import within_pile_auc
from synth.data.datastore import chunk_path, read_chunk, read_store


def round_grasps(store_dir: str | Path) -> dict[str, np.ndarray]:
    """Every tried grasp of a round with repeats: ``share`` (the repeats' success share), ``exact`` (1 for
    an exact success), ``pile`` (``ROUND/pile_id``) and ``outcome`` (the exact trial's)."""
    store = read_store(store_dir)
    if "onpolicy" not in store["params"]:
        raise ValueError(f"{store_dir} is not an on-policy round (loggrasp round): a data store repeats only its "
                         "exact successes, so its repeats say nothing about the failures")
    name = Path(store_dir).name
    rows = []
    for c in store["chunks"]:
        for p in read_chunk(chunk_path(store_dir, int(c["chunk"])), store["params_sha256"])["piles"]:
            for sub in p["subsets"]:
                for t in sub["trials"]:
                    reps = [r[4] == "success" for r in t.get("r") or []]
                    if reps:
                        pile = f"{name}/{p['pile_id']}"
                        rows.append((float(np.mean(reps)), float(t["o"] == "success"), pile, t["o"]))
    if not rows:
        raise ValueError(f"{store_dir} holds no trial with repeats (an on-policy round's store: loggrasp round)")
    share, exact, pile, outcome = zip(*rows)
    return {"share": np.array(share), "exact": np.array(exact), "pile": np.array(pile), "outcome": np.array(outcome)}


def rescored_grasps(path: str | Path, key: str = "p") -> dict[str, np.ndarray]:
    """The records of ``experiments.ranking rescore --out`` in :func:`round_grasps`' form, ``key`` as the score."""
    records = json.loads(Path(path).read_text())
    if not records or key not in records[0]:
        raise ValueError(f"{path}: no records with a {key!r} score (experiments.ranking rescore --out writes them)")
    return {"share": np.array([r[key] for r in records], float),
            "exact": np.array([float(r["outcome"] == "success") for r in records]),
            "pile": np.array([str(r["seed"]) for r in records]), "outcome": np.array([r["outcome"] for r in records])}


def ceiling(grasps: dict[str, np.ndarray]) -> dict:
    """The within-pile AUC of the repeats' share against the exact outcome, overall and per exact failure kind
    (successes against the failures of that kind)."""
    auc, pairs, piles = within_pile_auc(grasps["share"], grasps["exact"], grasps["pile"])
    by_kind = {}
    for kind in sorted(set(grasps["outcome"]) - {"success"}):
        sel = np.isin(grasps["outcome"], ["success", kind])
        a, n, _ = within_pile_auc(grasps["share"][sel], grasps["exact"][sel], grasps["pile"][sel])
        by_kind[kind] = {"auc": a, "pairs": n, "failures": int((grasps["outcome"] == kind).sum())}
    return {"grasps": int(len(grasps["exact"])), "success": float(grasps["exact"].mean()), "auc": auc,
            "pairs": pairs, "piles": piles, "by_failure": by_kind}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rounds", nargs="*", type=Path, help="on-policy round stores (loggrasp round --out)")
    ap.add_argument("--rescored", type=Path, action="append", default=[],
                    help="rescored records (experiments.ranking rescore --out) to measure by --key instead")
    ap.add_argument("--key", default="p", help="the rescored records' score: p (the ranker) or u (the network)")
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    a = ap.parse_args(argv)
    if not a.rounds and not a.rescored:
        ap.error("give round stores or --rescored FILE")
    rounds = {str(r): round_grasps(r) for r in a.rounds}
    result = {k: ceiling(g) for k, g in rounds.items()}
    if len(rounds) > 1:  # the rounds' piles are distinct; rescored files are not pooled (the same piles twice)
        keys = next(iter(rounds.values()))
        result["all rounds"] = ceiling({k: np.concatenate([g[k] for g in rounds.values()]) for k in keys})
    result.update({f"{r} ({a.key})": ceiling(rescored_grasps(r, a.key)) for r in a.rescored})
    if a.json:
        print(json.dumps(result, indent=1))
        return
    print("| grasps of | grasps | exact success | within-pile AUC of the score (pairs, piles) "
          "| by exact failure |")
    print("|---|---|---|---|---|")
    for k, m in result.items():
        kinds = "; ".join(f"{kind} {v['auc']:.3f} ({v['failures']})" for kind, v in m["by_failure"].items())
        print(f"| {k} | {m['grasps']} | {100 * m['success']:.1f} % | {m['auc']:.3f} ({m['pairs']}, {m['piles']}) "
              f"| {kinds} |")


if __name__ == "__main__":
    main()
