"""The learning curve of issue 15: the same recipe trained on 1/8, 1/4, 1/2 and all of the training
piles, every model evaluated on the same held-out piles (the paper's protocol, f1 and f3), so that
the curve says whether data, capacity or the recipe limits the network.

Each share trains into ``OUT/share_<s>/`` (resumable: ``planner.train.train`` resumes a run with
the same configuration) and the evaluation of all models runs once, on the same fresh piles, into
``OUT/eval/`` (resumable per pile). Writes ``OUT/learning_curve.md``, ``.json`` and ``.png``.

    # the full run (hours on 2 CPU cores; minutes of training on a GPU machine)
    .venv/bin/python bench/learning_curve.py --data data/paper-v3 --out docs/results/learning-curve \\
        --epochs 30 --per-cell 20 --workers 2
    # training only (e.g. on a GPU machine with an export), evaluation later where pybullet is
    .venv/bin/python bench/learning_curve.py --data out/paper-v3-train --out runs/lc --train-only --device cuda

The shares are nested (``DataConfig.train_fraction``): 1/8 of the piles is a subset of 1/4 of them.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

SHARES = (0.125, 0.25, 0.5, 1.0)


def share_dir(out: Path, share: float) -> Path:
    return out / f"share_{share:g}"


def train_shares(data: list[str], out: Path, shares, epochs: int, base_channels: int, device: str,
                 precision: str, max_steps_per_epoch: int | None = None, batch_size: int = 16,
                 skip_no_candidates: bool = False, progress=print) -> dict[float, Path]:
    """Train one model per share with the same recipe; returns share -> best checkpoint."""
    from planner.data import DataConfig, list_shards
    from planner.model import UNetConfig
    from planner.train import TrainConfig, train

    _, grid = list_shards(data if len(data) > 1 else data[0])
    size = int(grid.get("size_px", UNetConfig().size_px))
    models = {}
    for s in shares:
        cfg = TrainConfig(model=replace(UNetConfig(), base_channels=base_channels, size_px=size),
                          data=replace(DataConfig(), train_fraction=s, skip_no_candidates=skip_no_candidates), epochs=epochs, batch_size=batch_size,
                          device=device, precision=precision, max_steps_per_epoch=max_steps_per_epoch)
        progress(f"share {s:g}: training into {share_dir(out, s)}")
        res = train(data if len(data) > 1 else data[0], share_dir(out, s), cfg)
        models[s] = res.model_path
    return models


def evaluate_shares(models: dict[float, Path], out: Path, objectives, per_cell: int, logs, workers: int,
                    seed_base: int, size_px: int = 128) -> dict:
    """Every share's model on the same fresh piles (``planner.evaluate.run_evaluation``)."""
    from planner.evaluate import EvalConfig, PlannerSpec, run_evaluation

    specs = [PlannerSpec(kind="unet", model=str(p), objective=o, label=f"share{s:g}-{o}")
             for s, p in sorted(models.items()) for o in objectives]
    cfg = EvalConfig(logs=tuple(logs), per_cell=per_cell, seed_base=seed_base, size_px=size_px)
    return run_evaluation(specs, cfg, out / "eval", workers=workers)


def count_train_piles(data: list[str], shares) -> dict[float, int]:
    """How many piles each share trains on (the stream's own rule, default split)."""
    from planner.data import DataConfig, in_train_fraction, is_validation_pile, list_shards, load_samples, sample_pile_id

    shards, _ = list_shards(data if len(data) > 1 else data[0])
    ids = {sample_pile_id(x) for sh in shards for x in load_samples(sh)}
    d = DataConfig()
    train = [i for i in ids if not is_validation_pile(i, d.split_seed, d.val_fraction)]
    return {s: sum(in_train_fraction(i, d.split_seed, s) for i in train) for s in shares}


