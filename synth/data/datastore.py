"""The committed, compact form of a grasp data set: what the simulation found, not its images.

A data-set *store* is one folder that lives in the repository and grows across machines::

    DIR/store.json                   format name + version, the job's parameters (incl. the trial
                                     code revision), the chunks finished so far (sha256 of each),
                                     summary statistics; rewritten atomically after every chunk
    DIR/chunks/chunk_<nnnnn>.json.gz one chunk of piles, written atomically by one worker: per pile
                                     its settled PileSpec, per target subset the accepted grasps
                                     (x, y, phi, width, cos beta) and every trial Algorithm 1 ran
                                     (grasp, outcome, cos beta, logs held), and the chunk's statistics
    DIR/.cache/                      (not committed) the training shards made from the chunks

Renders and target maps are *not* stored: they are re-made deterministically from the stored
piles (:func:`materialize`: a World from the settled poses, :func:`synth.render.ortho.render_ortho` with
the pile's seed, :func:`synth.data.maps.encode_grasps`) into an ordinary data set (:mod:`synth.data.dataset`)
in ``DIR/.cache``, keyed by each chunk's sha256, the first time it is trained on.

A store is resumed from any clone: :func:`build_store` with the same parameters skips every chunk
file that is present, parses, carries the store's parameter hash and (if listed) the listed
sha256; a chunk made with other parameters or another trial revision is an error, never mixed in.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import re
import time
from pathlib import Path
from typing import Callable

from synth.data.dataset import (DatasetJob, DatasetJobError, JobProgress, SubsetResult, add_pile_samples, new_chunk_stats,
                                simulate_subsets, summarise)
from synth.data.shards import (DatasetFormatError, DatasetIntegrityError, Manifest, ShardInfo, ShardWriter, read_manifest,
                               write_manifest)
from synth.common.files import atomic_write_bytes
from synth.common.formats import VersionedJson
from synth.common.runner import pending, run_tasks
from synth.scene.pile import PileSpec

STORE_FORMAT_NAME = "loggrasp.grasp_store"
CHUNK_FORMAT_NAME = "loggrasp.grasp_store_chunk"
STORE_FORMAT_VERSION = "1.1"  # 1.1: robust repeats ("r") per trial, "unconfirmed" per subset
STORE_FILE = "store.json"
STORE = VersionedJson(STORE_FORMAT_NAME, STORE_FORMAT_VERSION, "data-set store record", DatasetFormatError,
                      unreadable_fix="restore it from git", filename=STORE_FILE)
CHUNK = VersionedJson(CHUNK_FORMAT_NAME, STORE_FORMAT_VERSION, "store chunk", DatasetFormatError)
CHUNK_DIR = "chunks"
CACHE_DIR = ".cache"
#: what the materialised shards hold beyond the chunk (a cached shard of another revision is made
#: anew): 2 = each subset's admissible candidate count (``Sample.n_candidates``); 3 = every trial of
#: each subset and whether they hit the cap (``Sample.trials``, ``Sample.capped``: outcome labels);
#: 4 = the pile's instance map (``Sample.instance``: the ranker's other-log and obstacle channels)
MATERIALIZE_REVISION = 4
_CHUNK_RE = re.compile(r"^chunk_(\d{5,})\.json\.gz$")


def is_store(path: str | Path) -> bool:
    """True when ``path`` is a store folder (holds ``store.json``)."""
    return (Path(path) / STORE_FILE).is_file()


def chunk_path(store_dir: str | Path, chunk: int) -> Path:
    return Path(store_dir) / CHUNK_DIR / f"chunk_{chunk:05d}.json.gz"


def params_sha256(params: dict) -> str:
    """Hash of a job's parameter record (stable JSON)."""
    return hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()


def _gzip_json(obj: dict) -> bytes:
    """Deterministic gzip of compact JSON (no timestamp, so equal content = equal bytes)."""
    return gzip.compress(json.dumps(obj, separators=(",", ":")).encode(), compresslevel=9, mtime=0)


