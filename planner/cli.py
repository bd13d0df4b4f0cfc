"""``loggrasp train`` and ``loggrasp plan``: thin commands over :mod:`planner`."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from synth.cli import fail

#: The trained default model shipped with loggrasp (safetensors + config in its header).
DEFAULT_MODEL = Path(__file__).resolve().parent / "weights" / "default.safetensors"


def train_command(
    data: list[Path] = typer.Option(..., "--data", help="Data set folder (from `loggrasp synth dataset`); repeat to train on several."),
    out: Path = typer.Option(..., "--out", help="Run folder: checkpoints, log, training curve."),
    epochs: int = typer.Option(50, "--epochs"),
    batch_size: int = typer.Option(16, "--batch-size"),
    lr: float = typer.Option(1e-3, "--lr"),
    lr_schedule: str = typer.Option("cosine", "--lr-schedule", help="cosine (decays to 5 % of --lr) or constant."),
    base_channels: int = typer.Option(23, "--base-channels", help="U-Net width (23 ~ 4.0M parameters, the paper's size; 16 ~ 1.9M)."),
    no_depth: bool = typer.Option(False, "--no-depth", help="The paper's ablation: inputs (I, M_T) only."),
    u_pos_weight: float = typer.Option(1.0, "--u-pos-weight", help="BCE weight of positive U pixels (1 = the paper's plain BCE; U marks ~0.3 % of pixels)."),
    seed: int = typer.Option(0, "--seed"),
    device: str = typer.Option("auto", "--device", help="auto, cpu or cuda."),
    precision: str = typer.Option("bf16", "--precision", help="bf16 (autocast) or fp32."),
    max_steps_per_epoch: int = typer.Option(None, "--max-steps-per-epoch", help="Cap steps per epoch (quick runs)."),
) -> None:
    """Train the target-conditioned U-Net; re-running the same command resumes from the last checkpoint.

    Example: loggrasp train --data data/ --out runs/r1 --epochs 50
    """
    from dataclasses import replace

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from planner.data import DataConfig
    from planner.errors import PlannerError
    from planner.loss import LossWeights
    from planner.model import UNetConfig
    from planner.train import TrainConfig, train
    from synth.errors import SynthError

    try:
        in_ch = 2 if no_depth else 3
        cfg = TrainConfig(model=replace(UNetConfig(), base_channels=base_channels, in_channels=in_ch),
                          loss=replace(LossWeights(), u_pos_weight=u_pos_weight),
                          data=replace(DataConfig(), in_channels=in_ch), epochs=epochs, batch_size=batch_size,
                          lr=lr, lr_schedule=lr_schedule, seed=seed, device=device, precision=precision,
                          max_steps_per_epoch=max_steps_per_epoch)
    except (ValueError, TypeError) as exc:
        fail(str(exc))
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[info]}"),
                  TimeElapsedColumn()) as bar:
        task = bar.add_task("training", total=epochs, info="")

        def progress(ev: dict) -> None:
            def num(key: str) -> str:
                v = ev.get(key)
                return "-" if v is None else f"{v:.4f}"

            if ev.get("kind") == "epoch":
                bar.update(task, completed=(ev.get("epoch") or 0) + 1,
                           info=f"train {num('train_loss')} val {num('val_loss')}")
            else:
                bar.update(task, info=f"step {ev.get('step')} loss {num('loss')} "
                                      f"{ev.get('samples_per_s') or 0:.1f} samples/s")

        try:
            result = train(data if len(data) > 1 else data[0], out, cfg, progress=progress)
        except (PlannerError, SynthError, ValueError) as exc:
            fail(str(exc))
    typer.echo(f"best checkpoint: {result.model_path}\ntraining curve: {result.curve_path}")


def load_observation(path: Path, cfg):
    """An observation from a pile folder (its ortho.npz when it has the network's pixel pitch,
    else re-rendered) or a pile.json (rendered at the pitch of ``cfg``, a
    :class:`planner.model.UNetConfig`). Returns (observation, pile or None)."""
    from planner.errors import ObservationError
    from planner.inference import check_grid
    from synth.pile import read_pile
    from synth.render import OrthoObservation, OrthoRenderConfig, render_ortho
    from synth.world import World

    folder = path if path.is_dir() else path.parent
    pile = None
    if (folder / "pile.json").exists() or path.suffix == ".json":
        pile = read_pile(path)
    npz = folder / "ortho.npz"
    if npz.exists():
        obs = OrthoObservation.load(npz)
        try:
            check_grid(obs.depth.shape[0], obs.extent_m, cfg)
            return obs, pile
        except ObservationError:
            pass  # rendered from the pile below
    if pile is None:
        raise FileNotFoundError(f"{path}: neither a pile.json nor an ortho.npz at the network's pixel pitch "
                                f"({100 * cfg.pixel_m:.2f} cm)")
    size = max(16, round(pile.terrain.extent_m / cfg.pixel_m))  # plan() names a patch that does not fit
    with World(pile) as world:
        return render_ortho(world, OrthoRenderConfig(size_px=size, n_renders=1), seed=pile.seed or 0), pile


def plan_command(
    pile: Path = typer.Argument(..., help="A pile folder (pile.json and/or ortho.npz) or a pile.json."),
    model: Path = typer.Option(None, "--model", help="Checkpoint (.safetensors); default: the shipped model."),
    objective: str = typer.Option("f1", "--objective", help="f1 (graspability), f2 (+ more logs), f3 (+ balance)."),
    top: int = typer.Option(5, "--top", help="How many subsets' best grasps to list."),
    as_json: bool = typer.Option(False, "--json", help="Print the plan as JSON."),
    png: Path = typer.Option(None, "--png", help="Draw the chosen grasp and targets over the render."),
    max_subsets: int = typer.Option(127, "--max-subsets", help="Network passes budget; larger piles are pruned."),
    views: int = typer.Option(1, "--views", help="Dihedral views averaged: 1, 2, 4 or 8 (slower, steadier)."),
    view_spread: float = typer.Option(0.0, "--view-spread", help="Lower U by K x its spread over the views (needs --views > 1)."),
) -> None:
    """Plan the best multi-log grasp on a pile: every target subset scored with Q = f(U, tau, B).

    Example: loggrasp plan piles/pile_00000 --objective f3 --json
    """
    from planner.errors import PlannerError
    from planner.inference import Objective, load_planner, plan
    from planner.subsets import SubsetPolicy
    from synth.errors import SynthError

    path = model or DEFAULT_MODEL
    try:
        planner = load_planner(path, views=views, view_spread_k=view_spread)
        obs, spec = load_observation(pile, planner.config)
        result = plan(obs, planner, Objective(kind=objective), top_k=top,
                      subsets=SubsetPolicy(max_subsets=max_subsets), pile=spec)
    except (PlannerError, SynthError, ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    if png is not None:
        from synth.preview import draw_grasps, write_png

        write_png(png, draw_grasps(obs, [(g.grasp, g.targets) for g in result.grasps],
                                   labels=[f"{g.quality:.2f}" for g in result.grasps]))
    if as_json:
        d = result.to_dict()
        typer.echo(json.dumps({k: d[k] for k in ("grasps", "subsets_evaluated", "elapsed_s")}, indent=1))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{result.subsets_evaluated} subsets in {result.elapsed_s:.2f} s, objective {objective}")
    for col in ("rank", "targets", "x m", "y m", "phi deg", "width m", "q", "u", "b"):
        table.add_column(col, justify="right")
    import math

    for i, g in enumerate(result.grasps):
        table.add_row(str(i + 1), ",".join(map(str, g.targets)), f"{g.grasp.x_m:.2f}", f"{g.grasp.y_m:.2f}",
                      f"{math.degrees(g.grasp.phi_rad):.1f}", f"{g.grasp.width_m:.2f}", f"{g.quality:.3f}",
                      f"{g.graspability:.3f}", f"{g.balance:.3f}")
    Console().print(table)
    for r in result.rejected:
        typer.echo(f"rejected {r['targets']}: {r['constraint']} ({r['detail']})")


def eval_command(
    out: Path = typer.Option(..., "--out", help="Results folder (records, results.md/json, examples.png)."),
    model: Path = typer.Option(None, "--model", help="Checkpoint; default: the shipped model."),
    per_cell: int = typer.Option(100, "--per-cell", help="Piles per (size, obstacles) cell."),
    logs: str = typer.Option("2-7", "--logs", help="Pile sizes, 'A-B'."),
    obstacles: str = typer.Option("both", "--obstacles", help="yes, no or both."),
    objectives: str = typer.Option("f1,f2,f3", "--objectives", help="Comma-separated: f1,f2,f3."),
    baselines: str = typer.Option("random,geometric,oracle", "--baselines",
                                  help="Comma-separated baselines through the same trials ('' for none)."),
    extra_model: list[str] = typer.Option([], "--extra-model", help="LABEL=PATH, e.g. no-depth=runs/nd/best.safetensors."),
    workers: int = typer.Option(0, "--workers", help="Processes (0 = all cores) or Dask workers."),
    engine: str = typer.Option("local", "--engine", help="local or dask."),
    address: str = typer.Option(None, "--address", help="Dask scheduler address."),
    trial: str = typer.Option("fast", "--trial", help="Trial preset: fast or careful."),
    seed_base: int = typer.Option(900_000_000, "--seed-base", help="First test seed (keep far from training seeds)."),
) -> None:
    """Evaluate planners in the twin, the paper's protocol: fresh piles, one grasp each, tried in physics.

    Example: loggrasp eval --per-cell 100 --logs 2-7 --obstacles both --objectives f1,f2,f3 --out results/
    Re-running resumes (one record file per pile).
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    from planner.evaluate import EvalConfig, PlannerSpec, run_evaluation
    from synth.errors import SynthError
    from synth.jobs import parse_range

    try:
        lo, hi = parse_range(logs, "--logs")
        obs = {"yes": (True,), "no": (False,), "both": (True, False)}.get(obstacles)
        if obs is None:
            raise ValueError(f"--obstacles must be yes, no or both, got {obstacles!r}")
        cfg = EvalConfig(logs=tuple(range(lo, hi + 1)), obstacles=obs, per_cell=per_cell, trial=trial,
                         seed_base=seed_base)
        path = str(model or DEFAULT_MODEL)
        specs = [PlannerSpec("unet", model=path, objective=o.strip()) for o in objectives.split(",") if o.strip()]
        for item in extra_model:
            label, _, p = item.partition("=")
            if not p:
                raise ValueError(f"--extra-model must be LABEL=PATH, got {item!r}")
            specs.append(PlannerSpec("unet", model=p, objective="f1", label=label))
        specs += [PlannerSpec(b.strip()) for b in baselines.split(",") if b.strip()]
        for s in specs:
            if s.kind == "unet" and not Path(s.model).exists():
                raise ValueError(f"model {s.model} not found; train one with `loggrasp train` or pass --model")
    except ValueError as exc:
        fail(str(exc))
    with Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TimeRemainingColumn()) as bar:
        task = bar.add_task("piles", total=len(cfg.tasks()))
        try:
            run_evaluation(specs, cfg, out, workers=workers, engine=engine, address=address,
                           progress=lambda d, t: bar.update(task, completed=d))
        except (SynthError, ValueError) as exc:
            fail(str(exc))
    typer.echo((Path(out) / "results.md").read_text())
