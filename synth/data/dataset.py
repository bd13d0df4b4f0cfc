"""The grasp training data set: format (shards + manifest), reader, writer, and the job that builds it.

On disk a data set is one folder::

    DIR/manifest.json                       format name + version, generation parameters, grid,
                                            the list of complete shards (sample counts, sha256),
                                            summary statistics; rewritten atomically, only ever
                                            from completed shards
    DIR/shard_<worker>_<nnnnn>.npz          one chunk of piles, written by ONE worker, atomically
    DIR/shard_<worker>_<nnnnn>.done.json    the shard's done record (sha256, counts, statistics),
                                            written after the shard; a shard without it is partial

A **sample** is one (pile, render ``r``, target subset ``T``): the render's intensity image, the
pile's depth image, the target mask ``M_T`` and the five target maps (see :mod:`synth.data.maps`).
Several renders of a scene share the depth, the mask and the maps; a shard stores each of them
once and :func:`load_shard` expands them into :class:`Sample` objects (sharing memory).

Shard arrays (``npz``, compressed; P piles, Q renders, K subsets, N samples, G grasps)::

    depth        (P, H, W)    float32  metres from the camera plane (height = camera_height - depth)
    intensity    (Q, H, W)    float32  [0, 1], colour channels summed and normalised
    target_mask  (K, H, W)    bool     M_T
    maps         (K, 5, H, W) float32  C, S, W [m], U, B (synth.data.maps.MAP_CHANNELS)
    grasps       (G, 5)       float64  x [m], y [m], phi [rad, pile frame], width [m], balance cos(beta)
    grasp_start  (K + 1,)     int64    subset k's grasps are grasps[grasp_start[k]:grasp_start[k+1]]
    trials       (T, 6)       float64  (optional) every trial of every subset: x, y, phi, width, success
                                       value, cos beta (synth.data.outcomes); subset k's are
                                       trials[trial_start[k]:trial_start[k+1]], its meta says "capped"
    trial_start  (K + 1,)     int64    (with trials)
    samples      (N, 3)       int32    (pile index, intensity index, subset index)
    meta         (bytes,)     uint8    JSON: format, version, worker, chunk, piles, renders, subsets
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from synth.common.files import atomic_write_bytes, make_writable_dir, sha256_file
from synth.common.formats import VersionedJson, major
from synth.common.runner import worker_died
from synth.errors import SynthError
from synth.geometry.grasp import Grasp

DATASET_FORMAT_NAME = "loggrasp.grasp_dataset"
SHARD_FORMAT_NAME = "loggrasp.grasp_shard"
DATASET_FORMAT_VERSION = "1.1"
# 1.1: U marks each grasp's 20 x 20 cm graspable region around its centre (synth.data.maps); 1.0 marked
# its whole footprint between the claw tips. 1.0 shards are re-encoded from their grasps on load.
MANIFEST_NAME = "manifest.json"
_SHARD_RE = re.compile(r"^shard_([A-Za-z0-9-]+)_(\d{5,})\.npz$")


class DatasetError(SynthError):
    """Root of data-set errors."""


class DatasetFormatError(DatasetError):
    """A manifest or shard is missing, unreadable, corrupted or of an unsupported version."""


class DatasetIntegrityError(DatasetError):
    """The data set disagrees with its manifest (missing shard, checksum or count mismatch)."""


MANIFEST = VersionedJson(DATASET_FORMAT_NAME, DATASET_FORMAT_VERSION, "grasp data-set manifest",
                         DatasetFormatError, fix="regenerate it or upgrade loggrasp", filename=MANIFEST_NAME)
SHARD_META = VersionedJson(SHARD_FORMAT_NAME, DATASET_FORMAT_VERSION, "grasp shard", DatasetFormatError,
                           fix="regenerate the data set or upgrade loggrasp")


# ---------------------------------------------------------------------------------------------
# samples
# ---------------------------------------------------------------------------------------------
@dataclass
class Sample:
    """One training sample: a render of a pile, a target subset and its grasp target maps."""

    pile_id: str  # e.g. "pile_00012" or the pile's seed
    render: int  # index of the intensity render of this scene [-]
    subset: tuple[int, ...]  # target log indices, sorted, 0-based
    intensity: np.ndarray  # (H, W) float32 in [0, 1]
    depth: np.ndarray  # (H, W) float32 [m] from the camera plane
    target_mask: np.ndarray  # (H, W) bool, M_T
    maps: np.ndarray  # (5, H, W) float32: C, S, W [m], U, B
    grasps: np.ndarray  # (n, 5) float64: x [m], y [m], phi [rad], width [m], balance [-]
    negative: bool  # True when no successful grasp was found for the subset
    n_logs: int = 0  # logs in the pile [-]
    n_candidates: int | None = None  # admissible geometric candidates of the subset; None = not recorded [-]
    trials: np.ndarray | None = None  # (t, 6) every trial run on the subset (synth.data.outcomes.TRIAL_COLUMNS); None = not recorded
    capped: bool | None = None  # the subset's trials hit the cap with candidates left; None = not recorded

    @property
    def tau(self) -> int:
        """Number of target logs |T|."""
        return len(self.subset)

    def grasp_list(self) -> list[tuple[Grasp, float]]:
        """The annotated grasps as ``(Grasp, balance)`` pairs."""
        return [(Grasp(float(x), float(y), float(p), float(w)), float(b)) for x, y, p, w, b in self.grasps]

    def validate(self) -> None:
        """Raise ``ValueError`` if any field is malformed (shapes, ranges, consistency)."""
        h, w = np.shape(self.depth)
        if np.shape(self.intensity) != (h, w) or np.shape(self.target_mask) != (h, w):
            raise ValueError(f"sample {self.pile_id}/{self.subset}: intensity, depth and mask shapes differ")
        if np.shape(self.maps) != (5, h, w):
            raise ValueError(f"sample {self.pile_id}/{self.subset}: maps must be (5, {h}, {w}), got {np.shape(self.maps)}")
        if not self.subset or list(self.subset) != sorted(set(int(t) for t in self.subset)) or min(self.subset) < 0:
            raise ValueError(f"sample {self.pile_id}: subset must be sorted, unique, non-negative log indices, got {self.subset}")
        if self.n_logs and max(self.subset) >= self.n_logs:
            raise ValueError(f"sample {self.pile_id}: subset {self.subset} names a log beyond the pile's {self.n_logs}")
        for name in ("intensity", "depth", "maps"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"sample {self.pile_id}/{self.subset}: {name} holds NaN or infinity")
        if np.min(self.intensity) < 0 or np.max(self.intensity) > 1:
            raise ValueError(f"sample {self.pile_id}: intensity must lie in [0, 1]")
        g = np.asarray(self.grasps, dtype=np.float64).reshape(-1, 5)
        if bool(self.negative) != (len(g) == 0):
            raise ValueError(f"sample {self.pile_id}/{self.subset}: negative={self.negative} but {len(g)} grasps")
        self.grasp_list()  # validates widths and finiteness
        if not np.all((g[:, 4] >= -1) & (g[:, 4] <= 1)):
            raise ValueError(f"sample {self.pile_id}/{self.subset}: balance must be cos(beta) in [-1, 1]")
        if self.render < 0:
            raise ValueError("render index must be >= 0")
        if self.trials is not None:
            t = np.asarray(self.trials, dtype=np.float64)
            if t.ndim != 2 or t.shape[1] != 6 or not np.all(np.isfinite(t[:, :5])) or np.any((t[:, 4] < 0) | (t[:, 4] > 1)):
                raise ValueError(f"sample {self.pile_id}/{self.subset}: trials must be (n, 6) rows with finite grasps "
                                 "and a success value in [0, 1]")


@dataclass(frozen=True)
class ShardInfo:
    """A complete shard as listed in the manifest and in its done record."""

    file: str  # file name inside the data-set folder
    worker: str
    chunk: int
    n_samples: int
    n_subsets: int
    n_grasps: int
    sha256: str
    bytes: int
    stats: dict = field(default_factory=dict)  # per-shard statistics (trials, outcomes, ...)

    def to_dict(self) -> dict:
        return {"file": self.file, "worker": self.worker, "chunk": self.chunk, "n_samples": self.n_samples,
                "n_subsets": self.n_subsets, "n_grasps": self.n_grasps, "sha256": self.sha256,
                "bytes": self.bytes, "stats": self.stats}

    @staticmethod
    def from_dict(d: dict) -> "ShardInfo":
        try:
            return ShardInfo(file=str(d["file"]), worker=str(d["worker"]), chunk=int(d["chunk"]),
                             n_samples=int(d["n_samples"]), n_subsets=int(d["n_subsets"]),
                             n_grasps=int(d["n_grasps"]), sha256=str(d["sha256"]), bytes=int(d["bytes"]),
                             stats=dict(d.get("stats", {})))
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetFormatError(f"malformed shard record {d!r}: {exc}") from exc


def shard_name(worker: str, chunk: int) -> str:
    """``shard_<worker>_<nnnnn>.npz``; ``worker`` may use letters, digits and '-'."""
    if not re.fullmatch(r"[A-Za-z0-9-]+", str(worker)):
        raise ValueError(f"worker label must use letters, digits and '-', got {worker!r}")
    if chunk < 0:
        raise ValueError(f"chunk index must be >= 0, got {chunk}")
    return f"shard_{worker}_{chunk:05d}.npz"


def done_record_path(shard_path: Path) -> Path:
    return shard_path.with_name(shard_path.name[: -len(".npz")] + ".done.json")


class ShardWriter:
    """Collects samples of one chunk and writes them as one shard (atomically) plus its done record.

    Samples of the same pile share the depth (keyed by ``pile_id``), renders are keyed by
    ``(pile_id, render)`` and subsets (mask, maps, grasps) by ``(pile_id, subset)``; each is stored
    once. Nothing is written before :meth:`close`; a writer that is never closed leaves nothing.
    """

    def __init__(self, out_dir: str | Path, worker: str, chunk: int) -> None:
        self.out_dir = Path(out_dir)
        self.worker = str(worker)
        self.chunk = int(chunk)
        self.path = self.out_dir / shard_name(self.worker, self.chunk)
        self._piles: dict[str, int] = {}
        self._pile_meta: list[dict] = []
        self._depth: list[np.ndarray] = []
        self._renders: dict[tuple[str, int], int] = {}
        self._intensity: list[np.ndarray] = []
        self._subsets: dict[tuple[str, tuple[int, ...]], int] = {}
        self._subset_meta: list[dict] = []
        self._mask: list[np.ndarray] = []
        self._maps: list[np.ndarray] = []
        self._grasps: list[np.ndarray] = []
        self._trials: list[np.ndarray | None] = []
        self._samples: list[tuple[int, int, int]] = []
        self._shape: tuple[int, int] | None = None
        self.closed = False

    def __len__(self) -> int:
        return len(self._samples)

    def add(self, sample: Sample) -> None:
        """Add one sample (validated; ``ValueError`` on malformed data)."""
        if self.closed:
            raise ValueError("this shard is already written; start a new ShardWriter")
        sample.validate()
        shape = tuple(np.shape(sample.depth))
        if self._shape is None:
            self._shape = shape
        elif shape != self._shape:
            raise ValueError(f"all samples of a shard need the same image size, got {shape} and {self._shape}")
        pid = str(sample.pile_id)
        if pid not in self._piles:
            self._piles[pid] = len(self._depth)
            self._depth.append(np.asarray(sample.depth, dtype=np.float32))
            self._pile_meta.append({"pile_id": pid, "n_logs": int(sample.n_logs)})
        p = self._piles[pid]
        rkey = (pid, int(sample.render))
        if rkey not in self._renders:
            self._renders[rkey] = len(self._intensity)
            self._intensity.append(np.asarray(sample.intensity, dtype=np.float32))
        q = self._renders[rkey]
        subset = tuple(int(t) for t in sample.subset)
        skey = (pid, subset)
        g = np.asarray(sample.grasps, dtype=np.float64).reshape(-1, 5)
        if skey not in self._subsets:
            self._subsets[skey] = len(self._maps)
            self._mask.append(np.asarray(sample.target_mask, dtype=bool))
            self._maps.append(np.asarray(sample.maps, dtype=np.float32))
            self._grasps.append(g)
            self._trials.append(None if sample.trials is None else np.asarray(sample.trials, np.float64).reshape(-1, 6))
            self._subset_meta.append({"pile": p, "subset": list(subset), "negative": bool(sample.negative)}
                                     | ({} if sample.n_candidates is None else {"n_candidates": int(sample.n_candidates)})
                                     | ({} if sample.capped is None else {"capped": bool(sample.capped)}))
            if (self._trials[-1] is None) != (self._trials[0] is None):
                raise ValueError(f"pile {pid} subset {subset}: a shard's subsets must all carry their trials or none")
        k = self._subsets[skey]
        if not np.array_equal(self._grasps[k], g):
            raise ValueError(f"pile {pid} subset {subset} was added twice with different grasps")
        self._samples.append((p, q, k))

    def close(self, stats: dict | None = None) -> ShardInfo:
        """Write the shard atomically, then its done record; return its :class:`ShardInfo`.

        An ``OSError`` (e.g. a full disk) propagates and leaves no shard and no done record.
        """
        if self.closed:
            raise ValueError("this shard is already written")
        if not self._samples:
            raise ValueError("a shard needs at least one sample")
        h, w = self._shape
        starts = np.zeros(len(self._grasps) + 1, dtype=np.int64)
        starts[1:] = np.cumsum([len(g) for g in self._grasps])
        meta = {
            "format": SHARD_FORMAT_NAME, "format_version": DATASET_FORMAT_VERSION, "worker": self.worker,
            "chunk": self.chunk, "n_samples": len(self._samples), "piles": self._pile_meta,
            "renders": [[self._piles[pid], r] for (pid, r) in self._renders],
            "subsets": self._subset_meta,
        }
        buf = io.BytesIO()
        extra = {}
        if self._trials and self._trials[0] is not None:
            extra["trial_start"] = np.concatenate([[0], np.cumsum([len(t) for t in self._trials])]).astype(np.int64)
            extra["trials"] = np.concatenate(self._trials).reshape(-1, 6)
        np.savez_compressed(
            buf, depth=np.stack(self._depth), intensity=np.stack(self._intensity),
            target_mask=np.stack(self._mask), maps=np.stack(self._maps),
            grasps=np.concatenate(self._grasps).reshape(-1, 5) if starts[-1] else np.zeros((0, 5)),
            grasp_start=starts, samples=np.asarray(self._samples, dtype=np.int32).reshape(-1, 3),
            meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **extra,
        )
        data = buf.getvalue()
        info = ShardInfo(
            file=self.path.name, worker=self.worker, chunk=self.chunk, n_samples=len(self._samples),
            n_subsets=len(self._maps), n_grasps=int(starts[-1]), sha256=hashlib.sha256(data).hexdigest(),
            bytes=len(data), stats=dict(stats or {}),
        )
        _write_bytes(self.path, data)
        record = {"format": SHARD_FORMAT_NAME + ".done", "format_version": DATASET_FORMAT_VERSION, **info.to_dict()}
        _write_bytes(done_record_path(self.path), json.dumps(record, indent=1).encode())
        self.closed = True
        return info


def _write_bytes(path: Path, data: bytes) -> None:
    """Atomic write (temp + rename); the seam where tests inject a full disk."""
    atomic_write_bytes(path, data)


def load_shard(path: str | Path) -> list[Sample]:
    """All samples of one shard. Raises :class:`DatasetFormatError` for a missing, truncated or
    corrupted shard or an unsupported version."""
    path = Path(path)
    try:
        with np.load(path) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            arrays = {k: z[k] for k in ("depth", "intensity", "target_mask", "maps", "grasps", "grasp_start", "samples",
                                        "trials", "trial_start") if k in z.files}
    except FileNotFoundError as exc:
        raise DatasetFormatError(f"shard {path} does not exist; re-run the data-set job to regenerate it") from exc
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, UnicodeDecodeError) as exc:
        raise DatasetFormatError(
            f"shard {path} is corrupted or not a loggrasp shard ({type(exc).__name__}: {exc}); "
            "delete it and its .done.json and re-run the data-set job"
        ) from exc
    SHARD_META.check(meta, path)
    try:
        piles, renders, subsets = meta["piles"], meta["renders"], meta["subsets"]
        starts, samples = arrays["grasp_start"], arrays["samples"]
        tstart = arrays.get("trial_start")
        if tstart is not None and len(tstart) != len(subsets) + 1:
            raise ValueError("trial_start disagrees with the shard's subsets")
        if len(samples) != int(meta["n_samples"]) or len(starts) != len(subsets) + 1:
            raise ValueError("array lengths disagree with the shard's metadata")
        if meta.get("format_version") == "1.0":
            arrays["maps"] = _reencode_1_0(path, arrays)
        out = []
        for p, q, k in samples:
            sm = subsets[k]
            out.append(Sample(
                pile_id=piles[p]["pile_id"], render=int(renders[q][1]), subset=tuple(sm["subset"]),
                intensity=arrays["intensity"][q], depth=arrays["depth"][p], target_mask=arrays["target_mask"][k],
                maps=arrays["maps"][k], grasps=arrays["grasps"][starts[k]:starts[k + 1]],
                negative=bool(sm["negative"]), n_logs=int(piles[p].get("n_logs", 0)),
                n_candidates=None if sm.get("n_candidates") is None else int(sm["n_candidates"]),
                trials=None if tstart is None else arrays["trials"][tstart[k]:tstart[k + 1]],
                capped=None if sm.get("capped") is None else bool(sm["capped"]),
            ))
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise DatasetFormatError(f"shard {path} is inconsistent ({exc}); delete it and re-run the job") from exc
    return out


def _reencode_1_0(path: Path, arrays: dict) -> np.ndarray:
    """The maps of a format 1.0 shard encoded anew from its stored grasps: 1.0 marked a grasp's
    whole footprint between the claw tips in U, 1.1 its graspable region (:mod:`synth.data.maps`).
    The grid's extent comes from the shard's done record."""
    from synth.geometry.frames import OrthoGrid
    from synth.data.maps import encode_grasps

    rec_path = done_record_path(path)
    try:
        extent_m = float(json.loads(rec_path.read_text())["stats"]["grid"]["extent_m"])
    except (OSError, KeyError, TypeError, ValueError) as exc:
        raise DatasetFormatError(
            f"{path} is a format 1.0 shard; its maps are re-encoded from its grasps, which needs the image "
            f"extent from its done record {rec_path.name} ({type(exc).__name__}: {exc}); regenerate the data set"
        ) from exc
    old = arrays["maps"]
    grid = OrthoGrid(int(old.shape[-1]), extent_m)
    starts, G = arrays["grasp_start"], arrays["grasps"]
    maps = np.empty_like(old)
    for k in range(len(old)):
        rows = G[starts[k]:starts[k + 1]]
        maps[k] = encode_grasps(grid, [Grasp(float(x), float(y), float(p), float(w)) for x, y, p, w, _ in rows],
                                [float(r[4]) for r in rows])
    return maps


# ---------------------------------------------------------------------------------------------
# manifest
# ---------------------------------------------------------------------------------------------
@dataclass
class Manifest:
    """The data set's table of contents (``manifest.json``)."""

    params: dict  # generation parameters
    grid: dict  # size_px, extent_m, camera_height_m
    shards: list[ShardInfo]
    summary: dict  # statistics over the listed shards
    format_version: str = DATASET_FORMAT_VERSION

    @property
    def n_samples(self) -> int:
        return sum(s.n_samples for s in self.shards)

    def to_dict(self) -> dict:
        return {"format": DATASET_FORMAT_NAME, "format_version": self.format_version,
                "map_channels": ["C", "S", "W", "U", "B"], "params": self.params, "grid": self.grid,
                "shards": [s.to_dict() for s in self.shards], "summary": self.summary}