# ---------------------------------------------------------------------------------------------
# chunks
# ---------------------------------------------------------------------------------------------
def simulate_chunk(job: DatasetJob, chunk: int, simulate_factory: Callable | None = None) -> dict:
    """Simulate the piles of ``chunk`` (no renders): the chunk record that is stored."""
    from synth.errors import GenerationError
    from synth.scene.generate import GenerationConfig, generate_pile

    if job.piles_dir is not None:
        raise ValueError("a store generates its own piles; piles_dir is for folder data sets")
    stats = new_chunk_stats()
    t0 = time.perf_counter()
    piles = []
    for k in job.chunk_piles(chunk):
        pile_seed, n_obst = job.pile_params(k)
        try:
            pile, report = generate_pile(pile_seed, GenerationConfig(n_logs=job.pile_logs(k), n_obstacles=n_obst))
        except GenerationError as exc:
            stats["piles_failed"] += 1
            stats["failed_piles"].append({"pile": k, "reason": str(exc)})
            continue
        subsets = simulate_subsets(job, k, pile, simulate_factory, stats)
        piles.append({"k": k, "pile_id": f"pile_{k:05d}", "pile_seed": pile_seed, "obstacles": n_obst,
                      "generation_attempts": report.attempts, "pile": pile.to_dict(),
                      "subsets": [_subset_dict(s) for s in subsets]})
    stats["wall_s"] = time.perf_counter() - t0
    return CHUNK.document({"chunk": chunk, "params_sha256": params_sha256(job.params()), "piles": piles,
                           "stats": stats})


def _subset_dict(s: SubsetResult) -> dict:
    return {"targets": list(s.targets), "accepted": [list(a) for a in s.accepted], "trials": list(s.trials),
            "candidates": s.n_candidates, "widened": s.widened, "capped": s.capped, "unconfirmed": s.unconfirmed}


def _subset_from(d: dict) -> SubsetResult:
    return SubsetResult(targets=tuple(int(t) for t in d["targets"]),
                        accepted=tuple(tuple(float(v) for v in a) for a in d["accepted"]),
                        trials=tuple(d["trials"]), n_candidates=int(d["candidates"]),
                        widened=int(d["widened"]), capped=bool(d["capped"]), unconfirmed=int(d.get("unconfirmed", 0)))


