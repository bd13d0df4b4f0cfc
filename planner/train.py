"""Train the grasp-map network on a :mod:`synth.data.dataset` data set.

``train(data_dir, out_dir, config)`` writes into ``out_dir``::

    train_config.json        the run's TrainConfig (a different config in the same folder is refused)
    state.safetensors        weights + Adam state + position (epoch, step) — resume point
    model.safetensors        best-validation-loss checkpoint (planner.checkpoint format)
    log.json                 per-epoch losses, throughput (format-versioned)
    curve.png                training / validation loss curves

Every file is written atomically, the state every ``checkpoint_every_steps`` steps and at each
epoch's end, so killing the process at any moment loses at most that many steps; calling
``train`` again with the same folder and config resumes (the data order is a function of
(seed, epoch), so skipped batches are replayed exactly). Only ``epochs`` may differ on resume
(to extend a finished run); any other change is refused.

Speed on the CPU: channels-last memory + bfloat16 autocast (``precision="bf16"``) is about twice
plain fp32 here (see ``bench/bench_planner.py``); on CUDA bf16 autocast is used as well.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, Literal

from planner.augment import AugmentConfig
from planner.data import DataConfig, ShardStream, batches, list_shards
from planner.errors import CheckpointError, DataError, TrainingError
from planner.loss import LossWeights, grasp_loss
from planner.model import UNetConfig
from synth.common.formats import VersionedJson

TRAIN_FORMAT_NAME = "loggrasp.planner.train_state"
#: what a resumed run may change: more epochs extend it; where it runs (device, CPU threads) is not
#: what it learns (a run started on these CPUs can go on on a GPU machine, or with the cores shared)
RESUMABLE_CHANGES = frozenset({"epochs", "device", "num_threads"})
LOG_FORMAT_NAME = "loggrasp.planner.train_log"
LOG_FORMAT_VERSION = "1.0"
TRAIN_LOG = VersionedJson(LOG_FORMAT_NAME, LOG_FORMAT_VERSION, "training log", TrainingError)


@dataclass(frozen=True)
class TrainConfig:
    model: UNetConfig = field(default_factory=UNetConfig)
    epochs: int = 50  # passes over the training split [-]
    batch_size: int = 16  # samples per step [-]
    lr: float = 1e-3  # Adam learning rate [-]
    lr_schedule: Literal["cosine", "constant"] = "cosine"  # "cosine" (per epoch, down to lr_min_frac * lr at the end) or "constant"
    lr_min_frac: float = 0.05  # cosine floor as a fraction of lr [-]
    weight_decay: float = 0.0  # Adam weight decay [-]
    seed: int = 0  # initialisation, data order and augmentation [-]
    device: Literal["auto", "cpu", "cuda"] = "auto"  # "auto" (cuda if available), "cpu" or "cuda"
    precision: Literal["bf16", "fp32"] = "bf16"  # "bf16" (autocast, channels-last on CPU) or "fp32"
    num_threads: int | None = None  # torch CPU threads; None = torch default
    loss: LossWeights = field(default_factory=LossWeights)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    data: DataConfig = field(default_factory=DataConfig)
    max_steps_per_epoch: int | None = None  # cap (tests, quick runs) [-]
    max_val_batches: int | None = None  # cap on validation batches per epoch [-]
    checkpoint_every_steps: int = 200  # resume-state interval [steps]
    init_from: str | None = None  # checkpoint whose weights start a fresh run (fine-tuning, e.g. after an
    # on-policy round); its network configuration must equal ``model``. None = random initialisation

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1:
            raise ValueError("epochs and batch_size must be >= 1")
        if not self.lr > 0 or self.weight_decay < 0:
            raise ValueError("lr must be > 0 and weight_decay >= 0")
        if self.lr_schedule not in ("cosine", "constant"):
            raise ValueError(f"lr_schedule must be 'cosine' or 'constant', got {self.lr_schedule!r}")
        if not 0.0 <= self.lr_min_frac <= 1.0:
            raise ValueError(f"lr_min_frac must be in [0, 1], got {self.lr_min_frac}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ValueError(f"device must be 'auto', 'cpu' or 'cuda', got {self.device!r}")
        if self.precision not in ("bf16", "fp32"):
            raise ValueError(f"precision must be 'bf16' or 'fp32', got {self.precision!r}")
        if self.checkpoint_every_steps < 1:
            raise ValueError("checkpoint_every_steps must be >= 1")
        if self.data.in_channels != self.model.in_channels:  # the model decides (2 = no-depth ablation)
            object.__setattr__(self, "data", replace(self.data, in_channels=self.model.in_channels))

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "TrainConfig":
        from synth.common.configs import config_from_dict

        return config_from_dict(TrainConfig, d)


@dataclass
class TrainResult:
    model_path: Path  # best-validation checkpoint
    state_path: Path
    log_path: Path
    curve_path: Path
    history: list[dict]
    resumed_from: dict | None


def _data_label(data_dir) -> str:
    dirs = data_dir if isinstance(data_dir, (list, tuple)) else [data_dir]
    return ",".join(str(d) for d in dirs)


def epoch_lr(cfg: TrainConfig, epoch: int) -> float:
    """The learning rate of ``epoch`` (a function of the epoch only, so a resumed run matches)."""
    if cfg.lr_schedule == "constant" or cfg.epochs <= 1:
        return cfg.lr
    lo = cfg.lr * cfg.lr_min_frac
    return lo + 0.5 * (cfg.lr - lo) * (1.0 + math.cos(math.pi * epoch / (cfg.epochs - 1)))


def _device(cfg: TrainConfig) -> str:
    import torch

    if cfg.device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise TrainingError("device 'cuda' was asked for but torch sees no CUDA device; use device='cpu'")
    return cfg.device


def _save_state(path: Path, model, opt, position: dict, cfg: TrainConfig) -> None:
    from planner.checkpoint import CHECKPOINT_FORMAT_VERSION, save_tensors

    tensors = {f"model.{k}": v for k, v in model.state_dict().items()}
    osd = opt.state_dict()
    for idx, st in osd["state"].items():
        for k, v in st.items():
            tensors[f"optim.{idx}.{k}"] = v if hasattr(v, "detach") else __import__("torch").tensor(v)
    header = {"format": TRAIN_FORMAT_NAME, "format_version": CHECKPOINT_FORMAT_VERSION, "position": position,
              "param_groups": osd["param_groups"], "config": cfg.to_dict()}
    save_tensors(path, tensors, header)


def _load_state(path: Path, model, opt) -> dict:
    from planner.checkpoint import load_tensors

    tensors, header = load_tensors(path, TRAIN_FORMAT_NAME)
    msd = {k[6:]: v for k, v in tensors.items() if k.startswith("model.")}
    state: dict = {}
    for k, v in tensors.items():
        if k.startswith("optim."):
            _, idx, key = k.split(".", 2)
            state.setdefault(int(idx), {})[key] = v
    try:
        model.load_state_dict(msd, strict=True)
        opt.load_state_dict({"state": state, "param_groups": header["param_groups"]})
    except (RuntimeError, ValueError, KeyError) as exc:
        raise CheckpointError(f"{path} does not fit this model/optimiser ({exc}); delete the folder to start afresh") from exc
    return header["position"]


def _write_log(path: Path, history: list[dict], cfg: TrainConfig, extra: dict) -> None:
    TRAIN_LOG.write(path, {"config": cfg.to_dict(), **extra, "epochs": history})


def read_log(path: str | Path) -> dict:
    """Read ``log.json`` written by :func:`train`."""
    return TRAIN_LOG.read(path)


def plot_curve(history: list[dict], path: Path) -> None:
    """Training / validation loss per epoch as a PNG (matplotlib, Agg backend)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from synth.common.files import atomic_write_bytes

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    ep = [h["epoch"] + 1 for h in history]
    ax.plot(ep, [h["train_loss"] for h in history], "o-", label="train")
    val = [(h["epoch"] + 1, h["val_loss"]) for h in history if h.get("val_loss") is not None]
    if val:
        ax.plot(*zip(*val), "s-", label="validation")
    ax.set_xlabel("epoch")
    ax.set_ylabel("loss (BCE + weighted MMSE)")
    ax.set_yscale("log")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def _step_context(device: str, precision: str):
    import contextlib

    import torch

    if precision == "bf16":
        return torch.autocast(device_type=device, dtype=torch.bfloat16)
    return contextlib.nullcontext()


