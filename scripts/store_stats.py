"""The statistics of a committed grasp store beside the paper's ("Synthetic data set"):

    .venv/bin/python scripts/store_stats.py data/paper-v3

Prints a Markdown table. The paper: 604 piles of 4 logs -> 5,491 grasp-map samples (of 9,060
subsets) after removing "samples that displayed unphysical behavior or unstable log
configurations", 12,124 grasps, 2,039 samples without a successful grasp (37 %).
"""

from __future__ import annotations

import sys
from collections import Counter

from synth.data.datastore import chunk_path, open_store, read_chunk

PAPER = {"piles": 604, "subsets": 604 * 15, "samples": 5491, "grasps": 12124, "negatives": 2039}


def stats(store_dir: str) -> dict:
    job, chunks, store = open_store(store_dir)
    c: Counter = Counter()
    outcomes: Counter = Counter()
    for k in sorted(chunks):
        rec = read_chunk(chunk_path(store_dir, k), store["params_sha256"])
        for p in rec["piles"]:
            c["piles"] += 1
            c["obstacle_piles"] += int(p.get("obstacles", 0) > 0)
            for s in p["subsets"]:
                c["subsets"] += 1
                has_cand = s.get("candidates", len(s["trials"])) > 0
                c["with_candidates"] += int(has_cand)
                c["negatives"] += int(not s["accepted"])
                c["negatives_with_candidates"] += int(has_cand and not s["accepted"])
                c["grasps"] += len(s["accepted"])
                c["trials"] += len(s["trials"])
                outcomes.update(t["o"] for t in s["trials"])
    return {"counts": dict(c), "outcomes": dict(outcomes)}


def table(s: dict) -> str:
    c, o = s["counts"], s["outcomes"]
    pos = c["subsets"] - c["negatives"]
    n_tr = max(c["trials"], 1)
    rows = [
        ("piles (with obstacles)", f"{c['piles']} ({c['obstacle_piles']})", "604 (a third)"),
        ("target subsets", c["subsets"], "9,060"),
        ("subsets with >= 1 admissible candidate", f"{c['with_candidates']} ({100 * c['with_candidates'] / c['subsets']:.1f} %)",
         "5,491 samples kept (60.6 %)"),
        ("negatives, all subsets", f"{c['negatives']} ({100 * c['negatives'] / c['subsets']:.1f} %)", ""),
        ("negatives among subsets with candidates",
         f"{c['negatives_with_candidates']} ({100 * c['negatives_with_candidates'] / max(c['with_candidates'], 1):.1f} %)",
         "2,039 of 5,491 (37.1 %)"),
        ("grasps (per positive subset)", f"{c['grasps']} ({c['grasps'] / max(pos, 1):.2f})", "12,124 (3.51)"),
        ("trials (per pile)", f"{c['trials']} ({c['trials'] / max(c['piles'], 1):.0f})", "not given"),
    ] + [(f"trial outcome: {k}", f"{v} ({100 * v / n_tr:.1f} %)", "") for k, v in sorted(o.items(), key=lambda kv: -kv[1])]
    lines = ["| | this store | the paper |", "|---|---|---|"] + [f"| {a} | {b} | {p} |" for a, b, p in rows]
    return "\n".join(lines)


if __name__ == "__main__":
    print(table(stats(sys.argv[1] if len(sys.argv) > 1 else "data/paper-v3")))