def write_manifest(out_dir: str | Path, manifest: Manifest) -> Path:
    path = Path(out_dir) / MANIFEST_NAME
    _write_bytes(path, json.dumps(manifest.to_dict(), indent=1).encode())
    return path


def read_manifest(data_dir: str | Path) -> Manifest:
    """Read ``DIR/manifest.json`` (or a path to it). Raises :class:`DatasetFormatError`."""
    path = MANIFEST.path(data_dir)
    d = MANIFEST.read(path)
    try:
        return Manifest(params=dict(d["params"]), grid=dict(d["grid"]),
                        shards=[ShardInfo.from_dict(s) for s in d["shards"]], summary=dict(d.get("summary", {})),
                        format_version=str(d["format_version"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetFormatError(f"{path} is malformed: {exc}") from exc


def verify_dataset(data_dir: str | Path, checksums: bool = True) -> Manifest:
    """Check that every shard the manifest lists exists with its size (and sha256 when
    ``checksums``). Raises :class:`DatasetIntegrityError` on the first mismatch."""
    data_dir = Path(data_dir)
    man = read_manifest(data_dir)
    for s in man.shards:
        _check_shard_file(data_dir / s.file, s, checksums)
    return man


def _check_shard_file(path: Path, info: ShardInfo, checksum: bool) -> None:
    if not path.is_file():
        raise DatasetIntegrityError(
            f"shard {path.name} listed in the manifest is missing; re-run the data-set job to regenerate it"
        )
    size = path.stat().st_size
    if size != info.bytes:
        raise DatasetIntegrityError(f"shard {path.name} has {size} bytes, the manifest says {info.bytes}; "
                                    "it was changed or truncated — delete it and its .done.json and re-run the job")
    if checksum and sha256_file(path) != info.sha256:
        raise DatasetIntegrityError(f"shard {path.name} fails its sha256 check; delete it and its .done.json "
                                    "and re-run the job")


def iter_samples(data_dir: str | Path, verify: bool = True) -> Iterator[Sample]:
    """Every sample of the data set, shard by shard in manifest order. With ``verify`` each shard's
    size and sha256 are checked against the manifest first (:class:`DatasetIntegrityError`)."""
    data_dir = Path(data_dir)
    man = read_manifest(data_dir)
    for s in man.shards:
        path = data_dir / s.file
        _check_shard_file(path, s, verify)
        samples = load_shard(path)
        if len(samples) != s.n_samples:
            raise DatasetIntegrityError(f"shard {s.file} holds {len(samples)} samples, the manifest says {s.n_samples}")
        yield from samples


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
    n_logs: int = 4  # logs per pile [-] (the paper: 4)
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

        from synth.physics.trial import TRIAL_REVISION

        d = {**self.to_dict(), "trial_revision": TRIAL_REVISION, "trial_config_values": asdict(self.trial_config()),
             "candidate_config_values": asdict(self.candidate_config()), "format_version": DATASET_FORMAT_VERSION}
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


def _subsets(n: int) -> list[tuple[int, ...]]:
    from itertools import combinations

    return [c for k in range(1, n + 1) for c in combinations(range(n), k)]


def _load_source_pile(job: DatasetJob, k: int):
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
    pile, report = generate_pile(pile_seed, GenerationConfig(n_logs=job.n_logs, n_obstacles=n_obst))
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
    for T in _subsets(pile.n_logs):
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
                              trials=trials, capped=sub.capped))


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
            pile, obs, pile_id, info = _load_source_pile(job, k)
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
    _write_bytes(done_record_path(path), json.dumps(record, indent=1).encode())
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
                _check_shard_file(out / info.file, info, checksum=True)
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
    job = DatasetJob(n_piles=n_piles, n_logs=n_logs, obstacles_fraction=obstacles_fraction,
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
