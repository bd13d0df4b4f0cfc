"""On-policy rounds: the network's own choices tried in the twin, added as outcome labels.

A round takes a checkpoint and a set of training piles (new 2-7-log piles, with and without
obstacles, from seeds apart from every test pile), plans every pile (every subset), and tries
its ``top_k`` best grasps by f1 and by f3 (the union) in the twin, each ``repeats`` times moved
by the field's positioning error (:mod:`synth.physics.perturb`, the same model the robust labels
and the evaluation's field row use). Each tried grasp becomes one stored trial in the robust
labels' form: ``g`` the grasp the network chose and ``o`` its outcome executed exactly, ``r`` its
repeats ``[x, y, phi, width, outcome]`` as executed (:func:`synth.data.robust.repeat_rows`' rows),
``u`` its U; its label is the repeats' success fraction (:func:`synth.data.outcomes.trial_success`).

The round is written as a grasp *store* (:mod:`synth.data.datastore`: ``store.json`` + one chunk
per pile), so it trains beside the main store with the outcome recipe::

    loggrasp train --data data/paper-v3 --data rounds/r1 --labels outcome ...

Its subsets hold only the tried grasps, so each is marked ``capped`` (the untried pixels are no
proven negatives). A round is resumable: finished pile chunks are kept; the round's parameters —
the checkpoint's sha256 and the piles included — are in ``store.json``, and resuming with another
model or other piles is a :class:`RoundError`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from planner.errors import PlannerError
from synth.physics.perturb import PositioningError

ROUND_SEED_BASE = 960_000_000  # pile seeds of round r: ROUND_SEED_BASE + r * 100_000 + k (apart from test/training seeds)
ACCEPT_FRACTION = 0.5  # a tried grasp with at least this success fraction is listed as accepted [-]


class RoundError(PlannerError):
    """An on-policy round cannot start or resume (another model or other piles in its folder)."""


@dataclass(frozen=True)
class RoundConfig:
    """One on-policy round."""

    round: int  # the round's index (0, 1, ...): its pile seeds [-]
    piles: int  # piles planned and tried [-]
    top_k: int = 4  # subsets tried per pile and objective (the best by f1 and by f3; their union) [-]
    repeats: int = 4  # executions of each tried grasp, each moved by a draw of the positioning error [-]
    error: PositioningError = field(default_factory=lambda: PositioningError(0.03, 2.0))  # the crane's
    min_logs: int = 2  # pile sizes cycle over min_logs..max_logs [-]
    max_logs: int = 7
    obstacles_every: int = 3  # every n-th pile has obstacles (1..7) [-]
    trial: str = "fast"  # trial preset

    def __post_init__(self) -> None:
        if self.round < 0 or not 1 <= self.piles <= 100_000:
            raise ValueError(f"round must be >= 0 and piles in [1, 100000], got {self.round}, {self.piles}")
        if self.top_k < 1 or self.repeats < 1:
            raise ValueError(f"top_k and repeats must be >= 1, got {self.top_k}, {self.repeats}")
        if not 1 <= self.min_logs <= self.max_logs <= 10:
            raise ValueError(f"need 1 <= min_logs <= max_logs <= 10, got {self.min_logs}, {self.max_logs}")
        if self.obstacles_every < 1:
            raise ValueError("obstacles_every must be >= 1")

    def task(self, k: int) -> tuple[int, bool, int, int]:
        """Pile ``k``'s (n_logs, obstacles, k, seed), as :func:`planner.evaluate.eval_scene` takes it."""
        n = self.min_logs + k % (self.max_logs - self.min_logs + 1)
        return n, k % self.obstacles_every == 0, k, ROUND_SEED_BASE + self.round * 100_000 + k


def _store_params(cfg: RoundConfig, model_sha256: str) -> dict:
    """The round's store record parameters: what a store reader needs (size, renders) and the round."""
    from synth.data.shards import DATASET_FORMAT_VERSION
    from synth.physics.trial_spec import TRIAL_REVISION

    # n_logs / obstacles_fraction only describe a generated store's piles; a round's piles are its own
    return {"n_piles": cfg.piles, "n_logs": cfg.max_logs, "obstacles_fraction": 1 / cfg.obstacles_every,
            "max_obstacles": 7, "seed": ROUND_SEED_BASE + cfg.round * 100_000, "size_px": 128, "n_renders": 1,
            "piles_per_shard": 1, "max_trials_per_subset": None, "max_candidates": None, "trial_preset": cfg.trial,
            "piles_dir": None, "trial_revision": TRIAL_REVISION, "format_version": DATASET_FORMAT_VERSION,
            "onpolicy": {**asdict(cfg), "model_sha256": model_sha256}}