def _prepare_batch(x, y, device: str, precision: str):
    import torch

    x, y = x.to(device), y.to(device)
    if precision == "bf16" and device == "cpu":
        x = x.contiguous(memory_format=torch.channels_last)
    return x, y


def evaluate(model, stream, cfg: TrainConfig, device: str) -> dict | None:
    """Mean validation loss and parts over the stream (None when the split is empty)."""
    import torch

    model.eval()
    tot, parts_sum, n = 0.0, {}, 0
    with torch.inference_mode():
        for x, y in batches(stream, cfg.batch_size, cfg.max_val_batches):
            x, y = _prepare_batch(x, y, device, cfg.precision)
            with _step_context(device, cfg.precision):
                pred = model(x)
            loss, parts = grasp_loss(pred, y, cfg.loss, cfg.model.b_encoding)
            b = len(x)
            tot += float(loss) * b
            for k, v in parts.items():
                parts_sum[k] = parts_sum.get(k, 0.0) + v * b
            n += b
    model.train()
    if n == 0:
        return None
    return {"loss": tot / n, **{k: v / n for k, v in parts_sum.items()}, "samples": n}


def train(data_dir: str | Path | list, out_dir: str | Path, config: TrainConfig = TrainConfig(),
          progress: Callable[[dict], None] | None = None) -> TrainResult:
    """Train (or resume training) and return where the results are.

    ``progress``, if given, is called after every step with ``{"epoch", "step", "loss",
    "samples_per_s"}`` and after every epoch with the epoch's log entry (``"kind": "epoch"``).
    ``data_dir`` may be one data set folder or a list of them (same image grid), e.g. a first set
    and a later extension; their shards are used together.
    Raises :class:`DataError` for an unusable data set and :class:`TrainingError` when
    ``out_dir`` holds a run with a different configuration."""
    import torch

    from planner.model import count_parameters

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    shards, grid = list_shards(data_dir)
    config = _config_for_grid(config, grid)
    _check_run_config(out, config)
    if config.num_threads:
        torch.set_num_threads(config.num_threads)
    device = _device(config)
    run = _Run.start(out, config, device)
    stream_kw = {"extent_m": config.model.extent_m, "b_encoding": config.model.b_encoding}
    train_stream = ShardStream(shards, "train", config.data, config.augment, config.seed, **stream_kw)
    val_stream = ShardStream(shards, "val", config.data, config.augment, config.seed, **stream_kw)
    n_params = count_parameters(run.model)
    meta_common = {"n_parameters": n_params, "data_dir": _data_label(data_dir), "train_config": config.to_dict()}

    run.model.train()
    for epoch in range(run.position["epoch"], config.epochs):
        skip = run.position["step"] if epoch == run.position["epoch"] else 0
        stats = _train_epoch(run, train_stream, epoch, skip, config, device, progress)
        if stats.n_samples == 0 and skip == 0:
            raise DataError(f"the training split of {_data_label(data_dir)} is empty (all piles fell into validation?); "
                            "add piles or lower data.val_fraction")
        val = evaluate(run.model, val_stream, config, device)
        entry = _epoch_entry(epoch, config, stats, val, skip)
        run.end_epoch(entry, config, meta_common, {"n_parameters": n_params, "device": device})
        if progress:
            progress({"kind": "epoch", **entry})
    if not run.model_path.exists():  # resumed after the last epoch had finished
        raise TrainingError(f"{out} has a finished state but no model.safetensors; delete the folder and retrain")
    return TrainResult(run.model_path, run.state_path, run.log_path, run.curve_path, run.history, run.resumed)


