"""`make bench`: measure loggrasp's speed targets and write docs/benchmarks.md.

Each section is a function returning Markdown; sections whose code is not there yet are skipped
with a note. A run appends its sections, dated, to docs/benchmarks-history.md, replaces the figures
it measured in docs/results/benchmarks.json (experiments.bench_measures reads them from the
sections' tables) and writes the page from that file (experiments.bench_page): the current figure
of every measure on top, measures this run did not touch kept with their own date and command.

Run: .venv/bin/python bench/run.py --out docs/benchmarks.md [--only NAME...] [--page-only]
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

from experiments.bench_measures import Run, measures_of_section
from experiments.bench_page import (BenchPageError, append_history, history_entry, read_measures, updated,
                                    write_measures, write_page)

ROOT = Path(__file__).resolve().parents[1]


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "?"


def machine() -> str:
    load = "/".join(f"{v:.1f}" for v in os.getloadavg())
    return (f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores ({_cpu()}), Python "
            f"{platform.python_version()}; load average at start {load} (1/5/15 min — other jobs inflate wall times)")


def machine_short() -> str:
    """``2-core Intel Xeon``: the page's machine column."""
    cpu = " ".join(w for w in _cpu().replace("(R)", "").replace("(TM)", "").split()
                   if w not in ("Processor", "CPU") and "@" not in w and not w.endswith("GHz"))
    return f"{os.cpu_count()}-core {cpu}"


def bench_piles(repeats: int = 5) -> str:
    from synth.scene.generate import GenerationConfig, generate_pile

    rows = ["| logs | obstacles | piles | wall s (median) | wall p90 | CPU s (median) | sim s (median) | attempts (mean) |",
            "|---|---|---|---|---|---|---|---|"]
    for n_logs in (4, 7):
        for n_obst in (0, 3):
            walls, cpus, sims, attempts = [], [], [], []
            for seed in range(repeats):
                t0, c0 = time.perf_counter(), time.process_time()
                _, rep = generate_pile(1000 + seed, GenerationConfig(n_logs=n_logs, n_obstacles=n_obst))
                walls.append(time.perf_counter() - t0)
                cpus.append(time.process_time() - c0)
                sims.append(rep.settle_time_s)
                attempts.append(rep.attempts)
            walls.sort()
            rows.append(f"| {n_logs} | {n_obst} | {repeats} | {statistics.median(walls):.2f} | "
                        f"{walls[int(0.9 * (len(walls) - 1))]:.2f} | {statistics.median(cpus):.2f} | "
                        f"{statistics.median(sims):.2f} | "
                        f"{statistics.mean(attempts):.1f} |")
    return ("### Settled piles (generate + drop + settle + validate, one process)\n"
            "Target: a 4-log pile settled in under 2 s.\n\n" + "\n".join(rows))


def bench_render(repeats: int = 20) -> str:
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    pile, _ = generate_pile(3, GenerationConfig(n_logs=7, n_obstacles=3))
    rows = ["| size px | one render wall s (median) | CPU s | 3 renders + depth + instance wall s (median) | CPU s |",
            "|---|---|---|---|---|"]
    with World(pile) as world:
        for size in (128, 256):
            one, three, one_c, three_c = [], [], [], []
            for _ in range(repeats):
                t0, c0 = time.perf_counter(), time.process_time()
                render_ortho(world, OrthoRenderConfig(size_px=size, n_renders=1))
                one.append(time.perf_counter() - t0)
                one_c.append(time.process_time() - c0)
                t0, c0 = time.perf_counter(), time.process_time()
                render_ortho(world, OrthoRenderConfig(size_px=size, n_renders=3))
                three.append(time.perf_counter() - t0)
                three_c.append(time.process_time() - c0)
            rows.append(f"| {size} | {statistics.median(one):.4f} | {statistics.median(one_c):.4f} | "
                        f"{statistics.median(three):.4f} | {statistics.median(three_c):.4f} |")
    return ("### Orthographic render (TinyRenderer, 7 logs + 3 obstacles)\n"
            "Target: under 0.1 s at 128 px.\n\n" + "\n".join(rows))


SECTIONS = {
    "piles": bench_piles,
    "render": bench_render,
}
OPTIONAL = {  # module in bench/ -> function returning Markdown; skipped if the module is absent
    "stereo": ("bench_stereo", "markdown"),
    "trials": ("bench_trials", "markdown"),
    "planner": ("bench_planner", "markdown"),
    "reconstruct": ("bench_reconstruct", "markdown"),
    "link": ("bench_link", "markdown"),
    "unposed": ("bench_unposed", "markdown"),
    "twin robustness": ("bench_twin_robustness", "markdown_section"),
}


def section_markdown(name: str) -> str:
    if name in SECTIONS:
        return SECTIONS[name]()
    mod_name, fn = OPTIONAL[name]
    try:
        return getattr(importlib.import_module(mod_name), fn)()
    except (ImportError, AttributeError) as exc:
        return f"### {name}\n_not measured: {exc}_"


def run_sections(names: list[str], only: bool, out: str, history: Path, measures: dict) -> dict:
    """Run ``names``; append them to ``history``; ``measures`` with the figures they gave."""
    start = dt.datetime.now(dt.timezone.utc)
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    command = f".venv/bin/python bench/run.py --out {out}" + (f" --only {' '.join(names)}" if only else "")
    title = f"loggrasp benchmarks, {start:%Y-%m-%d %H:%M} UTC"
    run = Run(date=f"{start:%Y-%m-%d %H:%M}", machine=machine_short(), load=f"{os.getloadavg()[0]:.1f}",
              command="make bench" if not only else command, commit=rev, details=title)
    run_lines = [f"Machine: {machine()}", f"Date: {start:%Y-%m-%d %H:%M} UTC, commit {rev}",
                 f"Command: `make bench` (= `{command}`)" if not only else f"Command: `{command}`"]
    parts, new = [], []
    for name in names:
        t0 = time.perf_counter()
        md = section_markdown(name)
        print(md, "\n", flush=True)
        parts.append(md + f"\n\n_section time {time.perf_counter() - t0:.0f} s_")
        try:
            new += measures_of_section(name, md, run)
        except BenchPageError as exc:
            print(f"warning: {exc}; its measures keep the figures of their last run", file=sys.stderr)
    append_history(history, history_entry(title, run_lines, parts))
    return updated(measures, new)


def main() -> None:
    ap = argparse.ArgumentParser(description="Measure loggrasp's speed targets; write docs/benchmarks.md.")
    ap.add_argument("--out", default="docs/benchmarks.md",
                    help="the page (default docs/benchmarks.md); its runs go to NAME-history.md beside it")
    ap.add_argument("--results", default="docs/results/benchmarks.json",
                    help="the current figure of every measure (read, updated, written)")
    ap.add_argument("--only", nargs="+", default=None, choices=[*SECTIONS, *OPTIONAL], help="run only these sections")
    ap.add_argument("--page-only", action="store_true", help="run nothing: write the page from --results")
    args = ap.parse_args()
    out, results = ROOT / args.out, ROOT / args.results
    try:
        measures = read_measures(results)
    except BenchPageError as exc:
        sys.exit(f"error: {exc}")
    if not args.page_only:
        measures = run_sections(args.only or [*SECTIONS, *OPTIONAL], bool(args.only), args.out,
                                out.with_name(out.stem + "-history.md"), measures)
        write_measures(results, measures)
    write_page(out, measures)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
