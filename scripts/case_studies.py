"""Draw the paper's case studies (ranking of all subsets, obstacle placed, packed piles, thick /
conical logs) with a planner checkpoint, trying every drawn grasp in the twin.

Usage (a few minutes on one core):

    nice -n 19 .venv/bin/python scripts/case_studies.py --model planner/weights/default.safetensors \
        --out docs/results/case-studies

Writes ranking.png, obstacle.png, packed.png, logs.png, results.json and README.md under --out.
All logic is in :mod:`experiments.case_studies`.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    from experiments.case_studies import FIGURES, CaseStudyConfig, model_record, run_case_studies

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=ROOT / "planner" / "weights" / "default.safetensors",
                    help="planner checkpoint (.safetensors); default: the shipped model")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "case-studies", help="output folder")
    ap.add_argument("--seed", type=int, default=CaseStudyConfig.seed, help="base pile seed")
    ap.add_argument("--ranking-logs", type=int, default=CaseStudyConfig.ranking_logs,
                    help="logs in the ranking pile (2^n - 1 subsets)")
    ap.add_argument("--cases", default=",".join(FIGURES), help=f"comma-separated subset of {','.join(FIGURES)}")
    ap.add_argument("--trial", default="fast", choices=("fast", "careful"), help="twin trial preset")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    args = ap.parse_args(argv)

    import torch

    from planner.errors import PlannerError
    from planner.inference import load_planner
    from synth.errors import SynthError

    torch.set_num_threads(args.threads)
    try:
        planner = load_planner(args.model, device="cpu")
        model = model_record(args.model, planner)
        cfg = CaseStudyConfig(seed=args.seed, ranking_logs=args.ranking_logs, trial=args.trial)
        model["path"] = str(args.model.resolve().relative_to(ROOT)) if args.model.resolve().is_relative_to(ROOT) \
            else str(args.model)
        command = "nice -n 19 .venv/bin/python scripts/case_studies.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
        results = run_case_studies(planner, args.out, cfg, model=model, command=command.strip(),
                                   cases=[c.strip() for c in args.cases.split(",") if c.strip()],
                                   progress=lambda name: print(f"case study: {name}", flush=True))
    except (PlannerError, SynthError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    recs = results["records"]
    ok = sum(r["outcome"] == "success" for r in recs)
    print(f"wrote {args.out}: {len(recs)} grasps tried, {ok} succeeded; model sha256 {model['sha256'][:12]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
