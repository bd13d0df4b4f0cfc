"""The job that builds a grasp training data set (:mod:`synth.data.shards` is its format): piles
generated or read, every target subset's candidates run through Algorithm 1 (with robust labels),
the accepted grasps encoded as maps, written shard by shard by worker processes, resumable."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from synth.common.files import make_writable_dir
from synth.common.formats import major
from synth.common.runner import worker_died
from synth.errors import SynthError
from synth.data import shards
from synth.data.shards import (DATASET_FORMAT_VERSION, MANIFEST_NAME, SHARD_FORMAT_NAME, DatasetError, Manifest,
                                Sample, ShardInfo, ShardWriter, check_shard_file, done_record_path,
                                read_manifest, shard_name, write_manifest)
from synth.geometry.grasp import Grasp

# ---------------------------------------------------------------------------------------------
# the data-set job
# ---------------------------------------------------------------------------------------------
class DatasetJobError(DatasetError):
    """The data-set job could not finish (worker died, disk full, bad input); the folder still
    holds a consistent data set of the shards completed so far — re-run the same job to resume."""


@dataclass(frozen=True)
class DatasetJob:
    """Parameters of a data-set job (recorded in the manifest; a resumed job must match them)."""

    n_piles: int  # piles to simulate [-]
    n_logs: int = 4  # logs per pile [-] (the paper: 4); with max_logs the smallest pile
    max_logs: int | None = None  # piles cycle over n_logs..max_logs logs [-]; None = all have n_logs
    max_subsets: int | None = None  # target subsets simulated per pile [-]; None = all 2^n - 1
    obstacles_fraction: float = 0.33  # share of piles with obstacles [-] (the paper: a third)
    max_obstacles: int = 7  # piles with obstacles get 1..max_obstacles [-] (the paper: 0–7)
    seed: int = 0
    size_px: int = 128  # image side [px]
    n_renders: int = 3  # intensity renders per scene [-] (the paper: 3)
    piles_per_shard: int = 1  # piles per chunk (= per shard) [-]
    max_trials_per_subset: int | None = 16  # Algorithm 1 trial cap per subset [-]; None = no cap
    max_candidates: int | None = None  # candidate list cap per subset [-]; None = all
    trial_preset: str = "fast"  # "fast" or "careful" (synth.physics.trial.TrialConfig presets)
    piles_dir: str | None = None  # use the piles of a `synth piles` job folder instead of generating
    # robust labels (synth.data.robust.RobustLabels): perturbed repeats of each exact success
    label_repeats: int = 4  # [-]; 0 = the paper's labels (one exact success)
    label_sigma_xy_m: float = 0.02  # positioning error per horizontal axis [m]
    label_sigma_phi_deg: float = 2.0  # rotator angle error [deg]
    label_min_fraction: float = 0.75  # accepted when this share of the repeats succeeds [-]

    def __post_init__(self) -> None:
        if not 1 <= self.n_piles <= 1_000_000:
            raise ValueError(f"n_piles must be in [1, 1,000,000], got {self.n_piles}")
        if not 1 <= self.n_logs <= 10:
            raise ValueError(f"n_logs must be in [1, 10] (2^n - 1 subsets per pile), got {self.n_logs}")
        if self.max_logs is not None and not self.n_logs <= self.max_logs <= 10:
            raise ValueError(f"max_logs must be in [n_logs = {self.n_logs}, 10] or None, got {self.max_logs}")
        if self.max_subsets is not None and not self.max_subsets >= 1:
            raise ValueError(f"max_subsets must be >= 1 or None, got {self.max_subsets}")
        if not (isinstance(self.obstacles_fraction, (int, float)) and 0.0 <= self.obstacles_fraction <= 1.0):
            raise ValueError(f"obstacles_fraction must be in [0, 1], got {self.obstacles_fraction}")
        if not 1 <= self.max_obstacles <= 12:
            raise ValueError(f"max_obstacles must be in [1, 12], got {self.max_obstacles}")
        if not 1 <= self.n_renders <= 32:
            raise ValueError(f"n_renders must be in [1, 32], got {self.n_renders}")
        if not 1 <= self.piles_per_shard <= 10_000:
            raise ValueError(f"piles_per_shard must be in [1, 10000], got {self.piles_per_shard}")
        if self.max_trials_per_subset is not None and self.max_trials_per_subset < 1:
            raise ValueError("max_trials_per_subset must be >= 1 or None")
        if self.max_candidates is not None and self.max_candidates < 1:
            raise ValueError("max_candidates must be >= 1 or None")
        if self.trial_preset not in ("fast", "careful"):
            raise ValueError(f"trial_preset must be 'fast' or 'careful', got {self.trial_preset!r}")
        self.robust_labels()  # validates the label settings
        from synth.geometry.frames import OrthoGrid

        OrthoGrid(self.size_px)  # validates the size

    @property
    def n_chunks(self) -> int:
        return -(-self.n_piles // self.piles_per_shard)

    def chunk_piles(self, chunk: int) -> range:
        return range(chunk * self.piles_per_shard, min(self.n_piles, (chunk + 1) * self.piles_per_shard))

    def pile_params(self, k: int) -> tuple[int, int]:
        """(pile seed, number of obstacles) of pile ``k`` — a pure function of (seed, k)."""
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed), int(k), 0xDA7A]))
        pile_seed = int(rng.integers(0, 2**31 - 1))
        n_obst = int(rng.integers(1, self.max_obstacles + 1)) if rng.random() < self.obstacles_fraction else 0
        return pile_seed, n_obst

    def pile_logs(self, k: int) -> int:
        """Logs in pile ``k``: ``n_logs``, or n_logs..max_logs in turn (every size equally often)."""
        if self.max_logs is None:
            return self.n_logs
        return self.n_logs + k % (self.max_logs - self.n_logs + 1)

    def pile_subsets(self, k: int, n_logs: int) -> list[tuple[int, ...]]:
        """The target subsets simulated on pile ``k`` of ``n_logs`` logs, smallest first: all 2^n - 1, or
        with ``max_subsets`` every single log and then subsets of 2, 3, ... n logs in turn, each size's
        drawn at random from (seed, k), until ``max_subsets`` are chosen (so large subsets, which the
        planner is asked about, are sampled as often as small ones)."""
        every = all_subsets(n_logs)
        if self.max_subsets is None or len(every) <= self.max_subsets:
            return every
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed), int(k), 0x5B5E]))
        by_size = {m: [t for t in every if len(t) == m] for m in range(1, n_logs + 1)}
        for m in range(2, n_logs + 1):
            by_size[m] = [by_size[m][i] for i in rng.permutation(len(by_size[m]))]
        chosen = by_size[1][: self.max_subsets]
        while len(chosen) < self.max_subsets:
            for m in range(2, n_logs + 1):
                if by_size[m] and len(chosen) < self.max_subsets:
                    chosen.append(by_size[m].pop(0))
        return sorted(chosen, key=lambda t: (len(t), t))

    def candidate_config(self):
        from synth.data.candidates import CandidateConfig

        return CandidateConfig(max_candidates=self.max_candidates)

    def trial_config(self):
        from synth.physics.trial import TrialConfig

        return TrialConfig.preset(self.trial_preset)

    def robust_labels(self):
        from synth.data.robust import RobustLabels
        from synth.physics.perturb import PositioningError

        return RobustLabels(self.label_repeats, PositioningError(self.label_sigma_xy_m, self.label_sigma_phi_deg),
                            self.label_min_fraction)

    def to_dict(self) -> dict:
        from dataclasses import asdict

        return asdict(self)

    def params(self) -> dict:
        """The manifest's parameter record: the job plus the full trial configuration it implies
        (so a resumed job notices changed trial settings), JSON-normalised."""
        from dataclasses import asdict

        from synth.physics.trial_spec import TRIAL_REVISION

        d = {**self.to_dict(), "trial_revision": TRIAL_REVISION, "trial_config_values": asdict(self.trial_config()),
             "candidate_config_values": asdict(self.candidate_config()), "format_version": DATASET_FORMAT_VERSION}
        for name in ("max_logs", "max_subsets"):  # left out at their defaults: older jobs' records match
            if d[name] is None:
                del d[name]
        return json.loads(json.dumps(d))


def label_fields(labels) -> dict:
    """The :class:`DatasetJob` fields of a :class:`synth.data.robust.RobustLabels` ({} for None)."""
    if labels is None:
        return {}
    return {"label_repeats": labels.repeats, "label_sigma_xy_m": labels.error.sigma_xy_m,
            "label_sigma_phi_deg": labels.error.sigma_phi_deg, "label_min_fraction": labels.min_fraction}


@dataclass(frozen=True)
class JobProgress:
    """What the progress callback receives after each finished chunk."""

    chunks_done: int
    chunks_total: int
    samples: int  # samples in completed shards [-]
    trials: int  # trials simulated by this run so far [-]
    trials_per_s: float  # this run's trial throughput, all workers [1/s]
    elapsed_s: float  # wall time of this run [s]


def all_subsets(n: int) -> list[tuple[int, ...]]:
    """Every non-empty subset of ``n`` logs, smallest first."""
    from itertools import combinations

    return [c for k in range(1, n + 1) for c in combinations(range(n), k)]


def load_source_pile(job: DatasetJob, k: int):
    """Pile ``k`` and its render: generated from (seed, k), or read from ``job.piles_dir``."""
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.render.ortho import OrthoObservation, OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    if job.piles_dir is not None:
        from synth.scene.pile import read_pile

        folder = Path(job.piles_dir) / f"pile_{k:05d}"
        pile = read_pile(folder)  # PileFormatError names the file
        pile_id = folder.name
        obs = None
        ortho = folder / "ortho.npz"
        if ortho.exists():
            obs = OrthoObservation.load(ortho)
            if obs.depth.shape[0] != job.size_px or obs.intensity.shape[0] < job.n_renders:
                obs = None
        if obs is None:
            with World(pile) as world:
                obs = render_ortho(world, OrthoRenderConfig(size_px=job.size_px, n_renders=job.n_renders),
                                   seed=int(pile.seed or k))
        return pile, obs, pile_id, {"obstacles": pile.n_obstacles}
    pile_seed, n_obst = job.pile_params(k)
    pile, report = generate_pile(pile_seed, GenerationConfig(n_logs=job.pile_logs(k), n_obstacles=n_obst))
    with World(pile) as world:
        obs = render_ortho(world, OrthoRenderConfig(size_px=job.size_px, n_renders=job.n_renders), seed=pile_seed)
    return pile, obs, f"pile_{k:05d}", {"obstacles": n_obst, "pile_seed": pile_seed,
                                        "generation_attempts": report.attempts}


def new_chunk_stats() -> dict[str, Any]:
    """The per-chunk statistics a data-set job accumulates (see :func:`summarise`)."""
    return {"piles": 0, "piles_failed": 0, "piles_with_obstacles": 0, "subsets": 0, "negatives": 0,
            "grasps": 0, "candidates": 0, "trials": 0, "widened": 0, "capped_subsets": 0,
            "no_candidate_subsets": 0, "outcomes": {}, "trial_wall_s": 0.0, "wall_s": 0.0, "failed_piles": [],
            "proven_negatives": 0, "capped_negatives": 0, "unconfirmed": 0, "repeats": 0, "repeat_outcomes": {}}


@dataclass(frozen=True)
class SubsetResult:
    """Algorithm 1 on one target subset: the accepted grasps (x, y, phi, width, cos beta) and
    every trial it simulated (the grasp, its outcome, cos beta, the logs held)."""

    targets: tuple[int, ...]
    accepted: tuple[tuple[float, float, float, float, float], ...]
    trials: tuple[dict, ...]  # each may carry "r": its robust repeats [[x, y, phi, width, outcome], ...]
    n_candidates: int
    widened: int
    capped: bool
    unconfirmed: int = 0  # exact successes refused by their robust repeats

    @property
    def negative_kind(self) -> str | None:
        """None for a positive; "no_candidate" (geometry refused every grasp), "proven" (every
        candidate tried, none accepted) or "capped" (the trial cap stopped the search: untested)."""
        if self.accepted:
            return None
        if not self.n_candidates:
            return "no_candidate"
        return "capped" if self.capped else "proven"


def _trial_row(grasp: Grasp, result: object) -> dict:
    outcome = getattr(getattr(result, "outcome", None), "value", None)
    if outcome is None:
        outcome = "success" if getattr(result, "success", False) else "failure"
    b = float(getattr(result, "cos_beta", float("nan")))
    return {"g": [grasp.x_m, grasp.y_m, grasp.phi_rad, grasp.width_m], "o": outcome,
            "b": b if math.isfinite(b) else None, "h": list(getattr(result, "grasped", ()))}


def simulate_subsets(job: "DatasetJob", k: int, pile, simulate_factory: Callable | None,
                     stats: dict) -> list[SubsetResult]:
    """Candidates and Algorithm 1 for every target subset of pile ``k`` (updates ``stats``)."""
    import time

    from synth.data.candidates import generate_candidates, reduce_candidates
    from synth.data.robust import confirmer, repeat_rows

    labels = job.robust_labels()
    if simulate_factory is None:
        from synth.physics.trial import run_trial

        tc = job.trial_config()

        def simulate_factory(pile, targets):
            return lambda g: run_trial(pile, g, targets, tc)

    cand_cfg = job.candidate_config()
    stats["piles"] += 1
    stats["piles_with_obstacles"] += int(pile.n_obstacles > 0)
    out = []
    for T in job.pile_subsets(k, pile.n_logs):
        cands = generate_candidates(pile, T, cand_cfg)
        rng = np.random.default_rng(np.random.SeedSequence([int(job.seed), int(k), *T, 0xA1]))
        t1 = time.perf_counter()
        simulate = simulate_factory(pile, T)
        confirm = confirmer(labels, simulate, job.seed, int(k), tuple(T)) if labels.enabled else None
        res = reduce_candidates(cands, simulate, rng=rng, max_trials=job.max_trials_per_subset, confirm=confirm)
        stats["trial_wall_s"] += time.perf_counter() - t1
        accepted = []
        for g, r in res.accepted:
            b = float(getattr(r, "cos_beta", getattr(r, "balance", float("nan"))))
            accepted.append((g.x_m, g.y_m, g.phi_rad, g.width_m, min(1.0, max(-1.0, b)) if math.isfinite(b) else 1.0))
        trials = tuple(_trial_row(g, r) for g, r in res.trials)
        for t in trials:
            stats["outcomes"][t["o"]] = stats["outcomes"].get(t["o"], 0) + 1
        for i, c in res.confirmations.items():
            trials[i]["r"] = repeat_rows(c)
            for row in trials[i]["r"]:
                stats["repeat_outcomes"][row[4]] = stats["repeat_outcomes"].get(row[4], 0) + 1
            stats["repeats"] += len(trials[i]["r"])
        stats["candidates"] += len(cands)
        stats["no_candidate_subsets"] += int(not cands)
        stats["trials"] += res.n_trials
        stats["widened"] += res.widened
        stats["capped_subsets"] += int(res.capped)
        stats["subsets"] += 1
        stats["negatives"] += int(not accepted)
        stats["grasps"] += len(accepted)
        stats["unconfirmed"] += res.unconfirmed
        sub = SubsetResult(targets=tuple(T), accepted=tuple(accepted), trials=trials, n_candidates=len(cands),
                           widened=res.widened, capped=res.capped, unconfirmed=res.unconfirmed)
        kind = sub.negative_kind
        if kind in ("proven", "capped"):
            stats[f"{kind}_negatives"] += 1
        out.append(sub)
    return out


def add_pile_samples(writer: "ShardWriter", job: "DatasetJob", pile, pile_id: str, obs,
                     subsets: Sequence[SubsetResult], stats: dict) -> None:
    """The training samples of one simulated pile (every render x every subset) into ``writer``."""
    from synth.geometry.frames import OrthoGrid
    from synth.data.maps import encode_grasps
    from synth.data.outcomes import trial_array

    grid = OrthoGrid(obs.depth.shape[0], obs.extent_m)
    stats["grid"] = {"size_px": grid.size_px, "extent_m": grid.extent_m, "camera_height_m": obs.camera_height_m}
    for sub in subsets:
        arr = np.asarray(sub.accepted, dtype=np.float64).reshape(-1, 5)
        grasps = [Grasp(float(x), float(y), float(p), float(w)) for x, y, p, w, _ in arr]
        maps = encode_grasps(grid, grasps, [float(b) for b in arr[:, 4]])
        mask = obs.target_mask(sub.targets)
        trials = trial_array(sub.trials)
        for r in range(job.n_renders):
            writer.add(Sample(pile_id=pile_id, render=r, subset=tuple(sub.targets), intensity=obs.intensity[r],
                              depth=obs.depth, target_mask=mask, maps=maps, grasps=arr,
                              negative=not len(arr), n_logs=pile.n_logs, n_candidates=sub.n_candidates,
                              trials=trials, capped=sub.capped, instance=obs.instance))


def build_chunk(out_dir: str, job_dict: dict, chunk: int, worker: str | None = None,
                simulate_factory: Callable | None = None) -> dict:
    """Simulate every pile of ``chunk`` and write its shard + done record; returns the done record.

    ``simulate_factory(pile, targets) -> simulate(grasp)`` replaces the real
    :func:`synth.physics.trial.run_trial` (tests only).
    """
    import time

    from synth.errors import GenerationError
    from synth.scene.pile import write_pile

    job = DatasetJob(**job_dict)
    worker = worker or f"p{os.getpid()}"
    writer = ShardWriter(out_dir, worker, chunk)
    stats = new_chunk_stats()
    t0 = time.perf_counter()
    for k in job.chunk_piles(chunk):
        try:
            pile, obs, pile_id, info = load_source_pile(job, k)
        except GenerationError as exc:  # no valid pile for this seed: recorded, skipped
            stats["piles_failed"] += 1
            stats["failed_piles"].append({"pile": k, "reason": str(exc)})
            continue
        except SynthError as exc:
            raise DatasetJobError(f"pile {k} cannot be loaded: {exc}") from exc
        if job.piles_dir is None:
            write_pile(pile, Path(out_dir) / "piles" / f"{pile_id}.json")
        subsets = simulate_subsets(job, k, pile, simulate_factory, stats)
        add_pile_samples(writer, job, pile, pile_id, obs, subsets, stats)
    stats["wall_s"] = time.perf_counter() - t0
    if len(writer) == 0:  # every pile of the chunk failed: an empty shard still records the chunk
        return _write_empty_done(Path(out_dir), worker, chunk, stats)
    info = writer.close(stats)
    return info.to_dict()


def _write_empty_done(out: Path, worker: str, chunk: int, stats: dict) -> dict:
    info = ShardInfo(file="", worker=worker, chunk=chunk, n_samples=0, n_subsets=0, n_grasps=0,
                     sha256="", bytes=0, stats=stats)
    path = out / shard_name(worker, chunk)
    record = {"format": SHARD_FORMAT_NAME + ".done", "format_version": DATASET_FORMAT_VERSION, **info.to_dict()}
    shards.write_atomic(done_record_path(path), json.dumps(record, indent=1).encode())
    return info.to_dict()


def summarise(shards: Sequence[ShardInfo]) -> dict:
    """The paper's statistics over completed shards."""
    keys = ("piles", "piles_failed", "piles_with_obstacles", "subsets", "negatives", "grasps", "candidates",
            "trials", "widened", "capped_subsets", "no_candidate_subsets", "proven_negatives", "capped_negatives",
            "unconfirmed", "repeats")
    tot = {k: sum(int(s.stats.get(k, 0)) for s in shards) for k in keys}
    outcomes: dict[str, int] = {}
    repeat_outcomes: dict[str, int] = {}
    for s in shards:
        for k, v in s.stats.get("outcomes", {}).items():
            outcomes[k] = outcomes.get(k, 0) + int(v)
        for k, v in s.stats.get("repeat_outcomes", {}).items():
            repeat_outcomes[k] = repeat_outcomes.get(k, 0) + int(v)
    all_trials = tot["trials"] + tot["repeats"]
    trial_wall = sum(float(s.stats.get("trial_wall_s", 0.0)) for s in shards)
    wall = sum(float(s.stats.get("wall_s", 0.0)) for s in shards)
    return {
        "samples": sum(s.n_samples for s in shards), "map_samples": tot["subsets"], **tot,
        "negative_fraction": tot["negatives"] / tot["subsets"] if tot["subsets"] else 0.0,
        "grasps_per_positive": tot["grasps"] / max(1, tot["subsets"] - tot["negatives"]),
        "trials_per_subset": tot["trials"] / tot["subsets"] if tot["subsets"] else 0.0,
        "outcomes": dict(sorted(outcomes.items())),
        "success_rate": outcomes.get("success", 0) / tot["trials"] if tot["trials"] else 0.0,
        "repeat_outcomes": dict(sorted(repeat_outcomes.items())),
        "repeat_success_rate": repeat_outcomes.get("success", 0) / tot["repeats"] if tot["repeats"] else 0.0,
        "dropped_fraction": (outcomes.get("dropped", 0) + repeat_outcomes.get("dropped", 0)) / all_trials
        if all_trials else 0.0,
        "worker_s": wall, "trial_worker_s": trial_wall,
        "trials_per_worker_s": tot["trials"] / trial_wall if trial_wall > 0 else 0.0,
        "worker_s_per_pile": wall / tot["piles"] if tot["piles"] else 0.0,
    }


