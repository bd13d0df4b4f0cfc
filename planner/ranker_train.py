"""Training the grasp ranker (:mod:`planner.ranker`) on every stored trial.

Each trial a grasp store holds (Algorithm 1's, successes and failures alike, and the on-policy
rounds' choices of the network) is one example: the crop around the tried grasp in each render of
its pile, labelled by the trial's success value (:func:`synth.data.outcomes.trial_success`: the
robust repeats' success fraction, else the outcome). Piles are split into training and validation
by :func:`planner.data.is_validation_pile`; validation reports the loss, the Brier score and the
**within-pile AUC** (over the validation piles with a success (label >= 0.5) and a failure, the share
of their (success, failure) pairs the ranker orders right, ties half) — the figure issue 36 asks of U.

Augmentation keeps a grasp's meaning: the crop mirrored across the closing axis (the mirror pile's
same grasp) and turned by 180 degrees (phi + pi is the same grasp).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from planner.errors import DataError, TrainingError
from planner.ranker import RankerConfig, build_ranker, grasp_crops, grasp_scalars, load_ranker, save_ranker
from synth.geometry.frames import OrthoGrid
from synth.geometry.grasp import Grasp


@dataclass(frozen=True)
class RankerTrainConfig:
    epochs: int = 12  # passes over the training examples [-]
    batch_size: int = 128  # examples per step [-]
    lr: float = 1e-3  # AdamW learning rate, cosine-decayed to 5 % over the run [-]
    weight_decay: float = 1e-4  # AdamW weight decay [-]
    renders: int = 3  # renders of each pile used (the intensity differs, the geometry not) [-]
    val_fraction: float = 0.2  # share of piles held out for validation [-]
    split_seed: int = 0  # seed of the by-pile split (planner.data.is_validation_pile) [-]
    seed: int = 0  # initialisation and batch order [-]
    num_threads: int = 1  # torch CPU threads [-]
    repeats: bool = True  # also every repeat of a robust label (the grasp as executed, moved by the positioning
    # error) as an example of its own, labelled by its outcome: 4 more real trials per accepted grasp [-]
    balance_data: bool = True  # each --data set gives an equal share of every epoch's examples (drawn with
    # replacement): an on-policy round, a few hundred of the network's own choices, is not drowned by a
    # store's tens of thousands of Algorithm 1 trials, whose grasps the planner never proposes [-]
    pairwise_weight: float = 0.0  # weight of the within-pile pairwise term (RankNet) beside the BCE: a batch holds
    # whole piles, and each pair of one pile's examples whose success values differ adds the softplus of its
    # score difference taken the wrong way, weighted by the label difference. BCE alone rewards telling piles
    # and subsets apart (a 6-target rock-pile grasp fails more often than a single log); what the planner needs
    # is the order within one pile, the within-pile AUC. 0: BCE alone, batches across piles [-]
    pile_chunk: int = 16  # with the pairwise term, a batch is made of runs of this many examples of one pile
    # (batch_size / pile_chunk piles a batch): batches of whole piles (a store pile has ~200 examples, so one
    # pile a batch) swung the BCE's bias from pile to pile and the validation AUC fell to 0.52 after an epoch;
    # 16 gives 120 pairs a run [-]

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1 or self.renders < 1 or self.num_threads < 1:
            raise ValueError("epochs, batch_size, renders and num_threads must be >= 1")
        if not (self.lr > 0 and self.weight_decay >= 0):
            raise ValueError(f"lr must be > 0 and weight_decay >= 0, got {self.lr}, {self.weight_decay}")
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in (0, 1), got {self.val_fraction}")
        if self.pile_chunk < 2:
            raise ValueError(f"pile_chunk must be >= 2 (a pair), got {self.pile_chunk}")
        if not (math.isfinite(self.pairwise_weight) and self.pairwise_weight >= 0):
            raise ValueError(f"pairwise_weight must be a finite number >= 0, got {self.pairwise_weight}")


@dataclass
class Examples:
    crops: np.ndarray  # (N, C, S, S) float16 (C: RankerConfig.crop_channels)
    scalars: np.ndarray  # (N, 2) float32
    labels: np.ndarray  # (N,) float32 success value in [0, 1]
    piles: np.ndarray  # (N,) str pile id
    render: np.ndarray  # (N,) int
    val: np.ndarray  # (N,) bool
    repeat: np.ndarray | None = None  # (N,) bool: a robust label's repeat (validation leaves them out)


def load_examples(data: list[str | Path], ranker: RankerConfig, cfg: RankerTrainConfig,
                  progress: Callable[[int, int], None] | None = None) -> Examples:
    """Every stored trial of the data sets (grasp stores or materialised folders) as ranker examples."""
    from planner.data import is_validation_pile, list_shards, load_samples, normalise_depth, sample_arrays

    listed = [list_shards(str(d)) for d in data]
    sources = [(k, shard) for k, (shards, _) in enumerate(listed) for shard in shards]
    moved = {k: stored_repeats(d) for k, d in enumerate(data)} if cfg.repeats else {}
    grid_d = listed[0][1]
    for d, (_, g) in zip(data[1:], listed[1:]):
        if g != grid_d:
            raise DataError(f"data set {d} has image grid {g} but {data[0]} has {grid_d}; data sets trained "
                            "together must share size_px, extent_m and camera height")
    grid = OrthoGrid(int(grid_d["size_px"]), float(grid_d["extent_m"]))
    cam_h = float(grid_d.get("camera_height_m", 5.0))
    if abs(grid.pixel_m / ranker.pixel_m - 1.0) > 0.005:
        raise DataError(f"the data's pixels are {100 * grid.pixel_m:.2f} cm, the ranker's {100 * ranker.pixel_m:.2f} cm")

    def examples_of(k: int, shard):  # each usable sample of a shard with its grasps and labels
        for s in load_samples(shard):
            if s.trials is None:
                raise DataError(f"{shard} keeps no trials (materialised before outcome labels); materialise the "
                                "store again with this version")
            if s.render >= cfg.renders or not len(s.trials):
                continue
            if ranker.needs_instance and s.instance is None:
                raise DataError(f"{shard} keeps no instance maps (materialised before them), which the crop channels "
                                f"{', '.join(ranker.crop_channels)} need; materialise the store again with this version "
                                "(delete its .cache) or train with --crop-channels I,H,M_T,claws")
            reps = moved.get(k, {}).get((str(s.pile_id), tuple(s.subset)), [])
            grasps = [Grasp(float(t[0]), float(t[1]), float(t[2]), float(t[3])) for t in s.trials]
            yield s, grasps + [Grasp(*map(float, r[:4])) for r in reps], reps

    # counted first, so the crops (the bulk: 2 bytes x channels x crop_px^2 an example) are made in place
    total = sum(len(g) for k, shard in sources for _, g, _ in examples_of(k, shard))
    if not total:
        raise DataError(f"no stored trials in {', '.join(map(str, data))}; give grasp stores with trials")
    crops = np.empty((total, len(ranker.crop_channels), ranker.crop_px, ranker.crop_px), np.float16)
    parts: dict[str, list] = {k: [] for k in ("scalars", "labels", "piles", "render", "repeat")}
    n = 0
    for i, (k, shard) in enumerate(sources):
        for s, grasps, reps in examples_of(k, shard):
            inten, depth, mask, _ = sample_arrays(s)
            crops[n:n + len(grasps)] = grasp_crops(inten, normalise_depth(depth, cam_h), mask, grid, grasps, ranker,
                                                   s.instance)
            n += len(grasps)
            parts["scalars"].append(grasp_scalars(grasps, [len(s.subset)] * len(grasps)))
            parts["labels"].append(np.concatenate([np.asarray(s.trials[:, 4], dtype=np.float32),
                                                   np.array([r[4] == "success" for r in reps], np.float32)]))
            parts["piles"] += [f"{k}/{s.pile_id}"] * len(grasps)  # the data set's index: pile ids repeat across sets
            parts["render"] += [s.render] * len(grasps)
            parts["repeat"] += [False] * len(s.trials) + [True] * len(reps)
        if progress:
            progress(i + 1, len(sources))
    piles = np.asarray(parts["piles"])
    val = np.array([is_validation_pile(p.split("/", 1)[1], cfg.split_seed, cfg.val_fraction) for p in piles])
    return Examples(crops, np.concatenate(parts["scalars"]), np.concatenate(parts["labels"]), piles,
                    np.asarray(parts["render"]), val, np.asarray(parts["repeat"], dtype=bool))


def stored_repeats(data_dir: str | Path) -> dict[tuple[str, tuple[int, ...]], list[list]]:
    """A grasp store's repeats by (pile id, subset): ``[x, y, phi, width, outcome]`` rows (none for a
    materialised folder, which keeps only each trial's success fraction)."""
    from synth.data.datastore import chunk_path, is_store, open_store, read_chunk

    if not is_store(data_dir):
        return {}
    _, chunks, store = open_store(data_dir)
    out: dict[tuple[str, tuple[int, ...]], list[list]] = {}
    for c in sorted(chunks):
        for p in read_chunk(chunk_path(data_dir, c), store["params_sha256"])["piles"]:
            for sub in p["subsets"]:
                rows = [r for t in sub["trials"] for r in t.get("r", ())]
                if rows:
                    out[(str(p["pile_id"]), tuple(sub["targets"]))] = rows
    return out


