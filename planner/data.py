"""Network inputs and the training data stream.

Input normalisation (shared by training and :mod:`planner.inference`, one function each):

* intensity: as rendered, in [0, 1];
* depth -> relative height: ``h = camera_height_m - depth`` [m] minus the *median of h over the
  whole image*. Logs cover a small part of the 5 m x 5 m patch (7 logs ~ 10 %), so the median is
  a robust estimate of the ground height under the pile without needing the instance map (which
  training samples do not carry); the network thus sees heights above the local ground, in metres,
  independent of where the patch lies in the terrain;
* target mask M_T: 0/1.

The data stream reads the synthetic data set of :mod:`synth.data.dataset` shard by shard (memory stays
at one shard) and splits it 80/20 into training and validation **by pile**: a pile goes to the
validation side when a stable hash of ``(seed, pile id)`` falls below ``val_fraction``, so the
same pile is never on both sides, the split is deterministic from the seed, and no global listing
of piles is needed.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Literal

import numpy as np

from planner.augment import AugmentConfig, augment
from planner.errors import DataError
from synth.data.outcomes import OutcomeLabelConfig


def normalise_depth(depth: np.ndarray, camera_height_m: float = 5.0) -> np.ndarray:
    """Depth [m] from the camera plane -> height above the image's median height [m] (float32)."""
    h = camera_height_m - np.asarray(depth, dtype=np.float32)
    return (h - np.float32(np.median(h))).astype(np.float32)


def make_inputs(intensity: np.ndarray, depth: np.ndarray, masks: np.ndarray, in_channels: int = 3,
                camera_height_m: float = 5.0) -> np.ndarray:
    """Network input (N, in_channels, H, W) float32 for one image and N target masks (N, H, W)."""
    masks = np.asarray(masks)
    if masks.ndim == 2:
        masks = masks[None]
    n, h, w = masks.shape
    x = np.empty((n, in_channels, h, w), dtype=np.float32)
    x[:, 0] = np.asarray(intensity, dtype=np.float32)
    if in_channels == 3:
        x[:, 1] = normalise_depth(depth, camera_height_m)
    x[:, -1] = masks
    return x


def is_validation_pile(pile_id, seed: int = 0, val_fraction: float = 0.2) -> bool:
    """Deterministic by-pile split: True if ``pile_id`` belongs to the validation side."""
    digest = hashlib.blake2b(f"{seed}:{pile_id}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") / 2 ** 64 < val_fraction


def in_train_fraction(pile_id, seed: int = 0, fraction: float = 1.0) -> bool:
    """Deterministic, nested choice of training piles: True if ``pile_id`` is among the first
    ``fraction`` of them (by a hash independent of the validation split's)."""
    if fraction >= 1.0:
        return True
    digest = hashlib.blake2b(f"train-share:{seed}:{pile_id}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") / 2 ** 64 < fraction


def sample_pile_id(sample) -> str:
    """The pile identifier of a :mod:`synth.data.shards` sample (its ``pile_id`` attribute or metadata)."""
    for obj in (sample, getattr(sample, "meta", None), getattr(sample, "metadata", None)):
        if obj is None:
            continue
        v = obj.get("pile_id") if isinstance(obj, dict) else getattr(obj, "pile_id", None)
        if v is not None:
            return str(v)
    raise DataError("a data set sample carries no pile id; the by-pile split needs one (regenerate the data set)")