def _prepare(out: Path, job: DatasetJob) -> dict[int, ShardInfo]:
    """Check/record the job's parameters, drop partial shards, return the complete ones by chunk."""
    try:
        make_writable_dir(out)
    except OSError as exc:
        raise DatasetJobError(f"cannot write to output folder {out}: {exc.strerror or exc}; choose another folder") from exc
    params = job.params()
    if (out / MANIFEST_NAME).exists():
        have = read_manifest(out).params
        # a data set of an older minor format version is resumed: every shard carries its own
        # version and is read accordingly (load_shard)
        diff = [k for k in params if k not in ("n_piles", "format_version") and have.get(k) != params[k]]
        if major(have.get("format_version")) != major(params["format_version"]):
            diff.append("format_version")
        if diff:
            raise DatasetJobError(
                f"{out} holds a data set made with other parameters ({', '.join(diff)} differ); "
                "resume with the same parameters or choose a new folder"
            )
    for tmp in out.glob(".shard_*.tmp"):
        tmp.unlink(missing_ok=True)
    for tmp in [*out.glob(".manifest.json.*.tmp"), *out.glob("piles/.pile_*.tmp")]:
        tmp.unlink(missing_ok=True)
    done: dict[int, ShardInfo] = {}
    for rec in sorted(out.glob("shard_*.done.json")):
        try:
            d = json.loads(rec.read_text())
            info = ShardInfo.from_dict(d)
            if info.file:
                check_shard_file(out / info.file, info, checksum=True)
            ok = info.chunk not in done
        except (OSError, ValueError, DatasetError):
            ok = False
        if ok:
            done[info.chunk] = info
        else:  # unreadable, mismatched or duplicate record: redo that chunk
            rec.unlink(missing_ok=True)
    keep = {s.file for s in done.values() if s.file}
    for shard in out.glob("shard_*.npz"):
        if shard.name not in keep and not done_record_path(shard).exists():
            shard.unlink(missing_ok=True)  # partial: written, but no done record
    return done