def within_pile_auc(scores: np.ndarray, labels: np.ndarray, piles: np.ndarray) -> tuple[float, int, int]:
    """Pooled within-pile AUC (successes: label >= 0.5), its pairs and mixed piles; NaN without pairs."""
    good, pairs, mixed = 0.0, 0, 0
    for p in np.unique(piles):
        sel = piles == p
        s, f = scores[sel & (labels >= 0.5)], scores[sel & (labels < 0.5)]
        if len(s) and len(f):
            d = s[:, None] - f[None, :]
            good += float((d > 0).sum() + 0.5 * (d == 0).sum())
            pairs += d.size
            mixed += 1
    return (good / pairs if pairs else float("nan")), pairs, mixed


def _augment(x, rng: np.random.Generator):
    if rng.random() < 0.5:
        x = x.flip(2)  # mirrored across the closing axis
    if rng.random() < 0.5:
        x = x.flip(2).flip(3)  # phi + pi
    return x


def _epoch_order(ex: Examples, train_idx: np.ndarray, balance: bool, rng: np.random.Generator) -> np.ndarray:
    """The training examples of one epoch, shuffled; with ``balance`` as many drawn from each data set
    (with replacement) as the epoch has examples divided by the number of sets."""
    if not balance:
        return rng.permutation(train_idx)
    source = np.array([int(p.split("/", 1)[0]) for p in ex.piles[train_idx]])
    sets = np.unique(source)
    share = len(train_idx) // len(sets)
    return rng.permutation(np.concatenate([rng.choice(train_idx[source == k], share) for k in sets]))