def write_chunk(store_dir: str | Path, record: dict) -> dict:
    """Write a chunk record atomically; returns its listing entry (file, sha256, bytes, stats)."""
    data = _gzip_json(record)
    path = chunk_path(store_dir, int(record["chunk"]))
    atomic_write_bytes(path, data)
    return {"chunk": int(record["chunk"]), "file": f"{CHUNK_DIR}/{path.name}",
            "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data), "stats": record["stats"]}


def read_chunk(path: str | Path, expect_params_sha256: str | None = None) -> dict:
    """A chunk record. :class:`DatasetFormatError` for a truncated, corrupt or foreign file or one
    made with other job parameters / another trial revision (``expect_params_sha256``)."""
    path = Path(path)
    try:
        d = json.loads(gzip.decompress(path.read_bytes()))
    except FileNotFoundError as exc:
        raise DatasetFormatError(f"store chunk {path} does not exist") from exc
    except (OSError, EOFError, ValueError, UnicodeDecodeError) as exc:
        raise DatasetFormatError(f"store chunk {path} is truncated or corrupt ({type(exc).__name__}: {exc}); "
                                 "delete it and resume the job to make it again") from exc
    CHUNK.check(d, path)
    m = _CHUNK_RE.match(path.name)
    if m and int(m.group(1)) != d.get("chunk"):
        raise DatasetFormatError(f"{path} holds chunk {d.get('chunk')}, not the one its name says")
    if expect_params_sha256 is not None and d.get("params_sha256") != expect_params_sha256:
        raise DatasetFormatError(
            f"{path} was made with other job parameters or another trial-code revision than its store "
            f"(params {str(d.get('params_sha256'))[:12]} vs {expect_params_sha256[:12]}); it cannot be mixed in — "
            "move it away or build it in a store of its own")
    return d


# ---------------------------------------------------------------------------------------------
# the store record
# ---------------------------------------------------------------------------------------------
def read_store(store_dir: str | Path) -> dict:
    """The store record ``store_dir/store.json``. Raises :class:`DatasetFormatError`."""
    path = Path(store_dir) / STORE_FILE
    if not path.exists():
        raise DatasetFormatError(f"{store_dir} is not a data-set store (no {STORE_FILE})")
    return STORE.read(path)


def _write_store(store_dir: Path, job: DatasetJob, chunks: dict[int, dict]) -> None:
    listed = [chunks[c] for c in sorted(chunks)]
    shards = [ShardInfo(file=e["file"], worker="store", chunk=e["chunk"], n_samples=0, n_subsets=0,
                        n_grasps=0, sha256=e["sha256"], bytes=e["bytes"], stats=e["stats"]) for e in listed]
    summary = summarise(shards)
    summary.pop("samples", None)
    summary.update(chunks_done=len(listed), chunks_total=job.n_chunks, complete=len(listed) == job.n_chunks,
                   bytes=sum(e["bytes"] for e in listed))
    params = job.params()
    STORE.write(store_dir / STORE_FILE, {"params": params, "params_sha256": params_sha256(params),
                                         "chunks": listed, "summary": summary})


def _scan_chunks(store_dir: Path, params_sha: str, listed: dict[int, str]) -> dict[int, dict]:
    """Every valid finished chunk in the folder (a listed one must match its listed sha256)."""
    found: dict[int, dict] = {}
    for path in sorted((store_dir / CHUNK_DIR).glob("chunk_*.json.gz")):
        m = _CHUNK_RE.match(path.name)
        if not m:
            continue
        data = path.read_bytes()
        sha = hashlib.sha256(data).hexdigest()
        c = int(m.group(1))
        if c in listed and listed[c] != sha:
            raise DatasetIntegrityError(
                f"{path} differs from its entry in {store_dir / STORE_FILE} (sha256 {sha[:12]} vs "
                f"{listed[c][:12]}); restore it from git, or delete it to have it made again")
        rec = read_chunk(path, params_sha)
        found[c] = {"chunk": c, "file": f"{CHUNK_DIR}/{path.name}", "sha256": sha, "bytes": len(data),
                    "stats": rec["stats"]}
    return found


def open_store(store_dir: str | Path, job: DatasetJob | None = None) -> tuple[DatasetJob, dict[int, dict], dict]:
    """The store's job, its verified finished chunks and its record. With ``job``, it must match
    the store's parameters (a resume with other parameters is a :class:`DatasetJobError`)."""
    store_dir = Path(store_dir)
    rec = read_store(store_dir)
    have = rec["params"]
    if rec.get("params_sha256") != params_sha256(have):
        raise DatasetIntegrityError(f"{store_dir / STORE_FILE}: its params_sha256 does not match its parameters; "
                                    "restore the file from git")
    if job is not None:
        want = job.params()
        diff = [k for k in sorted(set(want) | set(have)) if k != "n_piles" and want.get(k) != have.get(k)]
        if diff:
            raise DatasetJobError(f"{store_dir} holds a store made with other parameters ({', '.join(diff)} "
                                  "differ); resume with the same parameters or choose a new folder")
    else:
        fields = DatasetJob.__dataclass_fields__
        job = DatasetJob(**{k: v for k, v in have.items() if k in fields})
    listed = {int(e["chunk"]): str(e["sha256"]) for e in rec.get("chunks", [])}
    found = _scan_chunks(store_dir, rec["params_sha256"], listed)
    missing = sorted(set(listed) - set(found))
    if missing:
        raise DatasetIntegrityError(f"{store_dir / STORE_FILE} lists chunks {missing[:5]} that are missing from "
                                    f"{store_dir / CHUNK_DIR}; restore them from git")
    return job, found, rec


# ---------------------------------------------------------------------------------------------
# the job
# ---------------------------------------------------------------------------------------------
def store_chunk(store_dir: str, job_dict: dict, chunk: int, simulate_factory: Callable | None = None) -> dict:
    """Simulate one chunk and write it (a worker's task); returns its listing entry."""
    job = DatasetJob(**job_dict)
    return write_chunk(store_dir, simulate_chunk(job, chunk, simulate_factory))


def build_store(store_dir: str | Path, job: DatasetJob, workers: int = 1,
                progress: Callable[[JobProgress], None] | None = None,
                simulate_factory: Callable | None = None) -> dict:
    """Build or resume the store in ``store_dir`` for ``job``; returns the store record.

    Chunks already in the folder (e.g. committed by another machine) are verified and kept;
    the rest are simulated, ``workers`` at a time (1 = in this process), each written atomically,
    and ``store.json`` is rewritten after every chunk."""
    store_dir = Path(store_dir)
    if job.piles_dir is not None:
        raise ValueError("a store generates its own piles (piles_dir must be None)")
    try:
        (store_dir / CHUNK_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DatasetJobError(f"cannot create the store folder {store_dir}: {exc.strerror or exc}") from exc
    if (store_dir / STORE_FILE).exists():
        _, done, _ = open_store(store_dir, job)
    else:
        done = _scan_chunks(store_dir, params_sha256(job.params()), {})
    for tmp in (store_dir / CHUNK_DIR).glob(".chunk_*.tmp"):
        tmp.unlink(missing_ok=True)
    _write_store(store_dir, job, done)
    todo = pending(range(job.n_chunks), done)
    t0, trials = time.perf_counter(), 0

    def finished(chunk: int, entry: dict) -> None:
        nonlocal trials
        done[entry["chunk"]] = entry
        trials += int(entry["stats"].get("trials", 0))
        _write_store(store_dir, job, done)
        if progress:
            el = time.perf_counter() - t0
            progress(JobProgress(chunks_done=len(done), chunks_total=job.n_chunks, samples=0, trials=trials,
                                 trials_per_s=trials / el if el > 0 else 0.0, elapsed_s=el))

    tasks = {c: (str(store_dir), job.to_dict(), c, simulate_factory) for c in todo}
    run_tasks(store_chunk, tasks, finished, workers=max(1, workers))  # 0 here: in this process
    return read_store(store_dir)


# ---------------------------------------------------------------------------------------------
# materialising the training shards
# ---------------------------------------------------------------------------------------------
def materialize(store_dir: str | Path, cache_dir: str | Path | None = None,
                progress: Callable[[int, int], None] | None = None) -> Path:
    """Training shards for every finished chunk of the store, made (once) in ``cache_dir``
    (default ``store_dir/.cache``); returns that folder, an ordinary data set for
    :mod:`synth.data.dataset` readers. A cached shard is reused only for the same chunk sha256."""
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    store_dir = Path(store_dir)
    job, chunks, store = open_store(store_dir)
    cache = Path(cache_dir) if cache_dir is not None else store_dir / CACHE_DIR
    cache.mkdir(parents=True, exist_ok=True)
    infos: list[ShardInfo] = []
    for i, c in enumerate(sorted(chunks)):
        entry = chunks[c]
        worker = f"s{entry['sha256'][:14]}m{MATERIALIZE_REVISION}"
        done_path = cache / f"shard_{worker}_{c:05d}.done.json"
        if done_path.exists():
            try:
                infos.append(ShardInfo.from_dict(json.loads(done_path.read_text())))
                continue
            except (OSError, ValueError, DatasetFormatError):
                pass
        rec = read_chunk(store_dir / entry["file"], store["params_sha256"])
        writer = ShardWriter(cache, worker, c)
        stats = dict(rec["stats"])
        for p in rec["piles"]:
            pile = PileSpec.from_dict(p["pile"])
            with World(pile) as world:
                obs = render_ortho(world, OrthoRenderConfig(size_px=job.size_px, n_renders=job.n_renders),
                                   seed=int(p["pile_seed"]))
            add_pile_samples(writer, job, pile, p["pile_id"], obs, [_subset_from(s) for s in p["subsets"]],
                             stats)
        if len(writer):
            infos.append(writer.close(stats))
        if progress:
            progress(i + 1, len(chunks))
    grid = next((s.stats["grid"] for s in infos if "grid" in s.stats),
                {"size_px": job.size_px, "extent_m": 5.0, "camera_height_m": 5.0})
    summary = summarise(infos)
    summary.update(chunks_done=len(chunks), chunks_total=job.n_chunks, complete=len(chunks) == job.n_chunks,
                   store=str(store_dir))
    write_manifest(cache, Manifest(params=store["params"], grid=dict(grid), shards=infos, summary=summary))
    for stale in cache.glob("shard_*.npz"):
        if stale.name not in {s.file for s in infos}:
            stale.unlink(missing_ok=True)
            Path(str(stale)[:-4] + ".done.json").unlink(missing_ok=True)
    return cache


#: what a lent GPU machine takes along (its file limit is 64 MiB, with the code)
EXPORT_BUDGET_BYTES = 60 * 2 ** 20


def export_training(store_dir: str | Path, out_dir: str | Path, max_bytes: int = EXPORT_BUDGET_BYTES,
                    progress: Callable[[int, int], None] | None = None) -> tuple[Path, int]:
    """The store's training shards rendered into ``out_dir``: an ordinary data set (manifest.json
    + compressed .npz shards) that :mod:`planner` trains on with numpy and torch alone, so it can
    travel to a machine without pybullet. Resumable like :func:`materialize` (it is the same
    cache). Returns the folder and its size in bytes; raises :class:`DatasetJobError` when the
    export exceeds ``max_bytes`` (the folder stays, complete, for a machine that takes more)."""
    out = materialize(store_dir, out_dir, progress=progress)
    size = sum(f.stat().st_size for f in out.iterdir() if f.is_file())
    if size > max_bytes:
        raise DatasetJobError(
            f"the training export in {out} is {size / 2 ** 20:.1f} MiB, over the {max_bytes / 2 ** 20:.0f} MiB "
            "a device machine takes along; export fewer piles (a smaller store) or raise --max-mib")
    return out, size


def data_folder(path: str | Path) -> Path:
    """The folder a trainer reads: a store is materialised first; any other folder is itself."""
    return materialize(path) if is_store(path) else Path(path)


__all__ = ["build_store", "materialize", "export_training", "data_folder", "open_store", "read_store", "read_chunk",
           "simulate_chunk", "is_store", "read_manifest"]
