"""``loggrasp round`` and ``loggrasp train-ranker``: learning from the twin's outcomes.

``round`` runs an on-policy round (:mod:`planner.onpolicy`): a checkpoint plans fresh training
piles, its best grasps are tried in the twin under the field's positioning error, and the outcomes
are stored as a grasp store that ``train --labels outcome`` and ``train-ranker`` read.
``train-ranker`` trains the grasp-centred ranker (:mod:`planner.ranker`) on every stored trial.
"""

from __future__ import annotations

from pathlib import Path

from planner.onpolicy import RoundConfig
from planner.ranker import CROP_CHANNELS, RankerConfig
from planner.ranker_train import RankerTrainConfig
from synth.cli import JSON, WORKERS
from synth.common.cli import CliError, Output, check_input, check_output_dir, check_output_file, option, progress_bar

MODEL = option("--model", "Checkpoint (.safetensors) that plans; default: the shipped model.", default=None,
               metavar="PATH")


def round_command(
    out: Path = option("--out", "The round's store folder (resumable: the same command continues it).",
                       default=..., metavar="DIR"),
    round_index: int = option("--round", "The round's index: its piles' seeds (960,000,000 + round x 100,000 + k).",
                              default=..., min=0, metavar="INT", names=["round"]),
    piles: int = option("--piles", "Piles planned and tried.", default=..., min=1, metavar="INT"),
    model: Path = MODEL,
    top_k: int = option("--top-k", "Subsets tried per pile and objective (the best by f1 and by f3; their union).",
                        field=(RoundConfig, "top_k"), min=1),
    repeats: int = option("--repeats", "Executions of each tried grasp, each moved by the positioning error.",
                          field=(RoundConfig, "repeats"), min=1),
    error: str = option("--error", "The crane's positioning error SIGMA_XY_M,SIGMA_PHI_DEG.", default="0.03,2",
                        metavar="M,DEG"),
    logs: str = option("--logs", "Pile sizes cycle over A-B logs.", default="2-7", metavar="A-B"),
    workers: int = WORKERS,
    as_json: bool = JSON,
) -> None:
    """Plan fresh training piles with a checkpoint and try its best grasps in the twin (an on-policy round).

    \b
    Example: loggrasp round --round 0 --piles 200 --out rounds/r0 --workers 2
    """
    from planner.checkpoint import DEFAULT_MODEL
    from planner.onpolicy import run_round
    from synth.physics.perturb import PositioningError

    o = Output(as_json)
    model = model or DEFAULT_MODEL
    check_input(model, "--model", "file")
    check_output_dir(out, "--out")
    try:
        err = PositioningError.parse(error)
    except ValueError as exc:
        raise CliError(f"--error: {exc}") from exc
    try:
        lo, hi = (int(v) for v in logs.split("-"))
    except ValueError as exc:
        raise CliError(f"--logs must be A-B (e.g. 2-7), got {logs!r}") from exc
    cfg = RoundConfig(round=round_index, piles=piles, top_k=top_k, repeats=repeats, error=err, min_logs=lo,
                      max_logs=hi)
    with progress_bar() as bar:
        task = bar.add_task(f"round {round_index}", total=piles, info="")
        store = run_round(cfg, model, out, lambda n, total: bar.update(task, completed=n), workers=workers)
    s = store["summary"]
    o.say(f"round {round_index}: {s['chunks_done']}/{s['chunks_total']} piles, {s['subsets']} grasps tried, "
          f"{s['trials']} stored trials in {out}")
    o.result("loggrasp.round", {"out": str(out), **s})


