"""The grasp training data set on disk: format (shards + manifest), its writer and its reader.

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
    instance     (P, H, W)    int16    (optional) which body each pixel sees: 0 ground, i + 1 log i, 1000 + j
                                       obstacle j (synth.render.ortho); the other logs' and the obstacles'
                                       masks the grasp ranker sees
    samples      (N, 3)       int32    (pile index, intensity index, subset index)
    meta         (bytes,)     uint8    JSON: format, version, worker, chunk, piles, renders, subsets
"""

from __future__ import annotations

import hashlib
import io
import json
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from synth.common.files import atomic_write_bytes, sha256_file
from synth.common.formats import VersionedJson
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
    instance: np.ndarray | None = None  # (H, W) int16 instance codes of the pile (synth.render.ortho); None = not recorded

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
        if self.instance is not None and np.shape(self.instance) != (h, w):
            raise ValueError(f"sample {self.pile_id}/{self.subset}: instance must be ({h}, {w}), got {np.shape(self.instance)}")


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
        self._instance: list[np.ndarray | None] = []
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
            self._instance.append(None if sample.instance is None else np.asarray(sample.instance, dtype=np.int16))
            self._pile_meta.append({"pile_id": pid, "n_logs": int(sample.n_logs)})
            if (self._instance[-1] is None) != (self._instance[0] is None):
                raise ValueError(f"pile {pid}: a shard's piles must all carry their instance map or none")
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
        if self._instance[0] is not None:
            extra["instance"] = np.stack(self._instance)
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
        write_atomic(self.path, data)
        record = {"format": SHARD_FORMAT_NAME + ".done", "format_version": DATASET_FORMAT_VERSION, **info.to_dict()}
        write_atomic(done_record_path(self.path), json.dumps(record, indent=1).encode())
        self.closed = True
        return info


def write_atomic(path: Path, data: bytes) -> None:
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
                                        "trials", "trial_start", "instance") if k in z.files}
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
                instance=arrays["instance"][p] if "instance" in arrays else None,
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
    write_atomic(path, json.dumps(manifest.to_dict(), indent=1).encode())
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
        check_shard_file(data_dir / s.file, s, checksums)
    return man


def check_shard_file(path: Path, info: ShardInfo, checksum: bool) -> None:
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
        check_shard_file(path, s, verify)
        samples = load_shard(path)
        if len(samples) != s.n_samples:
            raise DatasetIntegrityError(f"shard {s.file} holds {len(samples)} samples, the manifest says {s.n_samples}")
        yield from samples
