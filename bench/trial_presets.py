"""Which trial settings agree with the ``careful`` preset: the exploration behind ``TrialConfig.fast``.

Runs the 160 bench grasps of :mod:`bench_trials` (20 generated 4-log piles, 8 grasps each) under
``careful`` and under each named variant, caches every outcome in ``--cache`` (a JSON file, so a
variant is simulated once), and prints class agreement, success/failure agreement and CPU s per
trial against ``careful``. ``fast`` is the shipped preset.

    .venv/bin/python bench/trial_presets.py --workers 2 careful fast t32_start12 dt240_it20
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path


from bench_trials import make_cases
from synth.physics.trial import TrialConfig, run_trial
from synth.physics.world import PhysicsConfig


def _old_fast() -> TrialConfig:  # the preset before 2026-11-22: 32² terrain, tips 0.12 m above the pile
    return dataclasses.replace(TrialConfig.fast(), terrain_resolution=32, start_clearance_m=0.12)


VARIANTS = {
    "careful": TrialConfig.careful,
    "fast": TrialConfig.fast,
    "fast_nofreeze": lambda: dataclasses.replace(TrialConfig.fast(), freeze_when_free=False),
    "fast_noapproach": lambda: dataclasses.replace(TrialConfig.fast(), approach_speed_m_s=TrialConfig.fast().lower_speed_m_s),
    "t32_start12": _old_fast,
    "t32_start12_dt240_it20": lambda: dataclasses.replace(_old_fast(), physics=PhysicsConfig(dt_s=1 / 240, solver_iterations=20)),
    "t32_start12_dt180_it30": lambda: dataclasses.replace(_old_fast(), physics=PhysicsConfig(dt_s=1 / 180, solver_iterations=30), check_every=3),
    "t64_start12": lambda: dataclasses.replace(TrialConfig.fast(), start_clearance_m=0.12),
    "t64_start12_dt240_it20": lambda: dataclasses.replace(TrialConfig.fast(), start_clearance_m=0.12, physics=PhysicsConfig(dt_s=1 / 240, solver_iterations=20)),
    "t64_start12_hold1": lambda: dataclasses.replace(TrialConfig.fast(), start_clearance_m=0.12, hold_s=1.0),
    "t64_start12_check1": lambda: dataclasses.replace(TrialConfig.fast(), start_clearance_m=0.12, check_every=1),
}


def _run(args):
    i, pile, grasp, targets, name = args
    r = run_trial(pile, grasp, targets, VARIANTS[name]())
    return i, r.outcome.name, r.cpu_time_s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("variants", nargs="*", default=["careful", "fast"], help=f"any of {sorted(VARIANTS)}")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--piles", type=int, default=20)
    ap.add_argument("--cache", type=Path, default=Path("runs/trial_presets.json"))
    a = ap.parse_args(argv)
    unknown = [v for v in a.variants if v not in VARIANTS]
    if unknown:
        ap.error(f"unknown variant(s) {unknown}; choose from {sorted(VARIANTS)}")
    cases = make_cases(a.piles, 0, 8)
    res = json.loads(a.cache.read_text()) if a.cache.exists() else {}
    names = ["careful"] + [v for v in a.variants if v != "careful"]
    with ProcessPoolExecutor(a.workers) as ex:
        for name in names:
            if name in res and len(res[name]) == len(cases):
                continue
            out = sorted(ex.map(_run, [(i, p, g, t, name) for i, (p, g, t) in enumerate(cases)], chunksize=4))
            res[name] = [[o, c] for _, o, c in out]
            a.cache.parent.mkdir(parents=True, exist_ok=True)
            a.cache.write_text(json.dumps(res))
    ref = [o for o, _ in res["careful"]]
    print("| variant | class agreement | success/failure | CPU s / trial | main disagreements (careful -> variant) |")
    print("|---|---|---|---|---|")
    for name in names:
        v = res[name]
        agree = sum(o == r for (o, _), r in zip(v, ref))
        agree_bin = sum((o == "SUCCESS") == (r == "SUCCESS") for (o, _), r in zip(v, ref))
        conf = Counter((r, o) for (o, _), r in zip(v, ref) if o != r).most_common(3)
        print(f"| {name} | {100 * agree / len(ref):.1f} % | {100 * agree_bin / len(ref):.1f} % | "
              f"{sum(c for _, c in v) / len(v):.3f} | " + ", ".join(f"{k[0]}->{k[1]} x{n}" for k, n in conf) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
