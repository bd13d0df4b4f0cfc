"""What a checkpoint's maps get right on the validation piles of a data set (no physics):

* positives (subsets with a grasp): is the argmax of U inside the true U, how far from it, the
  angle and width error there;
* positives vs negatives: the AUC of the subset's max U (can the network tell a graspable subset
  from one with no grasp? The planner ranks subsets by it).

    .venv/bin/python scripts/map_diagnostics.py planner/weights/default.safetensors data/train-v2 [--shards N]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np



def main() -> None:
    from planner.data import is_validation_pile, list_shards, load_samples, make_inputs, sample_arrays
    from planner.inference import load_planner
    from synth.geometry.frames import wrap_phi
    from synth.data.maps import decode_at

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model", type=Path)
    ap.add_argument("data", type=Path)
    ap.add_argument("--shards", type=int, default=None, help="first N shards only")
    args = ap.parse_args()
    pl = load_planner(args.model)
    shards, _ = list_shards(args.data)
    inside, dist, ang, wid, pos, neg = [], [], [], [], [], []
    for sh in shards[: args.shards]:
        for s in load_samples(sh)[::3]:  # one render per (pile, subset)
            if not is_validation_pile(s.pile_id):
                continue
            inten, depth, mask, maps = sample_arrays(s)
            y = pl.predict(make_inputs(inten, depth, mask, pl.config.in_channels))[0]
            if maps[3].max() < 0.5:
                neg.append(float(y[3].max()))
                continue
            pos.append(float(y[3].max()))
            r, c = np.unravel_index(np.argmax(y[3]), y[3].shape)
            inside.append(bool(maps[3][r, c] > 0.5))
            rr, cc = np.nonzero(maps[3] > 0.5)
            dist.append(float(np.min(np.hypot(rr - r, cc - c))))
            if inside[-1]:
                phi_p, w_p, _, _ = decode_at(y, r, c)
                phi_t, w_t, _, _ = decode_at(maps, r, c)
                ang.append(abs(float(np.degrees(wrap_phi(phi_p - phi_t)))))
                wid.append(abs(w_p - w_t))
    p, n = np.array(pos), np.array(neg)
    auc = float(np.mean(p[:, None] > n[None, :])) if len(p) and len(n) else float("nan")
    print(f"| validation subsets | {len(p)} with a grasp, {len(n)} without |\n|---|---|")
    print(f"| argmax of U inside the true U | {100 * np.mean(inside):.0f} % |")
    print(f"| argmax to the true U [px] | median {np.median(dist):.1f}, p90 {np.percentile(dist, 90):.1f} |")
    print(f"| angle error there [deg] | median {np.median(ang):.1f}, p90 {np.percentile(ang, 90):.1f} |")
    print(f"| width error there [m] | median {np.median(wid):.3f} |")
    print(f"| AUC of max U, with vs without a grasp | {auc:.3f} |")


if __name__ == "__main__":
    main()
