"""The learning curve of issue 15: the same recipe trained on 1/8, 1/4, 1/2 and all of the training
piles, every model evaluated on the same held-out piles (the paper's protocol, f1 and f3), so that
the curve says whether data, capacity or the recipe limits the network.

Each share trains into ``OUT/share_<s>/`` (resumable: ``planner.train.train`` resumes a run with
the same configuration) and the evaluation of all models runs once, on the same fresh piles, into
``OUT/eval/`` (resumable per pile). Writes ``OUT/learning_curve.md``, ``.json`` and ``.png``.

    # the full run (hours on 2 CPU cores; minutes of training on a GPU machine)
    .venv/bin/python bench/learning_curve.py --data data/paper-v3 --out docs/results/learning-curve \\
        --epochs 30 --per-cell 20 --workers 2
    # training only (e.g. on a GPU machine with an export), evaluation later where pybullet is
    .venv/bin/python bench/learning_curve.py --data out/paper-v3-train --out runs/lc --train-only --device cuda

The shares are nested (``DataConfig.train_fraction``): 1/8 of the piles is a subset of 1/4 of them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from experiments.learning_curve import (SHARES, U_POS_WEIGHT, count_train_piles, curve_rows, evaluate_shares,
                                        model_share, size_px_of, train_shares, write_curve)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", action="append", required=True, help="data set or store folder (repeatable)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--shares", default=",".join(f"{s:g}" for s in SHARES))
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--base-channels", type=int, default=23, help="23 ~ 4.0 M parameters (the paper's 4.1 M)")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--precision", default="bf16")
    ap.add_argument("--max-steps-per-epoch", type=int, default=None)
    ap.add_argument("--objectives", default="f1,f3")
    ap.add_argument("--logs", default="2,3,4,5,6,7")
    ap.add_argument("--per-cell", type=int, default=20, help="piles per (size, obstacles) cell; 20 x 12 = 240")
    ap.add_argument("--seed-base", type=int, default=910_000_000, help="far from training and other evaluations")
    ap.add_argument("--workers", type=int, default=0)
    ap.add_argument("--train-only", action="store_true")
    ap.add_argument("--skip-no-candidates", action="store_true",
                    help="leave out subsets without an admissible candidate (DataConfig.skip_no_candidates)")
    ap.add_argument("--u-pos-weight", type=float, default=U_POS_WEIGHT,
                    help="BCE weight of positive U pixels (1 = the paper's plain BCE)")
    ap.add_argument("--extra-model", action="append", default=[], metavar="LABEL=PATH",
                    help="another recipe's checkpoint, evaluated on the same piles (repeatable), rows LABEL-<objective>")
    a = ap.parse_args(argv)
    extra = {}
    for item in a.extra_model:
        label, sep, path = item.partition("=")
        if not sep or not label or not Path(path).is_file():
            ap.error(f"--extra-model must be LABEL=PATH to a checkpoint, got {item!r}")
        extra[label] = Path(path)
    shares = [float(s) for s in a.shares.split(",")]
    if any(not 0 < s <= 1 for s in shares):
        ap.error(f"--shares must be in (0, 1], got {a.shares}")
    objectives = a.objectives.split(",")
    a.out.mkdir(parents=True, exist_ok=True)
    models = train_shares(a.data, a.out, shares, a.epochs, a.base_channels, a.device, a.precision,
                          a.max_steps_per_epoch, a.batch_size, a.skip_no_candidates, a.u_pos_weight)
    if a.train_only:
        print(json.dumps({str(k): str(v) for k, v in models.items()}))
        return 0
    tables = evaluate_shares(models, a.out, objectives, a.per_cell, [int(x) for x in a.logs.split(",")],
                             a.workers, a.seed_base, size_px_of(a.data), extra)
    all_shares = set(shares) | {model_share(p) for p in extra.values()} - {None}
    rows = curve_rows(tables, models, objectives, count_train_piles(a.data, all_shares), extra)
    write_curve(rows, a.out)
    print((a.out / "learning_curve.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