def _pile_runs(order: np.ndarray, piles: np.ndarray, run: int, rng: np.random.Generator) -> np.ndarray:
    """``order`` rearranged into runs of ``run`` examples of one pile (a pile's last run may be shorter; a run
    takes the pile's examples in their order in ``order``), the runs in a random order: batches cut from it
    hold ``batch / run`` piles' runs, whose pairs the pairwise term compares."""
    _, inverse = np.unique(piles[order], return_inverse=True)
    by_pile = np.argsort(inverse, kind="stable")  # positions in order, pile by pile
    counts = np.bincount(inverse)
    rank = np.arange(len(order)) - np.repeat(np.cumsum(counts) - counts, counts)  # place within its pile
    run_id = np.repeat(np.cumsum(-(-counts // run)) - (-(-counts // run)), counts) + rank // run
    key = rng.permutation(int(run_id.max()) + 1)[run_id]
    return order[by_pile[np.argsort(key, kind="stable")]]


def pairwise_loss(logits, labels, pile_index):
    """The within-pile pairwise (RankNet) loss of one batch: over every pair (i, j) of one pile with
    ``labels[i] > labels[j]``, the mean of ``softplus(logits[j] - logits[i])`` weighted by ``labels[i] -
    labels[j]``; 0 (with a gradient) when the batch has no such pair. Tensors (B,), ``pile_index`` integer."""
    import torch

    diff = labels[:, None] - labels[None, :]
    w = torch.where((pile_index[:, None] == pile_index[None, :]) & (diff > 0), diff, torch.zeros_like(diff))
    total = w.sum()
    if not float(total) > 0:
        return logits.sum() * 0.0
    return (w * torch.nn.functional.softplus(logits[None, :] - logits[:, None])).sum() / total


def _predict(model, ex: Examples, sel: np.ndarray, batch: int) -> np.ndarray:
    import torch

    out = []
    idx = np.flatnonzero(sel)
    with torch.inference_mode():
        for i in range(0, len(idx), 4 * batch):
            j = idx[i:i + 4 * batch]
            out.append(torch.sigmoid(model(torch.from_numpy(ex.crops[j].astype(np.float32)),
                                           torch.from_numpy(ex.scalars[j]))).numpy())
    return np.concatenate(out) if out else np.zeros(0)


def validate(model, ex: Examples, batch: int) -> dict:
    """Loss, Brier score and within-pile AUC on the validation piles' trials as tried (render 0: each
    once; repeats left out), and the AUC per data set (``auc_by_data``, keyed by its index in ``--data``)."""
    sel = ex.val & (ex.render == 0) & (~ex.repeat if ex.repeat is not None else True)
    p = _predict(model, ex, sel, batch)
    y = ex.labels[sel]
    pc = np.clip(p, 1e-6, 1 - 1e-6)
    piles = ex.piles[sel]
    auc, pairs, mixed = within_pile_auc(p, y, piles)
    source = np.array([q.split("/", 1)[0] for q in piles])
    return {"examples": int(sel.sum()), "bce": float(-np.mean(y * np.log(pc) + (1 - y) * np.log(1 - pc))),
            "brier": float(np.mean((p - y) ** 2)), "auc": auc, "auc_pairs": pairs, "auc_piles": mixed,
            "auc_by_data": {k: within_pile_auc(p[source == k], y[source == k], piles[source == k])[0]
                            for k in sorted(set(source))}}


def fit(ex: Examples, cfg: RankerTrainConfig, ranker: RankerConfig = RankerConfig(),
        say: Callable[[str], None] = lambda s: None, init_state: dict | None = None) -> tuple[object, list[dict]]:
    """A ranker trained on ``ex``'s training piles, validated each epoch: (model, history); from
    ``init_state`` (a state dict of the same ranker) when given, else from a random initialisation.
    :class:`TrainingError` when a side of the split is empty."""
    import torch

    t0 = time.perf_counter()
    torch.set_num_threads(cfg.num_threads)
    torch.manual_seed(cfg.seed)
    train_idx = np.flatnonzero(~ex.val)
    if not len(train_idx) or not ex.val.any():
        raise TrainingError(f"{len(train_idx)} training and {int(ex.val.sum())} validation examples: both sides of "
                            "the by-pile split need piles; give more data")
    model = build_ranker(ranker)
    if init_state is not None:
        model.load_state_dict(init_state, strict=True)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps = cfg.epochs * math.ceil(len(train_idx) / cfg.batch_size)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * s / steps)))
    rng = np.random.default_rng(cfg.seed)
    history = []
    for epoch in range(cfg.epochs):
        model.train()
        order = _epoch_order(ex, train_idx, cfg.balance_data, rng)
        if cfg.pairwise_weight > 0:
            order = _pile_runs(order, ex.piles, cfg.pile_chunk, rng)
        total = 0.0
        for i in range(0, len(order), cfg.batch_size):
            j = np.sort(order[i:i + cfg.batch_size])
            x = _augment(torch.from_numpy(ex.crops[j].astype(np.float32)), rng)
            logits, y = model(x, torch.from_numpy(ex.scalars[j])), torch.from_numpy(ex.labels[j])
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, y)
            if cfg.pairwise_weight > 0:
                pile_index = torch.from_numpy(np.unique(ex.piles[j], return_inverse=True)[1].reshape(-1))
                loss = loss + cfg.pairwise_weight * pairwise_loss(logits, y, pile_index)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(j)
        model.eval()
        val = validate(model, ex, cfg.batch_size)
        history.append({"epoch": epoch + 1, "train_bce": total / len(order), **{f"val_{k}": v for k, v in val.items()},
                        "elapsed_s": time.perf_counter() - t0})
        say(f"epoch {epoch + 1}/{cfg.epochs}: train BCE {history[-1]['train_bce']:.4f}, val BCE {val['bce']:.4f}, "
            f"within-pile AUC {val['auc']:.3f} ({val['auc_piles']} piles)")
    return model, history


