"""Benchmark of the grasp trial: trials/s per core on 4-log piles, and how often the ``fast``
preset's outcome agrees with the ``careful`` one on the same grasps.

Piles come from :func:`synth.scene.generate.generate_pile` (seeds 0..N-1, half with obstacles); grasps
are simple geometric ones across target subsets (perpendicular to the targets' mean axis, centred
on them, opened to their extent + a random margin), plus deliberately offset / narrow variants so
that every outcome class appears. Prints a Markdown block.

    .venv/bin/python bench/bench_trials.py --piles 20 --workers 2
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

from pathlib import Path

import numpy as np


from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, Grasp
from synth.scene.pile import PileSpec
from synth.physics.trial import TrialConfig, run_trial


def geometric_grasp(pile: PileSpec, targets: tuple[int, ...], margin_m: float, shift_m: float = 0.0,
                    along_m: float = 0.0) -> Grasp | None:
    """A grasp across ``targets``: closing axis perpendicular to their mean axis, centred on them."""
    axes, cens, diams = [], [], []
    for i in targets:
        log = pile.logs[i]
        a = log.axis()[:2]
        a = a / (np.linalg.norm(a) + 1e-12)
        if axes and np.dot(a, axes[0]) < 0:
            a = -a
        axes.append(a)
        cens.append(np.asarray(log.centre_m[:2]))
        diams.append(log.diameter_m)
    a = np.mean(axes, axis=0)
    a /= np.linalg.norm(a)
    cdir = np.array([-a[1], a[0]])
    centroid = np.mean(cens, axis=0) + a * along_m
    offs = []
    for ax, ce in zip(axes, cens):
        # where this log's axis line crosses the line through the centroid along cdir
        m = np.array([ax, -cdir]).T
        if abs(np.linalg.det(m)) < 1e-6:
            return None
        s, t = np.linalg.solve(m, centroid - ce)
        offs.append(t)
    lo, hi = min(offs), max(offs)
    width = (hi - lo) + max(diams) + margin_m
    if not MIN_WIDTH_M <= width <= MAX_WIDTH_M:
        width = float(np.clip(width, MIN_WIDTH_M, MAX_WIDTH_M))
    centre = centroid + cdir * ((lo + hi) / 2 + shift_m)
    return Grasp(float(centre[0]), float(centre[1]), math.atan2(cdir[1], cdir[0]), float(width))


def make_cases(n_piles: int, seed0: int = 0, per_pile: int = 8):
    """(pile, grasp, targets) cases on generated 4-log piles."""
    from synth.scene.generate import GenerationConfig, generate_pile

    cases = []
    for k in range(n_piles):
        seed = seed0 + k
        cfg = GenerationConfig(n_logs=4, n_obstacles=0 if k % 2 == 0 else 3)
        pile, _ = generate_pile(seed, cfg)
        rng = np.random.default_rng(1000 + seed)
        subsets = [s for r in (1, 2, 3, 4) for s in itertools.combinations(range(4), r)]
        picks = rng.choice(len(subsets), size=per_pile, replace=False)
        for j in picks:
            t = subsets[j]
            g = geometric_grasp(pile, t, margin_m=float(rng.uniform(0.0, 0.35)),
                                shift_m=float(rng.normal(0.0, 0.05)), along_m=float(rng.normal(0, 0.3)))
            if g is not None:
                cases.append((pile, g, t))
    return cases


def _run(args):
    pile, grasp, targets, which = args
    cfg = TrialConfig.preset(which)
    r = run_trial(pile, grasp, targets, cfg)
    return r.outcome.name, r.cpu_time_s, r.sim_time_s, r.max_penetration_m, r.wall_time_s


def pictures(out_dir: Path, n_piles: int = 6, seed0: int = 0) -> list[Path]:
    """Before/after PNGs of example trials (one per outcome class found) under ``out_dir``."""
    import cv2

    from synth.physics.trial import render_view

    out_dir.mkdir(parents=True, exist_ok=True)
    written, seen = [], set()
    for pile, grasp, targets in sorted(make_cases(n_piles, seed0, 8), key=lambda c: -len(c[2])):
        frames = {}

        def grab(name, world, grapple, g=grasp):
            if name in ("start", "end"):
                head, _ = grapple.head_pose()
                ground = float(pile.terrain.height_at(g.x_m, g.y_m))
                look_z = 0.5 * (ground + head[2] - 0.9)  # between the ground and the claws
                frames[name] = render_view(world, (g.x_m, g.y_m, look_z), distance_m=3.4,
                                           yaw_deg=math.degrees(g.phi_rad) + 20.0, pitch_deg=-18.0)

        r = run_trial(pile, grasp, targets, TrialConfig.fast())
        if r.outcome in seen:
            continue
        seen.add(r.outcome)
        run_trial(pile, grasp, targets, TrialConfig.fast(), on_phase=grab)  # deterministic: same trial
        stem = r.outcome.name.lower()
        for phase, suffix in (("start", "before"), ("end", "after")):
            path = out_dir / f"{stem}_{suffix}.png"
            img = cv2.cvtColor(frames[phase], cv2.COLOR_RGB2BGR)
            label = f"{r.outcome.name}  targets {list(targets)}  held {list(r.grasped)}  w={grasp.width_m:.2f} m"
            cv2.putText(img, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 2)
            cv2.imwrite(str(path), img)
            written.append(path)
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--piles", type=int, default=20)
    ap.add_argument("--per-pile", type=int, default=8)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pictures", type=Path, default=None, help="write example PNGs here and exit")
    a = ap.parse_args(argv)
    if a.pictures is not None:
        for path in pictures(a.pictures):
            print(path)
        return 0
    t0 = time.perf_counter()
    cases = make_cases(a.piles, a.seed, a.per_pile)
    t_gen = time.perf_counter() - t0
    results = {}
    for which in ("fast", "careful"):
        jobs = [(p, g, t, which) for p, g, t in cases]
        t1 = time.perf_counter()
        if a.workers > 1:
            with ProcessPoolExecutor(a.workers) as ex:
                out = list(ex.map(_run, jobs, chunksize=2))
        else:
            out = [_run(j) for j in jobs]
        results[which] = (out, time.perf_counter() - t1)
    fast, t_fast = results["fast"]
    careful, t_careful = results["careful"]
    n = len(cases)
    agree = sum(f[0] == c[0] for f, c in zip(fast, careful))
    agree_bin = sum((f[0] == "SUCCESS") == (c[0] == "SUCCESS") for f, c in zip(fast, careful))
    per_trial_fast = np.mean([f[1] for f in fast])
    per_trial_careful = np.mean([c[1] for c in careful])
    confusion = Counter((c[0], f[0]) for f, c in zip(fast, careful) if f[0] != c[0])
    print("```")
    print(f"bench_trials: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end (CPU time is "
          "per process, so it is the per-core cost even on a shared machine)")
    print(f"bench_trials: {n} grasps on {a.piles} generated 4-log piles (half with 3 obstacles), "
          f"workers={a.workers}, pile generation {t_gen:.1f} s")
    print("```")
    print()
    print("| preset | CPU s / trial | trials/s per core | mean wall s / trial | mean sim s | max penetration mm |")
    print("|---|---|---|---|---|---|")
    for name, out, per in (("fast", fast, per_trial_fast), ("careful", careful, per_trial_careful)):
        print(f"| {name} | {per:.3f} | {1 / per:.2f} | {np.mean([o[4] for o in out]):.3f} | "
              f"{np.mean([o[2] for o in out]):.2f} | {1000 * max(o[3] for o in out):.1f} |")
    print()
    print(f"- outcome agreement fast vs careful: **{agree}/{n} = {100 * agree / n:.1f} %** "
          f"(success/failure only: {100 * agree_bin / n:.1f} %)")
    print(f"- careful outcomes: {dict(Counter(c[0] for c in careful))}")
    print(f"- fast outcomes: {dict(Counter(f[0] for f in fast))}")
    if confusion:
        print("- disagreements (careful -> fast): " + ", ".join(f"{k[0]}->{k[1]} x{v}" for k, v in confusion.most_common()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


def markdown(piles: int = 8, per_pile: int = 8, workers: int = 2) -> str:
    """`make bench` section: trials/s per core, fast-vs-careful agreement, paper-scale projection."""
    import contextlib
    import io
    import re

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        main(["--piles", str(piles), "--per-pile", str(per_pile), "--workers", str(workers)])
    text = buf.getvalue()
    m = re.search(r"\| fast \| ([0-9.]+) \|", text)
    proj = ""
    if m:
        cpu_per_trial = float(m.group(1))
        trials = 604 * 15 * 7.8  # piles x subsets x measured trials per subset (docs/dataset.md)
        proj = ("\n\nProjected wall time of the paper-scale data set (604 four-log piles, ~70,700 trials at the "
                "measured 7.8 trials per subset, fast preset, trials only, 90 % parallel efficiency assumed): "
                f"**{trials * cpu_per_trial / (2 * 0.9) / 3600:.1f} h on 2 cores**, "
                f"**{trials * cpu_per_trial / (16 * 0.9) / 60:.0f} min on 16 cores** (not measured on 16 cores).")
    return ("### Grasp trials (fast vs careful presets on the same grasps)\n"
            "Targets: ≥ 2 trials/s per core on 4-log piles; ≥ 95 % same outcome as careful settings.\n\n"
            + text + proj)