@dataclass(frozen=True)
class DataConfig:
    val_fraction: float = 0.2  # share of piles held out for validation [-]
    split_seed: int = 0  # seed of the by-pile split [-]
    camera_height_m: float = 5.0  # camera plane above the datum, as rendered [m]
    in_channels: int = 3  # 3 = (I, D, M_T), 2 = (I, M_T)
    shuffle_buffer: int = 256  # samples shuffled together across shards [-]
    train_fraction: float = 1.0  # share of the training side's piles used (nested: a smaller share
    # is a subset of a larger one; the validation piles stay the same) [-]
    skip_no_candidates: bool = False  # leave out subsets that had no admissible grasp candidate
    # (the paper's 5,491 samples of 9,060 subsets look like this; needs shards with n_candidates) [-]
    labels: Literal["accepted", "outcome"] = "accepted"  # U's target: "accepted" (1 on the grasps Algorithm 1
    # accepted, the paper's) or "outcome" (every tried centre labelled by its outcome, synth.data.outcomes)
    outcome: OutcomeLabelConfig = field(default_factory=OutcomeLabelConfig)  # BCE weights of the outcome labels

    def __post_init__(self) -> None:
        if self.labels not in ("accepted", "outcome"):
            raise ValueError(f"labels must be 'accepted' or 'outcome', got {self.labels!r}")
        if self.labels == "outcome" and self.skip_no_candidates:
            raise ValueError("skip_no_candidates cannot be combined with outcome labels: it hides the subsets "
                             "without a candidate, which inference scores; drop --skip-no-candidates")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction}")
        if not 0.0 < self.train_fraction <= 1.0:
            raise ValueError(f"train_fraction must be in (0, 1], got {self.train_fraction}")
        if self.in_channels not in (2, 3):
            raise ValueError(f"in_channels must be 2 or 3, got {self.in_channels}")
        if self.shuffle_buffer < 1:
            raise ValueError("shuffle_buffer must be >= 1")


def list_shards(data_dir: str | Path | list) -> tuple[list[Path], dict]:
    """Shard files of a data set in manifest order, and the manifest's grid (size_px, extent_m,
    camera_height_m), via :func:`synth.data.shards.read_manifest`. A list of folders gives all their
    shards (in the order given); their grids must agree."""
    if isinstance(data_dir, (list, tuple)):
        if not data_dir:
            raise DataError("no data set folder given")
        shards, grid = list_shards(data_dir[0])
        for d in data_dir[1:]:
            more, g = list_shards(d)
            if g != grid:
                raise DataError(f"data set {d} has image grid {g} but {data_dir[0]} has {grid}; "
                                "data sets trained together must share size_px, extent_m and camera height")
            shards += more
        return shards, grid
    from synth.data import shards as ds
    from synth.data.datastore import data_folder

    try:
        data_dir = data_folder(data_dir)  # a committed store is rendered into its cache first
        manifest = ds.read_manifest(data_dir)
    except ds.DatasetError as exc:
        raise DataError(f"cannot use the data set in {data_dir}: {exc}") from exc
    shards = [data_dir / s.file for s in manifest.shards]
    if not shards:
        raise DataError(f"data set {data_dir} lists no complete shards; generate data first")
    return shards, dict(manifest.grid)


def load_samples(shard: Path):
    from synth.data import shards as ds

    try:
        return list(ds.load_shard(shard))
    except ds.DatasetError as exc:
        raise DataError(f"cannot read data shard {shard}: {exc}") from exc


def sample_arrays(sample) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    inten = np.asarray(sample.intensity, dtype=np.float32)
    if inten.ndim == 3:
        inten = inten[0]
    return inten, np.asarray(sample.depth, np.float32), np.asarray(sample.target_mask, bool), np.asarray(sample.maps, np.float32)


