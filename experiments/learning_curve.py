"""The learning curve (issue 15): one recipe trained on nested shares of the training piles, every
model evaluated on the same held-out piles with the paper's protocol, so that the curve says whether
data, capacity or the recipe limits the network. ``bench/learning_curve.py`` is its command.

Each share trains into ``OUT/share_<s>/`` (resumable through ``planner.train.train``; a share whose
log holds every epoch and whose resume state was left out, as in a commit, is not trained again) and
all models are evaluated once, on the same fresh piles, into ``OUT/eval/`` (resumable per pile).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from planner.loss import LossWeights

SHARES = (0.125, 0.25, 0.5, 1.0)
#: BCE weight of the positive U pixels, the shipped model's: with the paper's plain BCE (1) the
#: network's U stays low everywhere (its maximum ~0.09 on validation piles after 16 epochs, the argmax
#: in a labelled grasp region on 10-27 % of them; docs/results/learning-curve-plain-bce)
U_POS_WEIGHT = LossWeights().u_pos_weight


def _source(data: list[str]):
    """What planner functions take for ``--data``: one folder, or a list of them."""
    return data if len(data) > 1 else data[0]


def share_dir(out: Path, share: float) -> Path:
    return out / f"share_{share:g}"


def finished_share(folder: Path, epochs: int) -> bool:
    """Whether ``folder`` holds a finished run of ``epochs`` epochs: its best model and a log of every
    epoch. Such a share is not trained again, so the committed result needs no 23 MB resume state."""
    from planner.train import read_log

    if not (folder / "model.safetensors").exists() or not (folder / "log.json").exists():
        return False
    done = {e["epoch"] for e in read_log(folder / "log.json")["epochs"]}
    return done == set(range(epochs))


def convergence(folder: Path) -> dict:
    """The share's best epoch (by validation loss), the epochs run and the best validation loss."""
    from planner.train import read_log

    eps = read_log(folder / "log.json")["epochs"]
    best = min(eps, key=lambda e: e["val_loss"])
    return {"best_epoch": best["epoch"] + 1, "epochs_run": len(eps), "val_loss": best["val_loss"]}


def train_shares(data: list[str], out: Path, shares, epochs: int, base_channels: int, device: str,
                 precision: str, max_steps_per_epoch: int | None = None, batch_size: int = 16,
                 skip_no_candidates: bool = False, u_pos_weight: float = U_POS_WEIGHT,
                 progress=print) -> dict[float, Path]:
    """Train one model per share with the same recipe; returns share -> best checkpoint."""
    from planner.data import DataConfig, list_shards
    from planner.loss import LossWeights
    from planner.model import UNetConfig
    from planner.train import TrainConfig, train

    _, grid = list_shards(_source(data))
    size = int(grid.get("size_px", UNetConfig().size_px))
    models = {}
    for s in shares:
        cfg = TrainConfig(model=replace(UNetConfig(), base_channels=base_channels, size_px=size),
                          data=replace(DataConfig(), train_fraction=s, skip_no_candidates=skip_no_candidates),
                          loss=replace(LossWeights(), u_pos_weight=u_pos_weight), epochs=epochs, batch_size=batch_size,
                          device=device, precision=precision, max_steps_per_epoch=max_steps_per_epoch)
        if finished_share(share_dir(out, s), epochs) and not (share_dir(out, s) / "state.safetensors").exists():
            progress(f"share {s:g}: finished in {share_dir(out, s)} (log.json has all {epochs} epochs)")
            models[s] = share_dir(out, s) / "model.safetensors"
            continue
        progress(f"share {s:g}: training into {share_dir(out, s)}")
        res = train(_source(data), share_dir(out, s), cfg)
        models[s] = res.model_path
    return models


def evaluate_shares(models: dict[float, Path], out: Path, objectives, per_cell: int, logs, workers: int,
                    seed_base: int, size_px: int = 128, extra: dict[str, Path] | None = None) -> dict:
    """Every share's model on the same fresh piles (``planner.evaluate.run_evaluation``); ``extra``
    (label -> checkpoint) adds other recipes' models to the same evaluation, rows ``<label>-<objective>``."""
    from planner.evaluate import EvalConfig, PlannerSpec, run_evaluation

    named = [(f"share{s:g}", p) for s, p in sorted(models.items())] + sorted((extra or {}).items())
    specs = [PlannerSpec(kind="unet", model=str(p), objective=o, label=f"{name}-{o}") for name, p in named
             for o in objectives]
    cfg = EvalConfig(logs=tuple(logs), per_cell=per_cell, seed_base=seed_base, size_px=size_px)
    return run_evaluation(specs, cfg, out / "eval", workers=workers)


