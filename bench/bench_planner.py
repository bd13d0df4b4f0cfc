"""``make bench`` section "planner" and its command: the measuring code is
:mod:`experiments.planner_bench` (training throughput, planning latency, averaged views, the cost of
subset pre-selection).

    .venv/bin/python bench/bench_planner.py [--pruning-only --model M --piles 20] [--views-only] [--ranker-only]
        [--balance-only] [--cost-only [--threads 1,2] [--precisions bf16,int8 [--rounds 3]]]
"""

from __future__ import annotations

import os

from experiments.planner_bench import (balance_latency, balance_markdown, cost_markdown, markdown, plan_cost,
                                       precision_cost, precision_markdown, pruning_markdown, pruning_quality,
                                       ranker_latency, ranker_markdown, views_latency, views_markdown)

__all__ = ["markdown"]

if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="Planner benchmarks (Markdown on stdout).")
    ap.add_argument("--pruning-only", action="store_true",
                    help="only the pre-selection vs exhaustive table with a trained model, graded in the twin")
    ap.add_argument("--model", default=os.environ.get("LOGGRASP_PLANNER_CKPT"),
                    help="checkpoint for the pruning table (default: planner/weights/default.safetensors)")
    ap.add_argument("--piles", type=int, default=20, help="7-log piles for the pruning table")
    ap.add_argument("--cache", default=None, help="folder keeping each pile's pruning rows (resume a run)")
    ap.add_argument("--cached-only", action="store_true", help="tabulate the piles in --cache, compute nothing")
    ap.add_argument("--views-only", action="store_true", help="only the planning time with averaged test-time views")
    ap.add_argument("--ranker-only", action="store_true", help="only the planning time with re-ranking by a ranker")
    ap.add_argument("--balance-only", action="store_true",
                    help="only the planning time with f3's balance from the B map and from the hang model")
    ap.add_argument("--cost-only", action="store_true",
                    help="only the wall and CPU seconds of a plan with 1 and 2 torch threads (shared machines)")
    ap.add_argument("--threads", default="1,2", help="torch threads for --cost-only, comma-separated")
    ap.add_argument("--precisions", default=None,
                    help="with --cost-only: CPU and wall s of a 7-log plan in these precisions, alternating "
                         "(e.g. bf16,int8), once per --threads count")
    ap.add_argument("--rounds", type=int, default=3, help="rounds for --precisions")
    args = ap.parse_args()
    if args.cost_only and args.precisions:
        rows = [r for t in args.threads.split(",")
                for r in precision_cost(tuple(args.precisions.split(",")), rounds=args.rounds, threads=int(t))]
        print("\n".join(precision_markdown(rows)))
    elif args.cost_only:
        print("\n".join(cost_markdown(plan_cost(threads=tuple(int(t) for t in args.threads.split(","))))))
    elif args.balance_only:
        print("\n".join(balance_markdown(balance_latency())))
    elif args.ranker_only:
        print("\n".join(ranker_markdown(ranker_latency())))
    elif args.views_only:
        print("\n".join(views_markdown(views_latency())))
    elif args.pruning_only:
        print("\n".join(pruning_markdown(pruning_quality(args.model, n_piles=args.piles, cache_dir=args.cache,
                                                                  only_cached=args.cached_only))))
    else:
        if args.model:
            os.environ["LOGGRASP_PLANNER_CKPT"] = args.model
        os.environ.setdefault("LOGGRASP_BENCH_PRUNING_PILES", str(args.piles))
        print(markdown(int(os.environ.get("LOGGRASP_BENCH_REPEATS", "3"))))
