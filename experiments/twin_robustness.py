"""Twin robustness: does a grasp that worked still work when the crane stands a little off?

Takes grasps that succeeded in the twin — the accepted grasps of a data-set store, and the exact
successes of Algorithm 1 (the paper's labels, no repeats) on fresh piles that no store holds —
and tries each again moved by draws of a :class:`synth.physics.perturb.PositioningError`. The
draws are keyed by (level, case, repeat), so a rerun is bit-identical and two trial revisions are
compared on the same moves.

Failures are sorted by what stopped them: ``grip`` (DROPPED: the claws closed on the load and let
it fall), ``neighbour`` (COLLISION or MORE_THAN_INTENDED: a grasp that really is next to a
neighbour or an obstacle), ``claw on target`` (NOT_CLOSED: a narrow opening landed a claw on a
target), ``other`` (FEWER_OR_OTHER).

    from experiments.twin_robustness import cases_from_store, run_cases, summarise, markdown
"""

from __future__ import annotations

import gzip
import json
import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synth.geometry.grasp import Grasp
from synth.physics.perturb import PositioningError, grasp_rng, perturbed_grasps

#: the perturbation levels of the issue's targets: (label, error or None for the exact grasp)
LEVELS: tuple[tuple[str, PositioningError | None], ...] = (
    ("exact", None),
    ("1 cm / 1°", PositioningError(0.01, 1.0)),
    ("3 cm / 3°", PositioningError(0.03, 3.0)),
)
FAILURE_KIND = {"dropped": "grip", "collision": "neighbour", "more_than_intended": "neighbour",
                "not_closed": "claw on target", "fewer_or_other": "other"}


@dataclass(frozen=True)
class Case:
    """One grasp that succeeded: its pile (as a dict), targets, the grasp and where it came from."""

    pile: dict
    targets: tuple[int, ...]
    grasp: tuple[float, float, float, float]
    source: str  # "store" or "fresh"
    key: str  # stable id, e.g. "chunk_00012/pile_00012/0-2/1"


def cases_from_store(store_dir: str | Path, n: int, seed: int = 0) -> list[Case]:
    """``n`` accepted grasps drawn uniformly (without replacement) from a store's chunks."""
    every: list[tuple[Path, int, int, int]] = []
    chunks = sorted((Path(store_dir) / "chunks").glob("chunk_*.json.gz"))
    docs = {}
    for path in chunks:
        d = json.loads(gzip.decompress(path.read_bytes()))
        docs[path] = d
        for pi, p in enumerate(d["piles"]):
            for si, s in enumerate(p["subsets"]):
                every += [(path, pi, si, ai) for ai in range(len(s["accepted"]))]
    if not every:
        raise ValueError(f"{store_dir} holds no accepted grasp")
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(every), size=min(n, len(every)), replace=False)
    out = []
    for i in sorted(pick):
        path, pi, si, ai = every[i]
        p = docs[path]["piles"][pi]
        s = p["subsets"][si]
        t = tuple(int(v) for v in s["targets"])
        out.append(Case(p["pile"], t, tuple(float(v) for v in s["accepted"][ai][:4]), "store",
                        f"{path.name.split('.')[0]}/{p['pile_id']}/{'-'.join(map(str, t))}/{ai}"))
    return out


def fresh_pile_cases(seed: int, n_logs: int, n_obstacles: int, max_trials: int = 16) -> list[Case]:
    """Algorithm 1's exact successes (no repeats) on one freshly generated pile, every subset."""
    from itertools import combinations

    from synth.data.candidates import generate_candidates, reduce_candidates
    from synth.errors import GenerationError
    from synth.physics.trial import TrialConfig, run_trial
    from synth.scene.generate import GenerationConfig, generate_pile

    try:
        pile, _ = generate_pile(seed, GenerationConfig(n_logs=n_logs, n_obstacles=n_obstacles))
    except GenerationError:
        return []
    cfg = TrialConfig.fast()
    out = []
    for k in range(1, n_logs + 1):
        for t in combinations(range(n_logs), k):
            cands = generate_candidates(pile, t, None)
            res = reduce_candidates(cands, lambda g, t=t: run_trial(pile, g, list(t), cfg),
                                    rng=np.random.default_rng([seed, *t]), max_trials=max_trials)
            for j, (g, _) in enumerate(res.accepted):
                out.append(Case(pile.to_dict(), t, (g.x_m, g.y_m, g.phi_rad, g.width_m), "fresh",
                                f"fresh/{seed}/{'-'.join(map(str, t))}/{j}"))
    return out