def round_pile(cfg: RoundConfig, k: int, model: str, plan_fn: Callable | None = None) -> dict:
    """Pile ``k`` of the round planned with ``model`` and its choices tried: the chunk's pile entry."""
    from planner.evaluate import EvalConfig, eval_scene
    from planner.inference import Objective, plan
    from synth.physics.perturb import grasp_rng, perturbed_grasps
    from synth.physics.trial import TrialConfig, run_trial

    task = cfg.task(k)
    pile, obs = eval_scene(task, EvalConfig(trial=cfg.trial))
    p = (plan_fn or (lambda o, pl: plan(o, _network(model), Objective("f1"), pile=pl)))(obs, pile)
    f3 = Objective("f3")
    by_f3 = sorted(p.grasps, key=lambda g: -float(f3.quality(g.graspability, len(g.targets), g.balance)))
    chosen = {g.targets: g for g in p.grasps[: cfg.top_k] + by_f3[: cfg.top_k]}
    trial = TrialConfig.preset(cfg.trial)
    subsets = []
    for targets, g in sorted(chosen.items()):
        exact = run_trial(pile, g.grasp, targets, trial)
        moved = perturbed_grasps(g.grasp, cfg.error, cfg.repeats, grasp_rng(task[3], "onpolicy", targets))
        results = [run_trial(pile, m, targets, trial) for m in moved]
        repeats = [[m.x_m, m.y_m, m.phi_rad, m.width_m, r.outcome.value] for m, r in zip(moved, results)]
        betas = [float(r.cos_beta) for r in results if r.success and math.isfinite(r.cos_beta)]
        b = float(np.mean(betas)) if betas else None
        gl = [g.grasp.x_m, g.grasp.y_m, g.grasp.phi_rad, g.grasp.width_m]
        frac = sum(r.success for r in results) / len(results)
        subsets.append({"targets": list(targets), "trials": [{"g": gl, "o": exact.outcome.value, "r": repeats, "b": b,
                                                              "h": list(exact.grasped), "u": g.graspability}],
                        "accepted": [gl + [min(1.0, b if b is not None else 1.0)]] if frac >= ACCEPT_FRACTION else [],
                        "candidates": len(chosen), "widened": 0, "capped": True})
    return {"k": k, "pile_id": f"pile_{k:05d}", "pile_seed": task[3], "obstacles": pile.n_obstacles,
            "generation_attempts": 0, "pile": pile.to_dict(), "subsets": subsets}


_NET: dict = {}


def _network(model: str):
    import torch

    from planner.inference import load_planner

    if model not in _NET:
        torch.set_num_threads(1)
        _NET[model] = load_planner(model)
    return _NET[model]


def run_round(cfg: RoundConfig, model: str | Path, out_dir: str | Path,
              progress: Callable[[int, int], None] | None = None, plan_fn: Callable | None = None,
              workers: int = 1) -> dict:
    """Run (or resume) the round into the store folder ``out_dir``, ``workers`` piles at a time (a
    ``plan_fn`` runs in this process only); returns its store record."""
    from synth.common.runner import run_tasks
    from synth.common.files import sha256_file
    from synth.data.datastore import CHUNK, STORE, STORE_FILE, chunk_path, params_sha256, read_chunk, write_chunk

    out = Path(out_dir)
    try:
        sha = sha256_file(Path(model))
    except OSError as exc:
        raise RoundError(f"cannot read the checkpoint {model}: {exc.strerror or exc}; give an existing --model") from exc
    params = _store_params(cfg, sha)
    psha = params_sha256(params)
    if (out / STORE_FILE).exists():
        have = STORE.read(out / STORE_FILE)["params"].get("onpolicy", {})
        want = params["onpolicy"]
        diff = [k for k in sorted(set(have) | set(want)) if k != "piles" and have.get(k) != want.get(k)]
        if diff:
            what = "another model" if "model_sha256" in diff else "other piles or settings"
            raise RoundError(f"{out} holds an on-policy round made with {what} ({', '.join(diff)} differ); resume it "
                             "with the same model and round, or choose a new folder")
    listed, todo = {}, {}
    for k in range(cfg.piles):
        path = chunk_path(out, k)
        if path.exists():
            try:
                rec = read_chunk(path)
            except Exception:  # a truncated chunk is made again
                rec = None
            if rec is not None and rec.get("params_sha256") == psha:
                listed[k] = _entry(out, path, rec)
                continue
        todo[k] = (cfg, k, str(model), plan_fn)

    def finished(k: int, pile: dict) -> None:
        trials = sum(len(s["trials"]) for s in pile["subsets"])
        record = CHUNK.document({"chunk": k, "params_sha256": psha, "piles": [pile],
                                 "stats": {"piles": 1, "subsets": len(pile["subsets"]), "trials": trials,
                                           "grasps": sum(len(s["accepted"]) for s in pile["subsets"]),
                                           "capped_subsets": len(pile["subsets"])}})
        listed[k] = write_chunk(out, record)
        _write_round_store(out, params, psha, listed, cfg.piles)
        if progress:
            progress(len(listed), cfg.piles)

    run_tasks(round_pile, todo, finished, workers=1 if plan_fn is not None else workers)
    _write_round_store(out, params, psha, listed, cfg.piles)
    return STORE.read(out / STORE_FILE)


def _entry(out: Path, path: Path, rec: dict) -> dict:
    import hashlib

    data = path.read_bytes()
    return {"chunk": int(rec["chunk"]), "file": f"chunks/{path.name}", "sha256": hashlib.sha256(data).hexdigest(),
            "bytes": len(data), "stats": rec["stats"]}


def _write_round_store(out: Path, params: dict, psha: str, listed: dict, n: int) -> None:
    from synth.data.datastore import STORE, STORE_FILE

    chunks = [listed[c] for c in sorted(listed)]
    summary = {"chunks_done": len(chunks), "chunks_total": n, "complete": len(chunks) == n,
               "trials": sum(int(e["stats"]["trials"]) for e in chunks),
               "subsets": sum(int(e["stats"]["subsets"]) for e in chunks)}
    STORE.write(out / STORE_FILE, {"params": params, "params_sha256": psha, "chunks": chunks, "summary": summary})