def count_train_piles(data: list[str], shares) -> dict[float, int]:
    """How many piles each share trains on (the stream's own rule, default split)."""
    from planner.data import DataConfig, in_train_fraction, is_validation_pile, list_shards, load_samples, sample_pile_id

    shards, _ = list_shards(_source(data))
    ids = {sample_pile_id(x) for sh in shards for x in load_samples(sh)}
    d = DataConfig()
    train = [i for i in ids if not is_validation_pile(i, d.split_seed, d.val_fraction)]
    return {s: sum(in_train_fraction(i, d.split_seed, s) for i in train) for s in shares}


NO_LOG = {"best_epoch": None, "epochs_run": None, "val_loss": None}


def model_share(path: Path) -> float | None:
    """The share of the training piles a checkpoint was trained on (its training log's config);
    None for a checkpoint without its log beside it (e.g. the shipped model, trained on other data)."""
    from planner.train import read_log

    log = Path(path).parent / "log.json"
    return float(read_log(log)["config"]["data"]["train_fraction"]) if log.exists() else None


def curve_rows(tables: dict, models: dict[float, Path], objectives, train_piles: dict[float, int],
               extra: dict[str, Path] | None = None) -> list[dict]:
    """One row per (model, objective): training piles, success, logs per success, beta. The curve's
    models are recipe ``curve``; an ``extra`` model's recipe is its label."""

    named = [("curve", f"share{s:g}", s, p) for s, p in sorted(models.items())]
    named += [(label, label, model_share(p), p) for label, p in sorted((extra or {}).items())]
    rows = []
    for recipe, name, s, path in named:
        for o in objectives:
            t = tables["planners"][f"{name}-{o}"]["total"]
            rows.append({"recipe": recipe, "share": s, "objective": o, "train_piles": train_piles.get(s),
                         "piles": t["piles"], "success_rate": t["success_rate"],
                         "avg_logs_success": t["avg_logs_success"], "beta_avg_deg": t["beta_avg_deg"],
                         **(convergence(path.parent) if s is not None else NO_LOG)})
    return rows


def write_curve(rows: list[dict], out: Path) -> None:
    from synth.common.files import atomic_write_bytes, dumps_json

    lines = ["| recipe | share of training piles | training piles | objective | test piles | success (95 % half-width) "
             "| logs / success | beta avg | best epoch / run | best val loss |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        z = 1.96 * math.sqrt(max(r["success_rate"] * (1 - r["success_rate"]), 1e-12) / max(r["piles"], 1))
        share = "-" if r["share"] is None else f"{r['share']:g}"
        piles = "-" if r["train_piles"] is None else r["train_piles"]
        conv = "- | -" if r["val_loss"] is None else f"{r['best_epoch']} / {r['epochs_run']} | {r['val_loss']:.4f}"
        lines.append(f"| {r.get('recipe', 'curve')} | {share} | {piles} | {r['objective']} | {r['piles']} | "
                     f"{100 * r['success_rate']:.1f} % ± {100 * z:.1f} | {r['avg_logs_success']:.2f} | "
                     f"{r['beta_avg_deg']:.1f}° | {conv} |")
    atomic_write_bytes(out / "learning_curve.md", ("\n".join(lines) + "\n").encode())
    atomic_write_bytes(out / "learning_curve.json", dumps_json({"format": "loggrasp.learning-curve",
                                                                "format_version": "1.0", "rows": rows}).encode())
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    recipes = sorted({r["recipe"] for r in rows if r.get("recipe", "curve") != "curve"})
    marker = dict(zip(recipes, "sD^vP*XhpH" * 3))  # one shape per extra recipe, the colour per objective
    for o, ref in (("f1", 0.90), ("f3", 0.96)):
        mine = [r for r in rows if r["objective"] == o and r.get("recipe", "curve") == "curve"]
        if not mine:
            continue
        line, = ax.plot([r["train_piles"] for r in mine], [100 * r["success_rate"] for r in mine], "o-", label=f"{o} (network)")
        ax.axhline(100 * ref, color=line.get_color(), ls=":", label=f"{o}: the paper ({100 * ref:.0f} %)")
        for r in rows:
            if r["objective"] != o or r.get("recipe", "curve") == "curve":
                continue
            if r["train_piles"] is None:  # trained on other data: a level to compare with
                ax.axhline(100 * r["success_rate"], color=line.get_color(), ls="--", lw=0.8, label=f"{o}: {r['recipe']}")
            else:
                ax.plot([r["train_piles"]], [100 * r["success_rate"]], marker[r["recipe"]], mfc="none",
                        color=line.get_color(), label=f"{o}: {r['recipe']}")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("training piles (nested shares of the data set)")
    ax.set_ylabel("success on held-out piles [%]")
    ax.set_title("Learning curve: same recipe, nested shares of the data")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "learning_curve.png", dpi=120)
    plt.close(fig)


def size_px_of(data: list[str]) -> int:
    from planner.data import list_shards

    return int(list_shards(_source(data))[1].get("size_px", 128))