def trial_variant(preset: str = "fast", grapple: dict | None = None) -> "TrialConfig":
    """A trial preset with grapple fields overridden (e.g. ``{"closed_bowl_diameter_m": 0.342}``:
    revision 3's stroke) — the variants docs/trials.md compares."""
    from dataclasses import replace

    from synth.physics.trial import TrialConfig

    cfg = TrialConfig.preset(preset)
    return replace(cfg, grapple=replace(cfg.grapple, **(grapple or {})))


def try_case(case: Case, level: int, reps: int, preset: str = "fast", grapple: dict | None = None) -> list[dict]:
    """The case's grasp at perturbation ``LEVELS[level]`` (``reps`` draws; 1 trial when exact)."""
    from synth.physics.trial import run_trial
    from synth.scene.pile import PileSpec

    cfg = trial_variant(preset, grapple)
    pile = PileSpec.from_dict(case.pile)
    g = Grasp(*case.grasp)
    label, err = LEVELS[level]
    grasps = [g] if err is None else perturbed_grasps(g, err, reps, grasp_rng(0, "robustness", label, case.key))
    rows = []
    for j, q in enumerate(grasps):
        r = run_trial(pile, q, list(case.targets), cfg)
        rows.append({"case": case.key, "source": case.source, "level": label, "rep": j, "n_targets": len(case.targets),
                     "outcome": r.outcome.value, "cos_beta": None if not math.isfinite(r.cos_beta) else r.cos_beta,
                     "cpu_s": r.cpu_time_s})
    return rows


def run_cases(cases: list[Case], reps: int = 2, workers: int = 2, levels: tuple[int, ...] = (0, 1, 2),
              preset: str = "fast", grapple: dict | None = None) -> list[dict]:
    """Every case at every level (indices into ``LEVELS``); the trial rows in a stable order."""
    from synth.common.runner import run_tasks

    tasks = {(i, lv): (c, lv, reps, preset, grapple) for i, c in enumerate(cases) for lv in levels}
    got: dict = {}
    run_tasks(try_case, tasks, lambda k, rows: got.__setitem__(k, rows), workers=workers)
    return [row for k in sorted(got) for row in got[k]]


def summarise(rows: list[dict]) -> dict:
    """Per source and level: success, by target count, and the failures by kind and outcome."""
    out: dict = {}
    for r in rows:
        cell = out.setdefault(r["source"], {}).setdefault(r["level"], {"n": 0, "ok": 0, "by_logs": {}, "kinds": Counter(),
                                                                        "outcomes": Counter(), "cpu_s": []})
        ok = r["outcome"] == "success"
        cell["n"] += 1
        cell["ok"] += ok
        bl = cell["by_logs"].setdefault(min(r["n_targets"], 5), [0, 0])
        bl[0] += ok
        bl[1] += 1
        cell["cpu_s"].append(r["cpu_s"])
        if not ok:
            cell["kinds"][FAILURE_KIND.get(r["outcome"], "other")] += 1
            cell["outcomes"][r["outcome"]] += 1
    for levels in out.values():
        for cell in levels.values():
            cell["kinds"], cell["outcomes"] = dict(cell["kinds"]), dict(cell["outcomes"])
            cell["cpu_s"] = float(np.median(cell["cpu_s"])) if cell["cpu_s"] else float("nan")
    return out


def _pct(a: int, b: int) -> str:
    return f"{100 * a / b:.1f} % ({a}/{b})" if b else "—"


def markdown(summary: dict, cases_by_source: dict[str, int]) -> str:
    """A table per source: success at each level, by target count, and the failure kinds."""
    lines = []
    for source, levels in summary.items():
        lines += [f"**{source} grasps** ({cases_by_source.get(source, '?')} grasps that succeeded exactly)", "",
                  "| moved by | success | 1 log | 2 logs | 3 logs | 4 logs | 5+ logs | failures by kind | CPU s/trial |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for label, _ in LEVELS:
            c = levels.get(label)
            if c is None:
                continue
            by_logs = {int(k): v for k, v in c["by_logs"].items()}  # a record read back has string keys
            logs = [(_pct(*by_logs[k]) if k in by_logs else "—") for k in range(1, 6)]
            kinds = ", ".join(f"{k} {v}" for k, v in sorted(c["kinds"].items())) or "none"
            lines.append(f"| {label} | {_pct(c['ok'], c['n'])} | " + " | ".join(logs) + f" | {kinds} | {c['cpu_s']:.2f} |")
        lines.append("")
    return "\n".join(lines)