def _config_for_grid(config: TrainConfig, grid: dict) -> TrainConfig:
    """``config`` with the data set's pitch and camera height; a size that differs is a DataError."""
    size = int(grid.get("size_px", config.model.size_px))
    if size != config.model.size_px:
        raise DataError(f"the data set's images are {size} px but the model is configured for "
                        f"{config.model.size_px} px; set model.size_px={size}")
    extent = float(grid.get("extent_m", config.model.extent_m))
    if abs(extent - config.model.extent_m) > 1e-9:  # the pitch the network learns is the data set's
        config = replace(config, model=replace(config.model, extent_m=extent))
    cam_h = float(grid.get("camera_height_m", config.data.camera_height_m))
    if abs(cam_h - config.data.camera_height_m) > 1e-9:
        config = replace(config, data=replace(config.data, camera_height_m=cam_h))
    return config


def _check_run_config(out: Path, config: TrainConfig) -> None:
    """Write ``train_config.json``, or check that a run there has the same configuration (only
    ``RESUMABLE_CHANGES`` may change: more epochs, another device or thread count)."""
    from synth.common.files import atomic_write_bytes

    cfg_path = out / "train_config.json"
    if cfg_path.exists():
        try:
            old = json.loads(cfg_path.read_text())
            old.setdefault("lr_schedule", "constant")  # runs from before the schedule existed
            old.setdefault("lr_min_frac", TrainConfig.lr_min_frac)
            old = json.loads(json.dumps(TrainConfig.from_dict(old).to_dict()))  # fields added since: their defaults
        except (OSError, ValueError) as exc:
            raise TrainingError(f"{cfg_path} is unreadable ({exc}); delete {out} to start afresh") from exc
        now = json.loads(json.dumps(config.to_dict()))
        differ = sorted(k for k in set(old) | set(now) if k not in RESUMABLE_CHANGES and old.get(k) != now.get(k))
        if differ:
            raise TrainingError(f"{out} holds a training run with a different configuration ({', '.join(differ)}); "
                                "use another output folder or the same configuration to resume "
                                f"(only {', '.join(sorted(RESUMABLE_CHANGES))} may change)")
        if old == now:
            return
    atomic_write_bytes(cfg_path, json.dumps(config.to_dict(), indent=1).encode())


