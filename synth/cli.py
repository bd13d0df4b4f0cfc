"""``loggrasp synth ...``: thin commands over :mod:`synth` (heavy imports stay inside commands).

Flags take their defaults from the config dataclasses (:func:`synth.common.cli.option`); errors
are raised and printed once by ``field.cli.run``."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import typer

from synth.common.cli import CliError, Output, check_input, check_output_dir, option, plural, progress_bar
from synth.data.dataset import DatasetJob
from synth.data.jobs import PileJob

#: how every loggrasp Typer app formats help: plain text (units such as [m] kept, no markup), -h
APP_SETTINGS = dict(no_args_is_help=True, rich_markup_mode=None, add_completion=False, pretty_exceptions_enable=False,
                    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})

app = typer.Typer(help="The simulator twin: generate and render log piles, build the training data set, make "
                       "field scans with known truth.", **APP_SETTINGS)

JSON = option("--json", "Print the result as one JSON document on standard output (progress stays on "
                        "standard error).", default=False)
WORKERS = option("--workers", "Worker processes (0 = all cores) or Dask workers.", default=0, min=0)


@app.command("piles")
def piles(
    count: int = option("--count", "Number of piles to generate.", default=..., min=1, metavar="INT",
                        names=["count"]),
    out: Path = option("--out", "Output folder (one sub-folder per pile).", default=..., metavar="DIR"),
    logs: str = option("--logs", "Logs per pile, 'A-B' or 'A'.", default="4", names=["logs"]),
    obstacles: str = option("--obstacles", "Obstacles (stumps, rocks) per pile, 'A-B' or 'A'.", default="0",
                            names=["obstacles"]),
    seed: int = option("--seed", "Job seed: same seed, same piles.", field=(PileJob, "seed")),
    packed: bool = option("--packed", "Aligned, tightly packed logs.", field=(PileJob, "packed")),
    size: int = option("--size", "Orthographic render size (a multiple of 16).", field=(PileJob, "size_px"),
                       min=16, max=2048),
    renders: int = option("--renders", "Renders per pile with random colours/light.", field=(PileJob, "n_renders"),
                          min=1),
    stereo: bool = option("--stereo", "Also write a ZED 2-like stereo pair + calibration.", field=(PileJob, "stereo")),
    workers: int = WORKERS,
    as_json: bool = JSON,
) -> None:
    """Generate settled piles and their renders: pile.json, ortho.npz, preview.png per pile.

    \b
    Example: loggrasp synth piles --count 10 --logs 2-7 --obstacles 0-3 --seed 1 --out piles/
    Re-running the same command resumes: finished piles are kept, the rest are made.
    """
    from synth.common.ranges import parse_range
    from synth.data.jobs import run_pile_job

    o = Output(as_json)
    job = PileJob(count=count, logs=parse_range(logs, "--logs"), obstacles=parse_range(obstacles, "--obstacles"),
                  seed=seed, packed=packed, size_px=size, n_renders=renders, stereo=stereo)
    check_output_dir(out, "--out")
    with progress_bar() as bar:
        task = bar.add_task("piles", total=count, info="")
        stats = run_pile_job(out, job, workers=workers, progress=lambda d, t: bar.update(task, completed=d))
    o.say(f"{plural(stats['generated'], 'pile')} generated, {stats['skipped']} already there, in {out}")
    o.result("loggrasp.synth-piles", {"out": str(out), **stats})


@app.command("render")
def render(
    pile: Path = typer.Argument(..., metavar="PILE", help="A pile.json (or a folder holding one)."),
    out: Path = option("--out", "Folder for ortho.npz + preview.png (default: beside the pile).", default=None,
                       metavar="DIR"),
    size: int = option("--size", "Render size (a multiple of 16).", field=(PileJob, "size_px"), min=16, max=2048),
    renders: int = option("--renders", "Renders with random colours/light.", field=(PileJob, "n_renders"), min=1),
    as_json: bool = JSON,
) -> None:
    """Validate a (hand-written or reconstructed) pile and render it in the training format.

    \b
    Example: loggrasp synth render piles/pile_00000 --out renders/p0
    """
    from synth.scene.pile import read_pile
    from synth.render.preview import preview_image, write_png
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    o = Output(as_json)
    check_input(pile, "PILE")
    spec = read_pile(pile)
    out_dir = Path(out) if out is not None else (pile if pile.is_dir() else pile.parent)
    check_output_dir(out_dir, "--out")
    cfg = OrthoRenderConfig(size_px=size, n_renders=renders)
    with World(spec) as world:
        world.check_valid()
        obs = render_ortho(world, cfg, seed=spec.seed or 0)
    files = [obs.save(out_dir / "ortho.npz"), write_png(out_dir / "preview.png", preview_image(obs))]
    o.say(f"rendered {plural(spec.n_logs, 'log')} to {out_dir}")
    o.result("loggrasp.synth-render", {"pile": str(pile), "files": [str(f) for f in files], "n_logs": spec.n_logs})


@app.command("dataset")
def dataset(
    piles: int = option("--piles", "Number of piles.", default=..., min=1, metavar="INT", names=["n_piles"]),
    out: Path = option("--out", "Data set folder (manifest.json + shards).", default=..., metavar="DIR"),
    logs: str = option("--logs", "Logs per pile, 'A' or 'A-B' (piles cycle over A..B; the paper: 4).", default="4",
                       metavar="A[-B]", names=["logs"]),
    max_subsets: int = option("--max-subsets", "Target subsets simulated per pile: every single log, then "
                              "subsets of 2, 3, ... logs in turn, drawn at random (default: all 2^n - 1).",
                              field=(DatasetJob, "max_subsets"), min=1, metavar="INT"),
    obstacles_fraction: float = option("--obstacles-fraction", "Share of piles with obstacles.",
                                       field=(DatasetJob, "obstacles_fraction"), min=0.0, max=1.0),
    seed: int = option("--seed", "Job seed: same seed, same data set.", field=(DatasetJob, "seed")),
    workers: int = WORKERS,
    engine: Literal["local", "dask"] = option("--engine", "local (process pool) or dask.", default="local",
                                              metavar="local|dask"),
    address: str = option("--address", "Dask scheduler address (tcp://HOST:PORT); none = a local cluster.",
                          default=None, metavar="URL"),
    size: int = option("--size", "Render size (a multiple of 16).", field=(DatasetJob, "size_px"), min=16, max=2048),
    renders: int = option("--renders", "Renders per scene.", field=(DatasetJob, "n_renders"), min=1),
    trial: Literal["fast", "careful"] = option("--trial", "Trial settings preset.", field=(DatasetJob, "trial_preset"),
                                                metavar="fast|careful"),
    max_trials_per_subset: int = option("--max-trials-per-subset", "Algorithm 1 trial cap per target subset.",
                                        field=(DatasetJob, "max_trials_per_subset"), min=1),
    piles_dir: Path = option("--piles-dir", "Use the piles of a `loggrasp synth piles` job.", default=None,
                             metavar="DIR"),
    label_repeats: int = option("--label-repeats", "Robust labels: perturbed repeats of each grasp that succeeded "
                                "exactly (0 = the paper's one-success labels).", field=(DatasetJob, "label_repeats"),
                                min=0, max=64),
    label_error: str = option("--label-error", "Robust labels: the positioning error of the repeats, "
                              "SIGMA_XY_M,SIGMA_PHI_DEG (per horizontal axis [m], rotator [deg]).",
                              default="0.02,2", metavar="M,DEG"),
    label_min_fraction: float = option("--label-min-fraction", "Robust labels: accept a grasp when this share of "
                                       "its repeats succeeds.", field=(DatasetJob, "label_min_fraction"),
                                       min=0.0, max=1.0),
    store: bool = option("--store", "Write the compact form that is committed to git (store.json + chunks/: "
                         "piles, grasps, trials; renders are re-made on load) and resumes from any clone; "
                         "local engine only.", default=False),
    as_json: bool = JSON,
) -> None:
    """Try rule-based candidate grasps in physics (Algorithm 1) and write the grasp-map data set.

    With --store (e.g. --out data/paper-v3) the folder holds only what the simulation found and
    `loggrasp train --data data/paper-v3` renders the training images from it on first use.

    \b
    Example: loggrasp synth dataset --piles 604 --logs 4 --obstacles-fraction 0.33 --out data/
    Re-running resumes: finished shards are kept, partial ones redone. With --engine dask
    --address tcp://HOST:8786 the same job runs on a Dask cluster.
    """
    from synth.common.ranges import parse_range
    from synth.data.dataset import build_dataset, label_fields
    from synth.data.robust import RobustLabels
    from synth.physics.perturb import PositioningError

    o = Output(as_json)
    try:
        min_logs, max_logs = parse_range(logs, "--logs")
    except ValueError as exc:
        raise CliError(str(exc)) from exc
    if not 1 <= min_logs <= max_logs <= 10:
        raise CliError(f"--logs must lie in 1-10 (2^n - 1 target subsets per pile), got {logs!r}")
    sizes = {"n_logs": min_logs, "max_logs": None if max_logs == min_logs else max_logs, "max_subsets": max_subsets}
    try:
        labels = RobustLabels(label_repeats, PositioningError.parse(label_error), label_min_fraction)
    except ValueError as exc:
        raise CliError(f"--label-error / --label-repeats: {exc}") from exc
    if address is not None and engine != "dask":
        raise CliError("--address needs --engine dask")
    if store and (engine != "local" or piles_dir is not None):
        raise CliError("--store runs with --engine local and generates its own piles (drop --piles-dir)")
    DatasetJob(n_piles=piles, **sizes, obstacles_fraction=obstacles_fraction, seed=seed, size_px=size,
               n_renders=renders, max_trials_per_subset=max_trials_per_subset, trial_preset=trial,
               piles_dir=None if piles_dir is None else str(piles_dir),
               **label_fields(labels))  # every value checked before any work
    if piles_dir is not None:
        check_input(piles_dir, "--piles-dir", "dir")
    check_output_dir(out, "--out")
    with progress_bar() as bar:
        task = bar.add_task("piles", total=None, info="")

        def progress(p) -> None:
            bar.update(task, total=p.chunks_total, completed=p.chunks_done,
                       info=f"{p.samples} samples, {p.trials} trials, {p.trials_per_s:.1f} trials/s")

        if store:
            from synth.data.datastore import build_store

            job = DatasetJob(n_piles=piles, **sizes, obstacles_fraction=obstacles_fraction, seed=seed,
                             size_px=size, n_renders=renders, trial_preset=trial,
                             max_trials_per_subset=max_trials_per_subset, **label_fields(labels))
            rec = build_store(out, job, workers=workers or (os.cpu_count() or 1), progress=progress)
        else:
            manifest = build_dataset(out, n_piles=piles, **sizes, obstacles_fraction=obstacles_fraction,
                                     seed=seed, workers=workers, engine=engine, address=address, size_px=size,
                                     n_renders=renders, trial_config=trial,
                                     max_trials_per_subset=max_trials_per_subset, piles_dir=piles_dir,
                                     progress=progress, robust_labels=labels)
    s = rec["summary"] if store else manifest.summary
    rate = s.get("success_rate")
    what = (f"store {out}: {plural(int(s.get('map_samples', 0)), 'grasp map')}" if store
            else f"data set {out}: {plural(int(s.get('samples', 0)), 'sample')}")
    o.say(f"{what} from {plural(int(s.get('piles', 0)), 'pile')}, {plural(int(s.get('trials', 0)), 'trial')}"
          + (f" ({100 * rate:.0f} % successful)" if isinstance(rate, float) else "")
          + ("" if s.get("complete", True) else f"; {s.get('chunks_done')} of {s.get('chunks_total')} chunks done"))
    o.result("loggrasp.synth-dataset", {"out": str(out), "store": store, "summary": s})



@app.command("export")
def export(
    data: Path = option("--data", "A committed data-set store (store.json + chunks/), e.g. data/paper-v3.",
                        default=..., metavar="DIR"),
    out: Path = option("--out", "Folder for the training shards (manifest.json + .npz).", default=..., metavar="DIR"),
    max_mib: float = option("--max-mib", "Refuse an export larger than this [MiB] (a device machine takes 64 MiB "
                            "with the code).", default=60.0, min=1.0),
    as_json: bool = JSON,
) -> None:
    """Render a store's training shards into a folder that trains without pybullet.

    \b
    Example: loggrasp synth export --data data/paper-v3 --out out/paper-v3-train
    Then, on a machine with torch but no pybullet: loggrasp train --data out/paper-v3-train ...
    Re-running reuses the shards already made.
    """
    from synth.data.datastore import export_training, is_store

    o = Output(as_json)
    check_input(data, "--data", "dir")
    if not is_store(data):
        raise CliError(f"--data {data} is not a data-set store (no store.json); give the folder that "
                       "`loggrasp synth dataset --store` wrote")
    check_output_dir(out, "--out")
    with progress_bar() as bar:
        task = bar.add_task("chunks", total=None, info="")
        folder, size = export_training(data, out, max_bytes=int(max_mib * 2 ** 20),
                                       progress=lambda i, n: bar.update(task, total=n, completed=i))
    o.say(f"training shards of {data} in {folder}: {size / 2 ** 20:.1f} MiB")
    o.result("loggrasp.synth-export", {"data": str(data), "out": str(folder), "bytes": size})