def _manifest_for(job: DatasetJob, done: dict[int, ShardInfo]) -> Manifest:
    shards = [done[c] for c in sorted(done) if c < job.n_chunks]
    listed = [s for s in shards if s.file]
    summary = summarise(shards)
    summary["chunks_done"] = len(shards)
    summary["chunks_total"] = job.n_chunks
    summary["complete"] = len(shards) == job.n_chunks
    grid = next((s.stats["grid"] for s in shards if "grid" in s.stats),
                {"size_px": job.size_px, "extent_m": 5.0, "camera_height_m": 5.0})
    return Manifest(params=job.params(), grid=dict(grid), shards=listed, summary=summary)


def build_dataset(out_dir: str | Path, n_piles: int, n_logs: int = 4, obstacles_fraction: float = 0.33,
                  max_logs: int | None = None, max_subsets: int | None = None,
                  seed: int = 0, workers: int = 0, engine: str = "local", address: str | None = None,
                  size_px: int = 128, n_renders: int = 3, trial_config: str = "fast",
                  max_trials_per_subset: int | None = 16, piles_per_shard: int = 1, max_obstacles: int = 7,
                  max_candidates: int | None = None, piles_dir: str | Path | None = None,
                  progress: Callable[[JobProgress], None] | None = None,
                  simulate_factory: Callable | None = None, robust_labels=None) -> Manifest:
    """Build (or resume) the grasp training data set in ``out_dir``; returns its manifest.

    Piles come from :func:`synth.scene.generate.generate_pile` (``n_logs`` logs; a share
    ``obstacles_fraction`` of them with 1..``max_obstacles`` obstacles), or from the pile folders of
    a ``synth piles`` job (``piles_dir``). For each pile and each of its 2^n − 1 target subsets:
    geometric candidates (:func:`synth.data.candidates.generate_candidates`) -> Algorithm 1
    (:func:`synth.data.candidates.reduce_candidates`) with :func:`synth.physics.trial.run_trial` under the
    ``trial_config`` preset ("fast" or "careful") -> target maps; subsets without a successful
    grasp are kept as negatives. ``robust_labels`` (:class:`synth.data.robust.RobustLabels`; None =
    the job's defaults) confirms each accepted grasp under the field's positioning error. One shard per chunk of ``piles_per_shard`` piles, written by one
    worker. ``engine``: "local" (``workers`` processes, 0 = all cores, 1 = in this process) or
    "dask" (``address`` of a running scheduler, or a LocalCluster of ``workers`` processes).

    Resumable: finished shards (a shard + its done record, checksum verified) are kept, partial
    ones removed and redone. The manifest is rewritten atomically after every finished chunk,
    from completed shards only. ``progress(JobProgress)`` is called after each chunk. Errors
    (a dead worker, a full disk, a pile that fails to load) raise :class:`DatasetJobError` with
    the data set still consistent with its manifest.
    """
    from synth.common.runner import check_engine, pending, run_tasks

    check_engine(engine, workers)
    job = DatasetJob(n_piles=n_piles, n_logs=n_logs, max_logs=max_logs, max_subsets=max_subsets,
                     obstacles_fraction=obstacles_fraction,
                     max_obstacles=max_obstacles, seed=seed, size_px=size_px, n_renders=n_renders,
                     piles_per_shard=piles_per_shard, max_trials_per_subset=max_trials_per_subset,
                     **label_fields(robust_labels),
                     max_candidates=max_candidates, trial_preset=trial_config,
                     piles_dir=None if piles_dir is None else _checked_piles_dir(piles_dir, n_piles))
    out = Path(out_dir)
    done = _prepare(out, job)
    try:
        write_manifest(out, _manifest_for(job, done))
    except OSError as exc:
        raise DatasetJobError(f"cannot write the manifest in {out}: {exc.strerror or exc}") from exc
    todo = pending(range(job.n_chunks), done)
    done = {c: s for c, s in done.items() if c < job.n_chunks}
    finished = _ChunkDone(out, job, done, progress)
    tasks = {c: (str(out), job.to_dict(), c, None, simulate_factory) for c in todo}
    try:
        run_tasks(build_chunk, tasks, finished, workers=workers, engine=engine, address=address)
    except DatasetJobError:
        raise
    except Exception as exc:
        failed = _job_failure(exc, len(done), job.n_chunks)
        if failed is None:
            raise
        raise failed from exc
    return read_manifest(out)