def train_ranker(data: list[str | Path], out: str | Path, cfg: RankerTrainConfig = RankerTrainConfig(),
                 ranker: RankerConfig | None = None, progress: Callable[[str], None] | None = None,
                 init: str | Path | None = None) -> dict:
    """Train a ranker on the data sets' trials; writes ``out`` (the checkpoint) and ``out`` + ``.json``
    (the run's log); returns the log. ``init``: a ranker checkpoint to fine-tune (an on-policy round's
    update of the last ranker) instead of starting from random weights; its crop is kept, and a
    ``ranker`` configuration that differs from it is a :class:`TrainingError`. ``ranker`` None: the
    default configuration (or the checkpoint's)."""
    from synth.common.files import atomic_write_bytes, sha256_file

    say = progress or (lambda s: None)
    start, ranker = _start_from(init, ranker)
    t0 = time.perf_counter()
    ex = load_examples(data, ranker, cfg, lambda i, n: say(f"crops: shard {i}/{n}") if i % 25 == 0 or i == n else None)
    say(f"{int((~ex.val).sum())} training examples, {int(ex.val.sum())} validation ({len(np.unique(ex.piles))} "
        f"piles), {time.perf_counter() - t0:.0f} s")
    model, history = fit(ex, cfg, ranker, say, None if start is None else start.model.state_dict())
    log = {"data": [str(d) for d in data], "train_config": asdict(cfg), "ranker_config": ranker.to_dict(),
           "init": None if init is None else {"path": str(init), "sha256": sha256_file(init)},
           "examples": {"train": int((~ex.val).sum()), "val": int(ex.val.sum()),
                        "train_positive_mean": float(ex.labels[~ex.val].mean())},
           "history": history, "final": history[-1]}
    save_ranker(out, model, ranker, {k: log[k] for k in ("data", "train_config", "init", "examples", "final")})
    atomic_write_bytes(Path(str(out) + ".json"), json.dumps(log, indent=1).encode())
    return log


def _start_from(init: str | Path | None, ranker: RankerConfig | None):
    """(the checkpoint to fine-tune or None, the ranker configuration to train)."""
    if init is None:
        return None, ranker or RankerConfig()
    start = load_ranker(init)
    if ranker is not None and ranker != start.config:
        diff = {k: (v, getattr(ranker, k)) for k, v in start.config.to_dict().items() if getattr(ranker, k) != v}
        raise TrainingError(f"{init}: the checkpoint to fine-tune has another crop or network than asked for "
                            f"({', '.join(f'{k} {a} there, {b} asked' for k, (a, b) in diff.items())}); "
                            "leave those options out to keep the checkpoint's")
    return start, start.config