@dataclass
class _Run:
    """A training run's model, optimiser, files and history, started afresh or resumed."""

    model: object
    opt: object
    out: Path
    history: list[dict]
    best: float  # best validation (or training) loss so far
    position: dict  # {"epoch", "step"} to continue from
    resumed: dict | None  # where it resumed, None for a fresh run

    @property
    def state_path(self) -> Path:
        return self.out / "state.safetensors"

    @property
    def model_path(self) -> Path:
        return self.out / "model.safetensors"

    @property
    def log_path(self) -> Path:
        return self.out / "log.json"

    @property
    def curve_path(self) -> Path:
        return self.out / "curve.png"

    @staticmethod
    def start(out: Path, config: TrainConfig, device: str) -> "_Run":
        import torch

        from planner.model import build_unet

        torch.manual_seed(config.seed)
        model = build_unet(config.model).to(device)
        if config.precision == "bf16" and device == "cpu":
            model = model.to(memory_format=torch.channels_last)
        opt = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        run = _Run(model, opt, out, [], math.inf, {"epoch": 0, "step": 0}, None)
        if config.init_from and not run.state_path.exists():
            _init_weights(model, config)
        if run.state_path.exists():
            run.position = _load_state(run.state_path, model, opt)
            run.resumed = dict(run.position)
            if run.log_path.exists():
                run.history = [h for h in read_log(run.log_path)["epochs"] if h["epoch"] < run.position["epoch"]]
            vals = [h["val_loss"] for h in run.history if h.get("val_loss") is not None]
            run.best = min(vals) if vals else math.inf
        return run

    def end_epoch(self, entry: dict, config: TrainConfig, meta_common: dict, log_meta: dict) -> None:
        """Keep the checkpoint if it is the best so far, then log, curve and resume state."""
        from planner.checkpoint import save_checkpoint

        self.history.append(entry)
        score = entry["val_loss"] if entry["val_loss"] is not None else entry["train_loss"]
        if score < self.best or not self.model_path.exists():
            self.best = min(self.best, score)
            save_checkpoint(self.model_path, self.model, config.model,
                            {**meta_common, "epoch": entry["epoch"], "val_loss": entry["val_loss"],
                             "train_loss": entry["train_loss"]})
        # log before state: a kill in between replays the epoch and drops its log entry
        _write_log(self.log_path, self.history, config, log_meta)
        plot_curve(self.history, self.curve_path)
        _save_state(self.state_path, self.model, self.opt, {"epoch": entry["epoch"] + 1, "step": 0}, config)


