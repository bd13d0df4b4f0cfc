"""How far can a successful grasp's centre move and still succeed? (Why U marks a 20 cm region.)

Takes accepted grasps of a data set, moves each centre along its closing axis and across it, and
re-runs the grasp trial (fast preset) on the stored pile:

    .venv/bin/python scripts/grasp_offsets.py data/train-v2 --shards 14 --fraction 0.25
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

SHIFTS = [(0.0, 0.0), (0.1, 0.0), (0.2, 0.0), (0.3, 0.0), (0.0, 0.1), (0.0, 0.2), (0.0, 0.3)]  # (along, across) [m]


def _trial(args) -> tuple[float, float, bool]:
    from synth.geometry.grasp import Grasp
    from synth.scene.pile import read_pile
    from synth.physics.trial import TrialConfig, run_trial

    pile_path, (x, y, phi, w), subset, along, across = args
    g = Grasp(x, y, phi, w)
    a = g.closing_axis()
    cx, cy = np.array([x, y]) + along * a + across * np.array([-a[1], a[0]])
    r = run_trial(read_pile(pile_path), Grasp(float(cx), float(cy), phi, w), subset, TrialConfig.fast())
    return along, across, r.outcome.name == "SUCCESS"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path)
    ap.add_argument("--shards", type=int, default=14, help="first N shards (sorted by name)")
    ap.add_argument("--fraction", type=float, default=0.25, help="share of positive subsets used")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from synth.data.shards import load_shard

    rng = np.random.default_rng(args.seed)
    jobs = []
    for shard in sorted(args.data.glob("shard_*.npz"))[: args.shards]:
        seen = set()
        for s in load_shard(shard):
            key = (s.pile_id, s.subset)
            if s.negative or key in seen:
                continue
            seen.add(key)
            pile = args.data / "piles" / f"{s.pile_id}.json"
            if rng.random() > args.fraction or not pile.exists():
                continue
            jobs += [(pile, tuple(float(v) for v in s.grasps[0][:4]), s.subset, da, db) for da, db in SHIFTS]
    res = defaultdict(list)
    with ProcessPoolExecutor(args.workers) as ex:
        for along, across, ok in ex.map(_trial, jobs, chunksize=4):
            res[(along, across)].append(ok)
    print("| centre moved along the closing axis [m] | across [m] | success | n |\n|---|---|---|---|")
    for k in SHIFTS:
        print(f"| {k[0]:.1f} | {k[1]:.1f} | {100 * np.mean(res[k]):.0f} % | {len(res[k])} |")


if __name__ == "__main__":
    main()
