"""The real test with verified planning (issue 17): the command of :mod:`experiments.verification`
(what it measures, how planning time is counted and how a record resumes is said there).

    .venv/bin/python bench/bench_verify.py --piles 500 --workers 2 --work-dir runs/verify-work \\
        --out runs/verify_real_test.json --md docs/results/verify/results.md --fig docs/results/verify/figure.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from experiments.verification import VerifyBenchConfig, figure, markdown, run, timing, write_record


def main() -> None:
    from synth.common.ranges import parse_range

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--piles", type=int, default=40)
    ap.add_argument("--seed", type=int, default=700000)
    ap.add_argument("--logs", default="3-6")
    ap.add_argument("--obstacles", default="0-2")
    ap.add_argument("--objectives", default="f1,f3")
    ap.add_argument("--ks", default="4,8,16")
    ap.add_argument("--copies", type=int, default=3, help="perturbed copies in the '+copies' variants (0: none)")
    ap.add_argument("--model", default=None)
    ap.add_argument("--n-float", type=int, default=2,
                    help="RTK float ends per twin survey (2: the twin's default survey, as in the field; 0: all fixed)")
    ap.add_argument("--work-dir", type=Path, default=Path("runs/verify-work"))
    ap.add_argument("--out", type=Path, default=Path("runs/verify_real_test.json"))
    ap.add_argument("--md", type=Path, default=None, help="write the tables here")
    ap.add_argument("--fig", type=Path, default=None, help="draw success and time vs K here")
    ap.add_argument("--report-only", action="store_true", help="tables and figure from --out, nothing run")
    ap.add_argument("--timing", type=int, default=0, help="instead: real wall times on this many 7-log piles")
    ap.add_argument("--workers", type=int, default=1, help="processes (piles at once; with --timing: the verifier's)")
    args = ap.parse_args()
    try:
        cfg = VerifyBenchConfig(piles=args.piles, seed=args.seed, logs=parse_range(args.logs, "--logs"),
                                obstacles=parse_range(args.obstacles, "--obstacles"),
                                objectives=tuple(o.strip() for o in args.objectives.split(",") if o.strip()),
                                ks=tuple(int(k) for k in args.ks.split(",")), copies=args.copies,
                                n_float=args.n_float, model=args.model, workers=args.workers)
    except ValueError as exc:
        ap.error(str(exc))
    say = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    if args.timing:
        rows = timing(cfg, args.timing, args.work_dir, say)
        write_record(args.out.with_name(args.out.stem + "_timing.json"), {"rows": rows, "workers": args.workers})
        for k in cfg.ks:
            mine = [r for r in rows if r["k"] == k]
            if mine:
                print(f"K={k}: plan {np.median([r['plan_s'] for r in mine]):.2f} s + verify "
                      f"{np.median([r['verify_s'] for r in mine]):.2f} s median wall ({len(mine)} piles, "
                      f"{args.workers} workers), trials {np.mean([r['trials'] for r in mine]):.1f}")
        return
    try:
        rec = json.loads(args.out.read_text()) if args.report_only else run(cfg, args.work_dir, args.out, say)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    command = "python " + " ".join(sys.argv)
    if args.md:
        args.md.parent.mkdir(parents=True, exist_ok=True)
        args.md.write_text(markdown(rec, command))
    if args.fig:
        figure(rec, args.fig)
    print(markdown(rec, command))


if __name__ == "__main__":
    main()