def curve_rows(tables: dict, models: dict[float, Path], objectives, train_piles: dict[float, int]) -> list[dict]:
    """One row per (share, objective): training piles, success, logs per success, beta."""

    rows = []
    for s, path in sorted(models.items()):
        piles = train_piles.get(s)
        for o in objectives:
            t = tables["planners"][f"share{s:g}-{o}"]["total"]
            rows.append({"share": s, "objective": o, "train_piles": piles, "piles": t["piles"],
                         "success_rate": t["success_rate"], "avg_logs_success": t["avg_logs_success"],
                         "beta_avg_deg": t["beta_avg_deg"]})
    return rows


def write_curve(rows: list[dict], out: Path) -> None:
    from synth.common.files import atomic_write_bytes, dumps_json

    lines = ["| share of training piles | training piles | objective | test piles | success (95 % half-width) "
             "| logs / success | beta avg |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        z = 1.96 * math.sqrt(max(r["success_rate"] * (1 - r["success_rate"]), 1e-12) / max(r["piles"], 1))
        lines.append(f"| {r['share']:g} | {r['train_piles']} | {r['objective']} | {r['piles']} | {100 * r['success_rate']:.1f} % "
                     f"± {100 * z:.1f} | {r['avg_logs_success']:.2f} | {r['beta_avg_deg']:.1f}° |")
    atomic_write_bytes(out / "learning_curve.md", ("\n".join(lines) + "\n").encode())
    atomic_write_bytes(out / "learning_curve.json", dumps_json({"format": "loggrasp.learning-curve",
                                                                "format_version": "1.0", "rows": rows}).encode())
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for o, ref in (("f1", 0.90), ("f3", 0.96)):
        mine = [r for r in rows if r["objective"] == o]
        if not mine:
            continue
        line, = ax.plot([r["train_piles"] for r in mine], [100 * r["success_rate"] for r in mine], "o-", label=f"{o} (network)")
        ax.axhline(100 * ref, color=line.get_color(), ls=":", label=f"{o}: the paper ({100 * ref:.0f} %)")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("training piles (nested shares of the data set)")
    ax.set_ylabel("success on held-out piles [%]")
    ax.set_title("Learning curve: same recipe, nested shares of the data")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "learning_curve.png", dpi=120)
    plt.close(fig)


def _size_px(data: list[str]) -> int:
    from planner.data import list_shards

    return int(list_shards(data if len(data) > 1 else data[0])[1].get("size_px", 128))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", action="append", required=True, help="data set or store folder (repeatable)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--shares", default=",".join(f"{s:g}" for s in SHARES))
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--base-channels", type=int, default=23, help="23 ~ 4.0 M parameters (the paper's 4.1 M)")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--precision", default="bf16")
    ap.add_argument("--max-steps-per-epoch", type=int, default=None)
    ap.add_argument("--objectives", default="f1,f3")
    ap.add_argument("--logs", default="2,3,4,5,6,7")
    ap.add_argument("--per-cell", type=int, default=20, help="piles per (size, obstacles) cell; 20 x 12 = 240")
    ap.add_argument("--seed-base", type=int, default=910_000_000, help="far from training and other evaluations")
    ap.add_argument("--workers", type=int, default=0)
    ap.add_argument("--train-only", action="store_true")
    ap.add_argument("--skip-no-candidates", action="store_true",
                    help="leave out subsets without an admissible candidate (DataConfig.skip_no_candidates)")
    a = ap.parse_args(argv)
    shares = [float(s) for s in a.shares.split(",")]
    if any(not 0 < s <= 1 for s in shares):
        ap.error(f"--shares must be in (0, 1], got {a.shares}")
    objectives = a.objectives.split(",")
    a.out.mkdir(parents=True, exist_ok=True)
    models = train_shares(a.data, a.out, shares, a.epochs, a.base_channels, a.device, a.precision,
                          a.max_steps_per_epoch, a.batch_size, a.skip_no_candidates)
    if a.train_only:
        print(json.dumps({str(k): str(v) for k, v in models.items()}))
        return 0
    tables = evaluate_shares(models, a.out, objectives, a.per_cell, [int(x) for x in a.logs.split(",")],
                             a.workers, a.seed_base, _size_px(a.data))
    rows = curve_rows(tables, models, objectives, count_train_piles(a.data, shares))
    write_curve(rows, a.out)
    print((a.out / "learning_curve.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
