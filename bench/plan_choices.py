"""The planner's chosen grasps on a fixed set of piles, before and after a speed change
(:mod:`experiments.plan_choices`): record them with one version of the code, then compare.

    .venv/bin/python bench/plan_choices.py --out before.json [--cache DIR] [--precision bf16|fp32|int8] [--batch-size 16]
    .venv/bin/python bench/plan_choices.py --out after.json --against before.json [--cache DIR]
"""

from __future__ import annotations

if __name__ == "__main__":
    import argparse

    import torch

    from experiments.plan_choices import (choice_tasks, choices_markdown, compare_choices, read_choices,
                                          record_choices, write_choices)
    from planner.checkpoint import DEFAULT_MODEL
    from planner.inference import load_planner

    ap = argparse.ArgumentParser(description="Record (and compare) the planner's choices on fixed piles.")
    ap.add_argument("--out", required=True, help="the record to write (JSON)")
    ap.add_argument("--against", default=None, help="an earlier record: print the comparison (Markdown)")
    ap.add_argument("--cache", default=None, help="folder keeping the piles' observations (npz)")
    ap.add_argument("--model", default=str(DEFAULT_MODEL), help="checkpoint (default: the shipped model)")
    ap.add_argument("--precision", default=None, help="bf16, fp32 or int8 (default: the planner's)")
    ap.add_argument("--batch-size", type=int, default=None,
                    help="target masks per forward pass (default: the planner's, 16 per torch thread)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    kw = {k: v for k, v in (("precision", a.precision), ("batch_size", a.batch_size)) if v is not None}
    rec = record_choices(load_planner(a.model, device="cpu", **kw), choice_tasks(), cache_dir=a.cache)
    write_choices(a.out, rec)
    if a.against:
        before = read_choices(a.against)
        print("\n".join(choices_markdown(compare_choices(before, rec), before, rec)))
