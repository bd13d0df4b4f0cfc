"""A golden record of :func:`synth.trial.run_trial`: every number ~40 trials produce, to prove a
refactor of the trial behaviour-preserving:

    .venv/bin/python scripts/trial_golden.py data/paper-v3 golden.json
    .venv/bin/python scripts/trial_golden.py data/paper-v3 after.json && cmp golden.json after.json

The trials: from the first chunks of a committed grasp store, the first few stored trials of each
outcome class, at most two from one pile (the store's pile, grasp, targets and trial config), the first three also with ``careful``; on a hand-built one-log pile,
a full trial with ``fast`` and with ``careful``, a count target, ``on_phase`` callbacks, and
``should_abort`` firing in each phase. Each record is ``TrialResult.to_dict()`` without the wall
and CPU times; floats are written with ``repr`` precision, so equal files mean bit-identical
results.
"""

from __future__ import annotations

import itertools
import json
import sys

from synth.datastore import chunk_path, open_store, read_chunk
from synth.grasp import Grasp
from synth.pile import LogSpec, PileSpec, TerrainSpec, quat_from_x_axis
from synth.trial import TRIAL_REVISION, TrialConfig, run_trial

CHUNKS = range(4)  # first chunks of the store to draw from
PER_OUTCOME = 5  # stored trials per outcome class ...
PER_PILE = 2  # ... at most this many from one pile
CAREFUL_STORE_TRIALS = 3  # the first few store trials also run with TrialConfig.careful()


def comparable(result, **extra) -> dict:
    d = result.to_dict()
    d.pop("wall_time_s")
    d.pop("cpu_time_s")
    return d | extra


def store_cases(store_dir: str) -> list[tuple[str, PileSpec, Grasp, tuple[int, ...], str]]:
    """(name, pile, grasp, targets, stored outcome) for the first PER_OUTCOME trials per class."""
    _, chunks, store = open_store(store_dir)
    taken: dict[str, int] = {}
    cases = []
    per_pile: dict[tuple[str, str], int] = {}
    for k in CHUNKS:
        if k not in chunks:
            continue
        rec = read_chunk(chunk_path(store_dir, k), store["params_sha256"])
        for p in rec["piles"]:
            pile = PileSpec.from_dict(p["pile"])
            for si, s in enumerate(p["subsets"]):
                for ti, t in enumerate(s["trials"]):
                    key = (p["pile_id"], t["o"])
                    if taken.get(t["o"], 0) >= PER_OUTCOME or per_pile.get(key, 0) >= PER_PILE:
                        continue
                    taken[t["o"]] = taken.get(t["o"], 0) + 1
                    per_pile[key] = per_pile.get(key, 0) + 1
                    cases.append((f"{p['pile_id']}/s{si}/t{ti}", pile, Grasp(*t["g"]), tuple(s["targets"]), t["o"]))
    return cases


def one_log_pile() -> PileSpec:
    heights = tuple(tuple(0.0 for _ in range(32)) for _ in range(32))
    log = LogSpec(centre_m=(0.0, 0.0, 0.41 * 0.16), orientation=quat_from_x_axis((0, 1, 0)), length_m=2.5,
                  diameter_m=0.16)
    return PileSpec(terrain=TerrainSpec(resolution=32, heights_m=heights), logs=(log,), rocks=())


def after(n_steps: int):
    """A should_abort that turns True at its n-th call (one call per simulation step)."""
    calls = itertools.count(1)
    return lambda: next(calls) >= n_steps


def hand_built_records() -> dict[str, dict]:
    pile, grasp = one_log_pile(), Grasp(0.0, 0.0, 0.0, 0.6)
    out: dict[str, dict] = {}
    for preset, cfg in (("fast", TrialConfig.fast()), ("careful", TrialConfig.careful())):
        full = run_trial(pile, grasp, [0], cfg)
        out[f"one_log/{preset}/full"] = comparable(full)
        dt = cfg.physics.dt_s
        steps = {ph: round(full.phase_s[ph] / dt) for ph in ("lower", "close", "lift", "hold")}
        start = 0
        for ph, n in steps.items():  # abort in the middle of each phase and on its last step
            for at in (start + max(1, n // 2), start + n):
                r = run_trial(pile, grasp, [0], cfg, should_abort=after(at))
                out[f"one_log/{preset}/abort_{ph}_at_{at}"] = comparable(r)
            start += n
    out["one_log/fast/count_target"] = comparable(run_trial(pile, grasp, 1, TrialConfig.fast()))
    out["one_log/fast/miss"] = comparable(run_trial(pile, Grasp(0.9, 0.0, 0.0, 0.6), [0], TrialConfig.fast()))
    phases: list[str] = []
    r = run_trial(pile, grasp, [0], TrialConfig.fast(), on_phase=lambda name, world, grapple: phases.append(name))
    out["one_log/fast/on_phase"] = comparable(r, on_phase_calls=phases)
    return out


def main(store_dir: str, out_path: str) -> None:
    job, _, _ = open_store(store_dir)
    cfg = job.trial_config()
    records: dict[str, dict] = {}
    cases = store_cases(store_dir)
    for name, pile, grasp, targets, stored in cases:
        records[name] = comparable(run_trial(pile, grasp, targets, cfg), stored_outcome=stored)
    for name, pile, grasp, targets, _ in cases[:CAREFUL_STORE_TRIALS]:
        records[f"{name}/careful"] = comparable(run_trial(pile, grasp, targets, TrialConfig.careful()))
    records |= hand_built_records()
    with open(out_path, "w") as f:
        json.dump({"trial_revision": TRIAL_REVISION, "n": len(records), "records": records}, f, indent=1)
        f.write("\n")
    classes: dict[str, int] = {}
    for r in records.values():
        classes[r["outcome"]] = classes.get(r["outcome"], 0) + 1
    agree = sum(r["outcome"] == r["stored_outcome"] for r in records.values() if "stored_outcome" in r)
    n_store = sum("stored_outcome" in r for r in records.values())
    print(f"{len(records)} trials -> {out_path}; outcomes {classes}; store trials agreeing with the stored "
          f"outcome {agree}/{n_store}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