# network fields that change only what an output means, not a weight's shape: a checkpoint with another
# value is a valid start (its B head is re-learnt for the new target, e.g. cos_beta -> beta_10deg)
RETARGETABLE = frozenset({"b_encoding"})


def _init_weights(model, config: TrainConfig) -> None:
    """Start ``model`` from the weights of ``config.init_from``; a checkpoint of another network
    configuration (beyond :data:`RETARGETABLE` fields) is a :class:`CheckpointError` naming the fields
    that differ."""
    from planner.checkpoint import load_checkpoint

    loaded, have, _ = load_checkpoint(config.init_from)
    diff = [k for k, v in have.to_dict().items() if v != config.model.to_dict()[k] and k not in RETARGETABLE]
    if diff:
        raise CheckpointError(f"{config.init_from} does not fit this run: its network differs in {', '.join(diff)}; "
                              "fine-tune with the same network settings (e.g. --base-channels, --mask-injection) "
                              "or drop --init-from")
    model.load_state_dict({k: v.to(next(model.parameters()).device) for k, v in loaded.state_dict().items()})


@dataclass
class _EpochStats:
    n_samples: int = 0
    loss_sum: float = 0.0  # sum of sample-weighted losses
    parts_sum: dict = field(default_factory=dict)  # the same per loss term
    wall_s: float = 0.0  # the epoch's training wall time [s]
    compute_s: float = 0.0  # of which forward, backward and step [s]


def _train_epoch(run: _Run, stream, epoch: int, skip: int, config: TrainConfig, device: str,
                 progress: Callable[[dict], None] | None) -> _EpochStats:
    """One pass over the training split, the first ``skip`` steps (done before a resume) skipped."""
    import torch

    stream.set_epoch(epoch)
    for group in run.opt.param_groups:
        group["lr"] = epoch_lr(config, epoch)
    st, t_epoch = _EpochStats(), time.perf_counter()
    for step, (x, y) in enumerate(batches(stream, config.batch_size, config.max_steps_per_epoch), start=1):
        if step <= skip:
            continue
        t0 = time.perf_counter()
        x, y = _prepare_batch(x, y, device, config.precision)
        with _step_context(device, config.precision):
            pred = run.model(x)
        loss, parts = grasp_loss(pred, y, config.loss, config.model.b_encoding)
        if not torch.isfinite(loss):
            raise TrainingError(f"loss became {float(loss)} at epoch {epoch} step {step}; lower the learning rate")
        run.opt.zero_grad(set_to_none=True)
        loss.backward()
        run.opt.step()
        st.compute_s += time.perf_counter() - t0
        b = len(x)
        st.n_samples += b
        st.loss_sum += float(loss.detach()) * b
        for k, v in parts.items():
            st.parts_sum[k] = st.parts_sum.get(k, 0.0) + v * b
        if progress:
            progress({"kind": "step", "epoch": epoch, "step": step, "loss": float(loss.detach()),
                      "samples_per_s": st.n_samples / max(time.perf_counter() - t_epoch, 1e-9)})
        if step % config.checkpoint_every_steps == 0:
            _save_state(run.state_path, run.model, run.opt, {"epoch": epoch, "step": step}, config)
    st.wall_s = time.perf_counter() - t_epoch
    return st


def _epoch_entry(epoch: int, config: TrainConfig, st: _EpochStats, val: dict | None, skip: int) -> dict:
    """The epoch's line in log.json."""
    n = max(st.n_samples, 1)
    return {"epoch": epoch, "lr": epoch_lr(config, epoch), "train_loss": st.loss_sum / n,
            "train_parts": {k: v / n for k, v in st.parts_sum.items()},
            "train_samples": st.n_samples, "wall_s": st.wall_s,
            "samples_per_s": st.n_samples / st.wall_s if st.wall_s > 0 else None,
            "compute_samples_per_s": st.n_samples / st.compute_s if st.compute_s > 0 else None,
            "val_loss": None if val is None else val["loss"],
            "val_parts": None if val is None else {k: v for k, v in val.items() if k not in ("loss", "samples")},
            "val_samples": 0 if val is None else val["samples"], "resumed_at_step": skip or None}