class ShardStream:
    """Iterable over (input (C, H, W), target (5, H, W)) float32 numpy pairs of one split.

    ``split`` is "train" (augmented, shuffled with ``epoch``-dependent order) or "val" (fixed
    order, no augmentation). ``shards`` may be given directly (tests) instead of ``data_dir``."""

    def __init__(self, shards: list[Path], split: str, config: DataConfig = DataConfig(),
                 augment_config: AugmentConfig = AugmentConfig(), seed: int = 0, loader=load_samples,
                 extent_m: float = 5.0, b_encoding: str = "cos_beta") -> None:
        from planner.model import B_ENCODINGS

        if split not in ("train", "val"):
            raise ValueError(f"split must be 'train' or 'val', got {split!r}")
        if b_encoding not in B_ENCODINGS:
            raise ValueError(f"b_encoding must be one of {list(B_ENCODINGS)}, got {b_encoding!r}")
        self.shards, self.split, self.config = list(shards), split, config
        self.extent_m, self.b_encoding = float(extent_m), b_encoding
        self.augment_config = augment_config if split == "train" else AugmentConfig.off()
        self.seed, self.epoch, self.loader = seed, 0, loader

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _keep(self, sample) -> bool:
        if self.config.skip_no_candidates:
            n = getattr(sample, "n_candidates", None)
            if n is None:
                raise DataError(f"sample {sample_pile_id(sample)}/{tuple(sample.subset)} carries no candidate count, "
                                "so --skip-no-candidates cannot tell which subsets had none; train from a grasp "
                                "store (its shards are re-made with the counts) or drop the flag")
            if n == 0:
                return False
        if self.config.labels == "outcome" and getattr(sample, "trials", None) is None:
            raise DataError(f"sample {sample_pile_id(sample)}/{tuple(sample.subset)} carries no trial outcomes, which "
                            "--labels outcome needs; train from a grasp store (its shards are re-made with every "
                            "trial) or use --labels accepted")
        pile_id = sample_pile_id(sample)
        val = is_validation_pile(pile_id, self.config.split_seed, self.config.val_fraction)
        if self.split == "val":
            return val
        return not val and in_train_fraction(pile_id, self.config.split_seed, self.config.train_fraction)

    def _convert(self, sample, rng) -> tuple[np.ndarray, np.ndarray]:
        inten, depth, mask, maps = sample_arrays(sample)
        if self.config.labels == "outcome":
            from synth.data.outcomes import outcome_targets
            from synth.geometry.frames import OrthoGrid

            maps = outcome_targets(OrthoGrid(maps.shape[-1], self.extent_m), sample.trials, bool(sample.capped),
                                   self.config.outcome)
        if self.b_encoding != "cos_beta":
            from planner.model import encode_balance

            maps = maps.copy()
            maps[4] = np.where(maps[3] > 0, encode_balance(maps[4], self.b_encoding), 0.0)
        inten, depth, mask, maps = augment(inten, depth, mask, maps, rng, self.augment_config)
        x = make_inputs(inten, depth, mask, self.config.in_channels, self.config.camera_height_m)[0]
        return x, maps

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        rng = np.random.default_rng([self.seed, self.epoch])
        order = list(range(len(self.shards)))
        if self.split == "train":
            rng.shuffle(order)
        buf = []
        for i in order:
            for s in self.loader(self.shards[i]):
                if not self._keep(s):
                    continue
                if self.split == "val":
                    yield self._convert(s, rng)
                    continue
                buf.append(s)
                if len(buf) >= self.config.shuffle_buffer:
                    yield self._convert(buf.pop(int(rng.integers(len(buf)))), rng)
        while buf:
            yield self._convert(buf.pop(int(rng.integers(len(buf)))), rng)


def as_torch_dataset(stream: ShardStream):
    """Wrap a :class:`ShardStream` as a ``torch.utils.data.IterableDataset`` yielding tensors
    (for a ``DataLoader``; use ``num_workers=0`` or give each worker its own shards)."""
    import torch
    from torch.utils.data import IterableDataset

    class _ShardDataset(IterableDataset):
        def __init__(self, s: ShardStream) -> None:
            self.stream = s

        def set_epoch(self, epoch: int) -> None:
            self.stream.set_epoch(epoch)

        def __iter__(self):
            for x, y in self.stream:
                yield torch.from_numpy(x), torch.from_numpy(y)

    return _ShardDataset(stream)


def batches(stream, batch_size: int, limit: int | None = None):
    """Group a :class:`ShardStream` into torch (x, y) batches (the last one may be smaller)."""
    import torch

    xs, ys, n = [], [], 0
    for x, y in stream:
        xs.append(x)
        ys.append(y)
        if len(xs) == batch_size:
            yield torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys))
            n += 1
            xs, ys = [], []
            if limit is not None and n >= limit:
                return
    if xs:
        yield torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys))
