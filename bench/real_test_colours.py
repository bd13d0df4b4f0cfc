"""Diagnostic for the real test: how much of the truth-vs-reconstruction disagreement could come
from colours alone?

The reconstruction cannot know a twin pile's render colours (the stereo scan shows bark textures,
not ``LogSpec.colour``), so it renders with default colours, while the truth is planned on its own
random colours. This plans each truth pile of the real test (same seeds and pile sizes as
:mod:`field.real_test`) twice — with its own colours and with the reconstruction's defaults — and
executes both grasps on the truth. Run:

    .venv/bin/python bench/real_test_colours.py --piles 50 --out runs/real_test_colours.json

2026-11-30, 50 piles (seeds 700000-700049), shipped model v2: f1 38 vs 35 successes, 3 discordant
piles; f3 41 vs 41, 2 discordant. The real test on the same piles: 18 (f1) and 7 (f3) discordant —
colour is not what moves the reconstruction's plans.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    from field.real_test import RealTestConfig, _execute
    from planner.cli import DEFAULT_MODEL
    from planner.inference import Objective, load_planner, plan
    from synth.generate import GenerationConfig, generate_pile
    from synth.pile import RockSpec, StumpSpec, atomic_write_bytes
    from synth.render import OrthoRenderConfig, render_ortho
    from synth.world import World

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--piles", type=int, default=50)
    ap.add_argument("--out", type=Path, default=Path("runs/real_test_colours.json"))
    a = ap.parse_args()
    cfg = RealTestConfig()
    planner = load_planner(cfg.model or DEFAULT_MODEL, device="cpu")
    rows = []
    for seed in range(cfg.seed, cfg.seed + a.piles):
        # the pile make_twin_scan makes for this seed (its georeference does not matter here)
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7]))
        n_logs = int(rng.integers(cfg.logs[0], cfg.logs[1] + 1))
        n_obst = int(rng.integers(cfg.obstacles[0], cfg.obstacles[1] + 1))
        pile, _ = generate_pile(seed, GenerationConfig(n_logs=n_logs, n_obstacles=n_obst))
        plain = replace(  # the colours a reconstructed pile gets
            pile, terrain=replace(pile.terrain, colour=(0.45, 0.40, 0.30)),
            logs=tuple(replace(lg, colour=(0.6, 0.5, 0.35)) for lg in pile.logs),
            stumps=tuple(replace(s, colour=StumpSpec.__dataclass_fields__["colour"].default) for s in pile.stumps),
            rocks=tuple(replace(r, colour=RockSpec.__dataclass_fields__["colour"].default) for r in pile.rocks))
        obs = {}
        for name, p in (("own", pile), ("plain", plain)):
            with World(p) as w:
                obs[name] = render_ortho(w, OrthoRenderConfig(size_px=planner.config.size_px, n_renders=3), seed=0)
        for kind in cfg.objectives:
            row = {"seed": seed, "objective": kind}
            for name in ("own", "plain"):
                best = plan(obs[name], planner, Objective(kind=kind), top_k=1, pile=pile).best
                row[name] = None if best is None else {
                    "targets": sorted(best.targets), "grasp": best.grasp.to_dict(),
                    **_execute(pile, best.grasp, best.targets)}
            rows.append(row)
        print(f"pile {seed} done", file=sys.stderr, flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(a.out, json.dumps({"rows": rows}, indent=1).encode())
    for kind in cfg.objectives:
        rr = [r for r in rows if r["objective"] == kind and r["own"] and r["plain"]]
        print(f"{kind}: {len(rr)} piles, own colours {sum(r['own']['success'] for r in rr)} successes, "
              f"default colours {sum(r['plain']['success'] for r in rr)}, discordant "
              f"{sum(r['own']['success'] != r['plain']['success'] for r in rr)}, same targets "
              f"{sum(r['own']['targets'] == r['plain']['targets'] for r in rr)}")


if __name__ == "__main__":
    main()
