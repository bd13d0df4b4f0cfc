"""How often the network's best grasp of a target subset succeeds in the twin, against its U and
the subset's size: the data a U calibration is fitted on (:mod:`planner.calibration`).

The objectives compare U *across* subsets (f1 takes the subset whose best pixel has the highest U),
but U is trained per pixel with positive pixels weighted (``u_pos_weight``), so its value is no
probability, and nothing makes a single log's U comparable with a four-log bundle's. This harness
measures it: on fresh piles (seeds apart from every test and training pile) it plans every subset,
takes the ``top_n`` best subsets by f1 and by f3, tries each one's best grasp in the twin and keeps
(pile, subset size, u, b, outcome) per trial, one record file per pile (resumable).

    .venv/bin/python -m experiments.calibration collect --model M --out runs/calib --per-cell 20 --workers 2
    .venv/bin/python -m experiments.calibration fit runs/calib --model M --out M.calibration.json
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

CALIBRATION_SEED_BASE = 930_000_000  # calibration piles: apart from test (900 M, 910 M) and training seeds


@dataclass(frozen=True)
class CollectConfig:
    model: str  # checkpoint path
    per_cell: int = 20  # piles per (size, obstacles) cell [-]
    top_n: int = 4  # subsets tried per pile and objective (f1 order, f3 order; the union is tried) [-]
    seed_base: int = CALIBRATION_SEED_BASE

    def __post_init__(self) -> None:
        if self.per_cell < 1 or self.top_n < 1:
            raise ValueError(f"per_cell and top_n must be >= 1, got {self.per_cell}, {self.top_n}")


_NET: dict = {}


def collect_pile(task: tuple[int, bool, int, int], cfg: CollectConfig) -> list[dict]:
    """One calibration pile: every subset planned, the best ``top_n`` by f1 and by f3 tried."""
    import torch

    from planner.evaluate import EvalConfig, eval_scene
    from planner.inference import Objective, load_planner, plan
    from synth.physics.trial import TrialConfig, run_trial

    if cfg.model not in _NET:
        torch.set_num_threads(1)
        _NET[cfg.model] = load_planner(cfg.model, calibrated=False)  # the raw U is what is fitted
    pile, obs = eval_scene(task, EvalConfig(seed_base=cfg.seed_base))
    p = plan(obs, _NET[cfg.model], Objective("f1"), pile=pile)
    by_f1 = p.grasps[: cfg.top_n]
    f3 = Objective("f3")
    by_f3 = sorted(p.grasps, key=lambda g: -float(f3.quality(g.graspability, len(g.targets), g.balance)))[: cfg.top_n]
    tried = {g.targets: g for g in by_f1 + by_f3}
    trial = TrialConfig.preset("fast")
    out = []
    for rank, g in enumerate(sorted(tried.values(), key=lambda g: -g.graspability)):
        t0 = time.perf_counter()
        r = run_trial(pile, g.grasp, g.targets, trial)
        out.append({"seed": task[3], "n_logs": task[0], "obstacles": task[1], "tau": len(g.targets),
                    "targets": list(g.targets), "u": g.graspability, "b": g.balance, "rank_f1": rank,
                    "outcome": r.outcome.value, "success": bool(r.success), "cos_beta": float(r.cos_beta),
                    "trial_s": time.perf_counter() - t0})
    return out


def collect(cfg: CollectConfig, out_dir: str | Path, workers: int = 2, progress=print) -> list[dict]:
    """Run (or resume) the collection; returns every trial record."""
    from planner.evaluate import EvalConfig
    from synth.common.files import atomic_write_bytes
    from synth.common.runner import run_tasks

    out = Path(out_dir)
    (out / "records").mkdir(parents=True, exist_ok=True)
    meta = out / "collect.json"
    want = asdict(cfg)
    if meta.exists() and json.loads(meta.read_text()) != want:
        raise ValueError(f"{out} holds a collection with other parameters ({meta}); choose a new --out")
    atomic_write_bytes(meta, json.dumps(want, indent=1).encode())
    tasks = EvalConfig(seed_base=cfg.seed_base, per_cell=cfg.per_cell).tasks()
    todo = {t: (t, cfg) for t in tasks if not (out / "records" / f"{t[3]}.json").exists()}
    done = [len(tasks) - len(todo)]

    def finish(task, recs):
        atomic_write_bytes(out / "records" / f"{task[3]}.json", json.dumps(recs).encode())
        done[0] += 1
        if progress and done[0] % 10 == 0:
            progress(f"{done[0]}/{len(tasks)} piles")

    run_tasks(collect_pile, todo, finish, workers=workers)
    return read_records(out)


def read_records(out_dir: str | Path) -> list[dict]:
    return [r for f in sorted((Path(out_dir) / "records").glob("*.json")) for r in json.loads(f.read_text())]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--model", required=True)
    c.add_argument("--out", required=True)
    c.add_argument("--per-cell", type=int, default=20)
    c.add_argument("--top-n", type=int, default=4)
    c.add_argument("--workers", type=int, default=2)
    f = sub.add_parser("fit")
    f.add_argument("records")
    f.add_argument("--model", required=True)
    f.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if a.cmd == "collect":
        recs = collect(CollectConfig(a.model, a.per_cell, a.top_n), a.out, a.workers)
        print(f"{len(recs)} trials")
    else:
        from planner.calibration import fit_calibration

        cal = fit_calibration(read_records(a.records), a.model)
        cal.write(a.out)
        print(cal.summary())


if __name__ == "__main__":
    main()