def _checked_piles_dir(piles_dir: str | Path, n_piles: int) -> str:
    """A ``synth piles`` folder holding at least ``n_piles`` piles, as an absolute path."""
    pdir = Path(piles_dir)
    if not pdir.is_dir():
        raise DatasetJobError(f"piles folder {pdir} does not exist; run `loggrasp synth piles` first")
    have = len(list(pdir.glob("pile_[0-9]*")))
    if have < n_piles:
        raise DatasetJobError(f"{pdir} holds {have} piles, {n_piles} were asked for")
    return str(pdir.resolve())


class _ChunkDone:
    """build_dataset's per-chunk callback: the chunk joins ``done``, the manifest is rewritten from
    the completed shards, and ``progress`` hears the totals."""

    def __init__(self, out: Path, job: DatasetJob, done: dict, progress: Callable[[JobProgress], None] | None):
        import time

        self.out, self.job, self.done, self.progress = out, job, done, progress
        self.t0 = time.perf_counter()
        self.run_trials = 0

    def __call__(self, chunk: int, record: dict) -> None:
        import time

        info = ShardInfo.from_dict(record)
        self.done[info.chunk] = info
        self.run_trials += int(info.stats.get("trials", 0))
        write_manifest(self.out, _manifest_for(self.job, self.done))
        if self.progress:
            el = time.perf_counter() - self.t0
            self.progress(JobProgress(chunks_done=len(self.done), chunks_total=self.job.n_chunks,
                                      samples=sum(s.n_samples for s in self.done.values()), trials=self.run_trials,
                                      trials_per_s=self.run_trials / el if el > 0 else 0.0, elapsed_s=el))


def _job_failure(exc: Exception, n_done: int, n_chunks: int) -> DatasetJobError | None:
    """The job error for a full disk or a dead worker, saying how much is kept and how to resume;
    None for anything else (a bug: raised as it is)."""
    if isinstance(exc, OSError) and not isinstance(exc, (ConnectionError, TimeoutError)):
        return DatasetJobError(
            f"writing the data set failed ({exc.strerror or exc}); {n_done} of {n_chunks} chunks are "
            "complete and listed in the manifest — free space / fix the folder and re-run the same job to resume")
    name = type(exc).__name__
    if worker_died(exc) or isinstance(exc, (ConnectionError, TimeoutError)):
        return DatasetJobError(
            f"a worker died ({name}: {exc}); {n_done} of {n_chunks} chunks are complete and listed "
            "in the manifest — re-run the same job to resume")
    return None
