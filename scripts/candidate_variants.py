"""Candidate-rule variants against a store's own results: which rules refuse grasps that work?

Re-runs whole piles of a store (every target subset, the store's trial cap, trial preset and
robust labels) with ``CandidateConfig`` changed as a named variant asks, and prints one JSON line
per pile beside the stored result: negatives, trials (Algorithm 1 + repeats), capped and
no-candidate subsets, grasps, and the subsets lost / gained. docs/trials.md ("Negatives and the
candidate rules") reports the variants run on data/paper-v4's first piles.

    .venv/bin/python scripts/candidate_variants.py data/paper-v4 --piles 0-3 --variant B > runs/cand-B.jsonl

A variant's values are absolute, so the comparison holds only against a store built with the
rules it differs from (the store's ``candidate_config_values``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time

from synth.data.dataset import load_source_pile, new_chunk_stats, simulate_subsets
from synth.data.datastore import chunk_path, open_store, read_chunk

VARIANTS = {
    "A": dict(end_margin_m=0.15, claw_clearance_m=0.0, under_tolerance_m=0.20, max_dphi_rad=math.radians(45), n_phi=9),
    "B": dict(end_margin_m=0.15, under_tolerance_m=0.20, max_dphi_rad=math.radians(45), n_phi=9),
    "revision4": dict(end_margin_m=0.30, under_tolerance_m=0.10, max_dphi_rad=math.radians(30), n_phi=7),
}


class _Job:
    """The store's job with another candidate configuration."""

    def __init__(self, job, candidates):
        self._job, self._candidates = job, candidates

    def candidate_config(self):
        return self._candidates

    def __getattr__(self, name):
        return getattr(self._job, name)


def _pile_range(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def compare_pile(store: str, job, variant_job, k: int) -> dict:
    stored = read_chunk(chunk_path(store, k))["piles"][0]["subsets"]
    pile, _obs, _pid, _info = load_source_pile(job, k)
    stats = new_chunk_stats()
    t0 = time.process_time()
    subsets = simulate_subsets(variant_job, k, pile, None, stats)
    return dict(pile=k, cpu_s=round(time.process_time() - t0, 1),
                neg_old=sum(not s["accepted"] for s in stored), neg_new=sum(not s.accepted for s in subsets),
                trials_old=sum(len(s["trials"]) + sum(len(t.get("r", [])) for t in s["trials"]) for s in stored),
                trials_new=stats["trials"] + stats["repeats"],
                capped_old=sum(bool(s["capped"]) for s in stored), capped_new=stats["capped_subsets"],
                nocand_old=sum(s["candidates"] == 0 for s in stored), nocand_new=stats["no_candidate_subsets"],
                grasps_old=sum(len(s["accepted"]) for s in stored), grasps_new=stats["grasps"],
                lost=[list(s.targets) for s, o in zip(subsets, stored) if o["accepted"] and not s.accepted],
                gained=[list(s.targets) for s, o in zip(subsets, stored) if not o["accepted"] and s.accepted])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("store", help="a store folder (loggrasp synth dataset --store)")
    ap.add_argument("--piles", default="0-3", help="pile range, e.g. 0-3")
    ap.add_argument("--variant", choices=sorted(VARIANTS), required=True)
    args = ap.parse_args()
    job, _chunks, _summary = open_store(args.store)
    variant_job = _Job(job, dataclasses.replace(job.candidate_config(), **VARIANTS[args.variant]))
    for k in _pile_range(args.piles):
        print(json.dumps({"variant": args.variant, **compare_pile(args.store, job, variant_job, k)}), flush=True)


if __name__ == "__main__":
    main()
