"""``loggrasp synth ...``: thin commands over :mod:`synth` (heavy imports stay inside commands)."""

from __future__ import annotations

import json
import os

from pathlib import Path

import typer

app = typer.Typer(help="The simulator twin: generate and render log piles.", no_args_is_help=True)


def fail(message: str, code: int = 2) -> None:
    from rich.console import Console
    from rich.markup import escape

    Console(stderr=True, soft_wrap=True).print(f"[bold red]error:[/] {escape(message)}", highlight=False)
    raise typer.Exit(code)


@app.command("piles")
def piles(
    count: int = typer.Option(..., "--count", help="Number of piles to generate."),
    out: Path = typer.Option(..., "--out", help="Output folder (one sub-folder per pile)."),
    logs: str = typer.Option("4", "--logs", help="Logs per pile, 'A-B' or 'A'."),
    obstacles: str = typer.Option("0", "--obstacles", help="Obstacles (stumps, rocks) per pile, 'A-B' or 'A'."),
    seed: int = typer.Option(0, "--seed", help="Job seed: same seed, same piles."),
    packed: bool = typer.Option(False, "--packed", help="Aligned, tightly packed logs."),
    size: int = typer.Option(128, "--size", help="Orthographic render size [px]."),
    renders: int = typer.Option(3, "--renders", help="Renders per pile with random colours/light."),
    stereo: bool = typer.Option(False, "--stereo", help="Also write a ZED 2-like stereo pair + calibration."),
    workers: int = typer.Option(0, "--workers", help="Worker processes (0 = all cores)."),
) -> None:
    """Generate settled piles and their renders: pile.json, ortho.npz, preview.png per pile.

    Example: loggrasp synth piles --count 10 --logs 2-7 --obstacles 0-3 --seed 1 --out piles/
    Re-running the same command resumes: finished piles are kept, the rest are made.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    from synth.errors import SynthError
    from synth.jobs import PileJob, parse_range, run_pile_job

    try:
        job = PileJob(count=count, logs=parse_range(logs, "--logs"), obstacles=parse_range(obstacles, "--obstacles"),
                      seed=seed, packed=packed, size_px=size, n_renders=renders, stereo=stereo)
    except ValueError as exc:
        fail(str(exc))
    with Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TimeRemainingColumn(), transient=False) as bar:
        task = bar.add_task("piles", total=count)
        try:
            stats = run_pile_job(out, job, workers=workers, progress=lambda d, t: bar.update(task, completed=d))
        except (SynthError, ValueError) as exc:
            fail(str(exc))
    typer.echo(f"{stats['generated']} piles generated, {stats['skipped']} already there, in {out}")


@app.command("render")
def render(
    pile: Path = typer.Argument(..., help="A pile.json (or a folder holding one)."),
    out: Path = typer.Option(None, "--out", help="Folder for ortho.npz + preview.png (default: beside the pile)."),
    size: int = typer.Option(128, "--size", help="Render size [px]."),
    renders: int = typer.Option(3, "--renders", help="Renders with random colours/light."),
) -> None:
    """Validate a (hand-written or reconstructed) pile and render it in the training format."""
    from synth.errors import SynthError
    from synth.pile import read_pile
    from synth.preview import preview_image, write_png
    from synth.render import OrthoRenderConfig, render_ortho
    from synth.world import World

    try:
        spec = read_pile(pile)
        out_dir = out or (pile if pile.is_dir() else pile.parent)
        with World(spec) as world:
            world.check_valid()
            obs = render_ortho(world, OrthoRenderConfig(size_px=size, n_renders=renders), seed=spec.seed or 0)
        obs.save(Path(out_dir) / "ortho.npz")
        write_png(Path(out_dir) / "preview.png", preview_image(obs))
    except (SynthError, ValueError) as exc:
        fail(str(exc))
    typer.echo(f"rendered {spec.n_logs} logs to {out_dir}")


@app.command("dataset")
def dataset(
    piles: int = typer.Option(..., "--piles", help="Number of piles."),
    out: Path = typer.Option(..., "--out", help="Data set folder (manifest.json + shards)."),
    logs: int = typer.Option(4, "--logs", help="Logs per pile (the paper: 4)."),
    obstacles_fraction: float = typer.Option(0.33, "--obstacles-fraction", help="Share of piles with obstacles."),
    seed: int = typer.Option(0, "--seed"),
    workers: int = typer.Option(0, "--workers", help="Processes (0 = all cores) or Dask workers."),
    engine: str = typer.Option("local", "--engine", help="local (process pool) or dask."),
    address: str = typer.Option(None, "--address", help="Dask scheduler address (tcp://host:port); "
                                                        "none = a local cluster."),
    size: int = typer.Option(128, "--size", help="Render size [px]."),
    renders: int = typer.Option(3, "--renders", help="Renders per scene."),
    trial: str = typer.Option("fast", "--trial", help="Trial settings preset: fast or careful."),
    max_trials_per_subset: int = typer.Option(16, "--max-trials-per-subset"),
    piles_dir: Path = typer.Option(None, "--piles-dir", help="Use the piles of a `synth piles` job."),
    store: bool = typer.Option(False, "--store", help="Write the compact form that is committed to git "
                               "(store.json + chunks/: piles, grasps, trials; renders are re-made on load) "
                               "and resumes from any clone; local engine only."),
) -> None:
    """Try rule-based candidate grasps in physics (Algorithm 1) and write the grasp-map data set.

    With --store (e.g. --out data/paper-v3) the folder holds only what the simulation found and
    `loggrasp train --data data/paper-v3` renders the training images from it on first use.

    Example: loggrasp synth dataset --piles 604 --logs 4 --obstacles-fraction 0.33 --out data/
    Re-running resumes: finished shards are kept, partial ones redone. With --engine dask
    --address tcp://HOST:8786 the same job runs on a Dask cluster.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from synth.dataset import build_dataset
    from synth.errors import SynthError

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                  TimeElapsedColumn()) as bar:
        task = bar.add_task("piles", total=None, info="")

        def progress(p) -> None:
            bar.update(task, total=p.chunks_total, completed=p.chunks_done,
                       info=f"{p.samples} samples, {p.trials} trials, {p.trials_per_s:.1f} trials/s")

        try:
            if store:
                if engine != "local" or piles_dir is not None:
                    fail("--store runs with --engine local and generates its own piles (drop --piles-dir)")
                from synth.dataset import DatasetJob
                from synth.datastore import build_store

                job = DatasetJob(n_piles=piles, n_logs=logs, obstacles_fraction=obstacles_fraction, seed=seed,
                                 size_px=size, n_renders=renders, trial_preset=trial,
                                 max_trials_per_subset=max_trials_per_subset)
                rec = build_store(out, job, workers=workers or (os.cpu_count() or 1), progress=progress)
                typer.echo(json.dumps(rec["summary"], indent=1))
                return
            manifest = build_dataset(out, n_piles=piles, n_logs=logs, obstacles_fraction=obstacles_fraction,
                                     seed=seed, workers=workers, engine=engine, address=address, size_px=size,
                                     n_renders=renders, trial_config=trial,
                                     max_trials_per_subset=max_trials_per_subset, piles_dir=piles_dir,
                                     progress=progress)
        except (SynthError, ValueError) as exc:
            fail(str(exc))
    typer.echo(json.dumps(manifest.summary, indent=1))