def train_ranker_command(
    data: list[Path] = option("--data", "Grasp store or data set with trials (a data store, a round); repeat to "
                              "train on several.", default=..., metavar="DIR"),
    out: Path = option("--out", "The ranker checkpoint to write (.safetensors; its log beside it, + .json).",
                       default=..., metavar="FILE"),
    epochs: int = option("--epochs", "Passes over the training examples.", field=(RankerTrainConfig, "epochs"), min=1),
    batch_size: int = option("--batch-size", "Examples per step.", field=(RankerTrainConfig, "batch_size"), min=1),
    lr: float = option("--lr", "AdamW learning rate (cosine-decayed).", field=(RankerTrainConfig, "lr"), min=0.0),
    renders: int = option("--renders", "Renders of each pile used.", field=(RankerTrainConfig, "renders"), min=1),
    crop_px: int = option("--crop-px", "Crop side.", field=(RankerConfig, "crop_px"), min=16, max=128),
    crop_channels: str = option("--crop-channels", "The crop's channels, comma-separated, a sub-sequence of "
                                "I,H,M_T,claws,M_L,M_O (M_L other logs, M_O obstacles; default all, or with "
                                "--init-from the checkpoint's).", default=None, metavar="LIST"),
    seed: int = option("--seed", "Initialisation and batch order.", field=(RankerTrainConfig, "seed")),
    threads: int = option("--threads", "Torch CPU threads.", field=(RankerTrainConfig, "num_threads"), min=1),
    no_repeats: bool = option("--no-repeats", "Leave out the robust labels' repeats (default: each repeat is an "
                              "example of its own, labelled by its outcome).", default=False, names=["repeats"]),
    no_balance: bool = option("--no-balance", "Pool the --data sets' examples (default: each set an equal share of "
                              "every epoch).", default=False, names=["balance_data"]),
    pairwise_weight: float = option("--pairwise-weight", "Weight of the within-pile pairwise (RankNet) term beside "
                                    "the BCE; batches then hold whole piles (0: BCE alone).",
                                    field=(RankerTrainConfig, "pairwise_weight"), min=0.0),
    init: Path = option("--init-from", "A ranker checkpoint to fine-tune (e.g. on a new on-policy round) instead of "
                        "starting from random weights; its crop and network are kept.", default=None,
                        metavar="FILE"),
    as_json: bool = JSON,
) -> None:
    """Train the grasp ranker that re-scores the network's best grasps (plan/eval --ranker).

    \b
    Example: loggrasp train-ranker --data data/paper-v4 --data rounds/r0 --out runs/ranker.safetensors
    """
    from planner.ranker_train import train_ranker

    o = Output(as_json)
    for d in data:
        check_input(d, "--data", "dir")
    check_output_file(out, "--out", ".safetensors")
    cfg = RankerTrainConfig(epochs=epochs, batch_size=batch_size, lr=lr, renders=renders, seed=seed,
                            num_threads=threads, balance_data=not no_balance, repeats=not no_repeats,
                            pairwise_weight=pairwise_weight)
    if init is not None:
        check_input(init, "--init-from", "file")
    rcfg = _ranker_config(crop_px, crop_channels, init)
    log = train_ranker(list(data), out, cfg, rcfg, progress=o.progress, init=init)
    f = log["final"]
    o.say(f"ranker: {out}; validation: within-pile AUC {f['val_auc']:.3f} on {f['val_auc_piles']} piles, "
          f"BCE {f['val_bce']:.4f}, Brier {f['val_brier']:.4f}")
    o.result("loggrasp.train_ranker", {"out": str(out), "final": f, "examples": log["examples"]})


def _ranker_config(crop_px: int, crop_channels: str | None, init: Path | None) -> RankerConfig | None:
    """The crop asked for; None (keep the checkpoint's) with --init-from and no crop option off its default."""
    channels = CROP_CHANNELS if crop_channels is None else tuple(c.strip() for c in crop_channels.split(","))
    if init is not None and crop_channels is None and crop_px == RankerConfig.crop_px:
        return None
    try:
        return RankerConfig(crop_px=crop_px, crop_channels=channels)
    except ValueError as exc:
        raise CliError(f"--crop-channels: {exc}") from exc
