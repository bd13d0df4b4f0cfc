"""The statistics of committed grasp stores side by side, and the paper's ("Synthetic data set"):

    .venv/bin/python scripts/store_stats.py data/paper-v4 data/paper-v3

Prints a Markdown table, one column per store. The paper: 604 piles of 4 logs -> 5,491 grasp-map
samples (of 9,060 subsets) after removing "samples that displayed unphysical behavior or unstable
log configurations", 12,124 grasps, 2,039 samples without a successful grasp (37 %). A store with
robust labels (trial revision 4 on) also shows its repeats: each accepted grasp tried again under
the field's positioning error, and the negatives split into proven (every candidate tried) and
capped (the trial cap stopped the search: untested).
"""

from __future__ import annotations

import math
import sys
from collections import Counter

import numpy as np

from synth.data.datastore import chunk_path, open_store, read_chunk
from synth.scene.pile import PileSpec

NEAR_END_M = 0.30  # a crossing this near a target's end is "near the end" (the revision-4 rules' end margin) [m]

PAPER = {"piles": 604, "subsets": 604 * 15, "samples": 5491, "grasps": 12124, "negatives": 2039}


def end_distance_m(pile: PileSpec, targets, grasp) -> float:
    """How far the grasp's closing line crosses the nearest target end [m] (along that target's axis)."""
    x, y, phi = grasp[0], grasp[1], grasp[2]
    a = np.array([math.cos(phi), math.sin(phi)])
    best = math.inf
    for i in targets:
        e0, e1 = (np.asarray(v[:2], dtype=float) for v in pile.logs[i].endpoints_m())
        length = float(np.linalg.norm(e1 - e0))
        u = (e1 - e0) / length
        m = np.array([a, -u]).T
        if abs(np.linalg.det(m)) < 1e-9:  # closing along the log: no crossing
            continue
        _, r = np.linalg.solve(m, e0 - np.array([x, y]))
        best = min(best, min(r, length - r))
    return best


def stats(store_dir: str) -> dict:
    job, chunks, store = open_store(store_dir)
    c: Counter = Counter()
    outcomes: Counter = Counter()
    repeats: Counter = Counter()
    for k in sorted(chunks):
        rec = read_chunk(chunk_path(store_dir, k), store["params_sha256"])
        for p in rec["piles"]:
            pile = PileSpec.from_dict(p["pile"])
            c["piles"] += 1
            c["obstacle_piles"] += int(p.get("obstacles", 0) > 0)
            for s in p["subsets"]:
                c["subsets"] += 1
                has_cand = s.get("candidates", len(s["trials"])) > 0
                c["with_candidates"] += int(has_cand)
                c["negatives"] += int(not s["accepted"])
                c["negatives_with_candidates"] += int(has_cand and not s["accepted"])
                c["capped_negatives"] += int(has_cand and not s["accepted"] and bool(s.get("capped")))
                c["grasps"] += len(s["accepted"])
                c["trials"] += len(s["trials"])
                c["unconfirmed"] += int(s.get("unconfirmed", 0))
                outcomes.update(t["o"] for t in s["trials"])
                for t in s["trials"]:
                    repeats.update(r[4] for r in t.get("r", ()))
                    band = "near" if end_distance_m(pile, s["targets"], t["g"]) < NEAR_END_M else "far"
                    c[f"{band}_trials"] += 1
                    c[f"{band}_dropped"] += int(t["o"] == "dropped")
    return {"counts": dict(c), "outcomes": dict(outcomes), "repeats": dict(repeats),
            "trial_revision": store["params"].get("trial_revision"), "labels": {
                k: store["params"].get(k) for k in ("label_repeats", "label_sigma_xy_m", "label_sigma_phi_deg",
                                                   "label_min_fraction")}}


def _pct(a: int, b: int) -> str:
    return f"{a} ({100 * a / b:.1f} %)" if b else f"{a}"


def column(s: dict) -> dict[str, str]:
    c, o, r = Counter(s["counts"]), s["outcomes"], s["repeats"]
    pos = c["subsets"] - c["negatives"]
    n_tr, n_rep = c["trials"], sum(r.values())
    neg_c = c["negatives_with_candidates"]
    lab = s["labels"]
    col = {
        "trial revision; labels": f"{s['trial_revision']}; " + (
            f"{lab['label_repeats']} repeats at σ {100 * lab['label_sigma_xy_m']:g} cm, {lab['label_sigma_phi_deg']:g}°, "
            f"accepted >= {lab['label_min_fraction']:g}" if lab.get("label_repeats") else "one exact success"),
        "piles (with obstacles)": f"{c['piles']} ({c['obstacle_piles']})",
        "target subsets": str(c["subsets"]),
        "subsets with >= 1 admissible candidate": _pct(c["with_candidates"], c["subsets"]),
        "negatives, all subsets": _pct(c["negatives"], c["subsets"]),
        "negatives among subsets with candidates": _pct(neg_c, c["with_candidates"]),
        "... of those proven (every candidate tried)": _pct(neg_c - c["capped_negatives"], neg_c),
        "... of those capped (untested)": _pct(c["capped_negatives"], neg_c),
        "grasps (per positive subset)": f"{c['grasps']} ({c['grasps'] / max(pos, 1):.2f})",
        "Algorithm 1 trials (per pile)": f"{n_tr} ({n_tr / max(c['piles'], 1):.0f})",
        "exact successes refused by their repeats": str(c["unconfirmed"]) if n_rep else "—",
        "repeats (per pile); success": (f"{n_rep} ({n_rep / max(c['piles'], 1):.0f}); "
                                        f"{100 * r.get('success', 0) / n_rep:.1f} %") if n_rep else "—",
        "DROPPED, all trials and repeats": _pct(o.get("dropped", 0) + r.get("dropped", 0), n_tr + n_rep),
        f"DROPPED, trials crossing a target < {NEAR_END_M:.2f} m from its end": (
            f"{_pct(c['near_dropped'], c['near_trials'])} of {c['near_trials']}"),
        f"DROPPED, trials crossing every target >= {NEAR_END_M:.2f} m from its ends": (
            f"{_pct(c['far_dropped'], c['far_trials'])} of {c['far_trials']}"),
    }
    for k in ("success", "collision", "dropped", "not_closed", "more_than_intended", "fewer_or_other"):
        col[f"trial outcome: {k}"] = _pct(o.get(k, 0), n_tr)
    return col


PAPER_COLUMN = {
    "piles (with obstacles)": "604 (a third)", "target subsets": "9,060",
    "subsets with >= 1 admissible candidate": "5,491 samples kept (60.6 %)",
    "negatives among subsets with candidates": "2,039 of 5,491 (37.1 %)", "grasps (per positive subset)": "12,124 (3.51)",
    "Algorithm 1 trials (per pile)": "not given",
}


def table(stores: dict[str, dict]) -> str:
    cols = {name: column(s) for name, s in stores.items()}
    rows = list(next(iter(cols.values())))
    head = "| | " + " | ".join(cols) + " | the paper |"
    lines = [head, "|---" * (len(cols) + 2) + "|"]
    for row in rows:
        lines.append(f"| {row} | " + " | ".join(c.get(row, "") for c in cols.values()) + f" | {PAPER_COLUMN.get(row, '')} |")
    return "\n".join(lines)


if __name__ == "__main__":
    dirs = sys.argv[1:] or ["data/paper-v3"]
    print(table({d: stats(d) for d in dirs}))
