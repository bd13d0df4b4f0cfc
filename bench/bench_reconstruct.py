"""``make bench`` section "reconstruct" and its command: the measuring code is
:mod:`experiments.reconstruct_bench` (accuracy, obstacles, single-pair speed, the real test) and
:mod:`experiments.survey_conditions` (``--survey-scans``, ``--survey-report``).

    .venv/bin/python bench/bench_reconstruct.py --piles 3
    .venv/bin/python bench/bench_reconstruct.py --real-only --real-piles 24 --model PATH
    .venv/bin/python bench/bench_reconstruct.py --survey-scans 200 --survey-out DIR [--survey-shard K/N]
    .venv/bin/python bench/bench_reconstruct.py --survey-scans 200 --survey-set heldout --survey-out DIR
    .venv/bin/python bench/bench_reconstruct.py --survey-scans 114 --survey-set heldout --survey-pairs auto --survey-only-shapes loose --survey-out DIR
    .venv/bin/python bench/bench_reconstruct.py --survey-rescore DIR --survey-work WORK
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from experiments.reconstruct_bench import markdown, real_test, real_test_markdown
from experiments.survey_conditions import (read_survey_records, survey_bench, survey_pairs_key, survey_set_key,
                                           SurveyBenchInputError)
from experiments.survey_report import compare_markdown, survey_figure, survey_markdown

__all__ = ["markdown"]

if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--piles", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--real-piles", type=int, default=24, help="twin scans for the real test (0: skip it)")
    ap.add_argument("--model", default=None, help="planner checkpoint for the real test (default: the shipped one)")
    ap.add_argument("--workers", type=int, default=2, help="processes for the real test")
    ap.add_argument("--real-out", type=Path, default=None,
                    help="keep the real-test record (JSON) here: written after every pile, resumed when re-run")
    ap.add_argument("--real-only", action="store_true", help="run only the real test")
    ap.add_argument("--views", type=int, default=1, help="dihedral views the planner averages in the real test")
    ap.add_argument("--view-spread", type=float, default=0.0, help="U lowered by K x its spread over the views")
    ap.add_argument("--log-direction", default="45",
                    help="reconstructed pile frames turned so the logs lie at this angle [deg], or 'site' for the "
                         "site's axes (default 45, ReconstructConfig's)")
    ap.add_argument("--work-dir", type=Path, default=None,
                    help="keep the real test's scans and reconstructions here (reused when re-run)")
    ap.add_argument("--n-float", type=int, default=0,
                    help="RTK float ends per real-test survey (the twin's default survey has 2; reconstructed "
                         "with allow_float)")
    ap.add_argument("--survey-scans", type=int, default=0,
                    help="run only the survey-conditions bench on this many fresh twin scans (one process)")
    ap.add_argument("--survey-set", default="tuning", choices=("tuning", "heldout", "final"),
                    help="which scans: 'tuning' (seeds from 1,100,000, dropped piles: what the fitting was tuned on), "
                         "'heldout' (seeds from 3,300,000; packed, loose and dropped piles in turn) or 'final' (the "
                         "same shapes from 5,500,000: the ship decision, once an estimator is frozen); the record "
                         "says which")
    ap.add_argument("--survey-estimator", default="rules22", choices=("rules22", "joint"),
                    help="ReconstructConfig.estimator the survey-conditions bench reconstructs with")
    ap.add_argument("--survey-radius-states", action="store_true",
                    help="with --survey-estimator joint: JointConfig.radius_states on (each log's radius a state of "
                         "the pile estimate); the record's key says so")
    ap.add_argument("--survey-pairs", default="2x2", choices=("2x2", "auto"),
                    help="the survey-conditions scans' stereo pairs: 2x2 (the twin's fixed grid, every record before "
                         "it) or auto (the smallest grid covering each scan's surveyed ends, "
                         "reconstruct.scan.plan; in the record's key)")
    ap.add_argument("--survey-only-shapes", nargs="+", default=(), choices=("dropped", "packed", "loose"),
                    help="do only the survey scans of these pile shapes (e.g. re-scan the loose piles)")
    ap.add_argument("--survey-only-seeds", nargs="+", type=int, default=(),
                    help="do only these survey seeds, in this order (within the run's seeds)")
    ap.add_argument("--survey-seed", type=int, default=None,
                    help="first seed of the survey-conditions bench (default: the --survey-set's)")
    ap.add_argument("--survey-work", type=Path, default=None,
                    help="its scans and reconstructions (default runs/survey-work, runs/survey-work-heldout)")
    ap.add_argument("--survey-out", type=Path, default=None,
                    help="its record: a folder with one JSON per scan (kept: the same command with more "
                         "--survey-scans extends the run) and summary.json (default "
                         "docs/results/survey-conditions, docs/results/survey-conditions-heldout)")
    ap.add_argument("--survey-shard", default="0/1", metavar="K/N",
                    help="do only the survey scans whose seed - --survey-seed is K modulo N (run N processes, "
                         "K = 0..N-1, on one --survey-out)")
    ap.add_argument("--figure", type=Path, default=None, help="write the error-distribution figure here")
    ap.add_argument("--survey-report", action="store_true",
                    help="print the markdown (and write --figure) of an existing --survey-out record, run nothing")
    ap.add_argument("--survey-compare", nargs="+", type=Path, default=None, metavar="LABEL=DIR",
                    help="print survey-conditions records side by side on the scans they share (seed and stereo "
                         "cloud), e.g. rules22=docs/results/survey-conditions-heldout-r22 joint=DIR; run nothing")
    ap.add_argument("--survey-rescore", type=Path, default=None, metavar="DIR",
                    help="add the obstacle comparison to the scan records of DIR from the kept piles of --survey-work "
                         "(those the record measured only), rewrite its summary; reconstruct nothing")
    args = ap.parse_args()
    if args.survey_rescore:
        from experiments.survey_rescore import RescoreError, rescore_obstacles

        if args.survey_work is None:
            raise SystemExit("--survey-rescore needs --survey-work: the folder with the scans' kept piles")
        try:
            done = rescore_obstacles(args.survey_rescore, args.survey_work,
                                     progress=lambda s: print(s, file=sys.stderr, flush=True))
        except RescoreError as exc:
            raise SystemExit(str(exc)) from None
        print(f"{args.survey_rescore}: {done['scans']} scan records; conditions: "
              + ", ".join(f"{k} {v}" for k, v in sorted(done["counts"].items())))
        raise SystemExit(0)
    if args.survey_compare:
        try:
            recs = {str(a).split("=", 1)[0]: read_survey_records(Path(str(a).split("=", 1)[1]), write=False) for a in args.survey_compare}
        except IndexError:
            raise SystemExit("--survey-compare takes LABEL=DIR arguments") from None
        print("\n".join(compare_markdown(recs)))
        raise SystemExit(0)
    if args.survey_scans > 0 or args.survey_report:
        try:
            shard = tuple(int(v) for v in args.survey_shard.split("/"))
            if len(shard) != 2 or not 0 <= shard[0] < shard[1]:
                raise ValueError
        except ValueError:
            raise SystemExit(f"--survey-shard must be K/N with 0 <= K < N, got {args.survey_shard!r}") from None

        tail = "" if args.survey_set == "tuning" else "-" + args.survey_set
        out = args.survey_out or Path(f"docs/results/survey-conditions{tail}")
        work = args.survey_work or Path(f"runs/survey-work{tail}")
        try:
            joint_options = {"radius_states": True} if args.survey_radius_states else None
            survey_set_key(args.survey_set, args.survey_seed, args.survey_estimator, joint_options)
            survey_pairs_key(args.survey_pairs)
        except ValueError as exc:
            raise SystemExit(str(exc)) from None
        try:
            rec = (read_survey_records(out) if args.survey_report else
                   survey_bench(args.survey_scans, args.survey_seed, work, out, shard=shard,
                                survey_set=args.survey_set, estimator=args.survey_estimator,
                                joint_options=joint_options, pairs=args.survey_pairs,
                                only_shapes=tuple(args.survey_only_shapes), only_seeds=tuple(args.survey_only_seeds),
                                progress=lambda s: print(s, file=sys.stderr, flush=True)))
        except SurveyBenchInputError as exc:
            raise SystemExit(str(exc)) from None
        fig = survey_figure(rec, args.figure) if args.figure is not None else None
        print("\n".join(survey_markdown(rec, fig)))
        raise SystemExit(0)
    from reconstruct.config import parse_log_direction

    try:
        log_direction = parse_log_direction(args.log_direction)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    from experiments.real_test import RealTestConfig

    real_cfg = None if args.real_piles <= 0 else RealTestConfig(
        n_piles=args.real_piles, model=args.model, workers=args.workers, views=args.views,
        view_spread_k=args.view_spread, log_direction_deg=log_direction, n_float=args.n_float)
    if args.real_only:
        if real_cfg is None:
            raise SystemExit("--real-only needs --real-piles > 0")
        print("\n".join(real_test_markdown(real_test(real_cfg, args.real_out, args.work_dir))))
    else:
        print(markdown(args.piles, args.repeats, real_cfg, args.real_out, args.work_dir, real_piles=args.real_piles))
