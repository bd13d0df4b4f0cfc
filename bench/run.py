"""`make bench`: measure loggrasp's speed targets and write docs/benchmarks.md.

Each section is a function returning Markdown; sections whose code is not there yet are skipped
with a note. Run: .venv/bin/python bench/run.py --out docs/benchmarks.md [--only NAME]
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def machine() -> str:
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = "/".join(f"{v:.1f}" for v in os.getloadavg())
    return (f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores ({cpu}), Python "
            f"{platform.python_version()}; load average at start {load} (1/5/15 min — other jobs inflate wall times)")


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
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="docs/benchmarks.md")
    ap.add_argument("--only", nargs="*", default=None)
    args = ap.parse_args()
    parts = []
    names = args.only or [*SECTIONS, *OPTIONAL]
    for name in names:
        t0 = time.perf_counter()
        if name in SECTIONS:
            md = SECTIONS[name]()
        else:
            mod_name, fn = OPTIONAL[name]
            try:
                mod = importlib.import_module(mod_name)
                md = getattr(mod, fn)()
            except (ImportError, AttributeError) as exc:
                md = f"### {name}\n_not measured: {exc}_"
        print(md, "\n", flush=True)
        parts.append(md + f"\n\n_section time {time.perf_counter() - t0:.0f} s_")
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    head = (f"# loggrasp benchmarks\n\nMachine: {machine()}  \nDate: {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC, "
            f"commit {rev}  \nCommand: `make bench` (= `.venv/bin/python bench/run.py --out {args.out}`"
            f"{' --only ' + ' '.join(args.only) if args.only else ''})\n\n")
    out = ROOT / args.out
    if args.only and out.exists():
        # keep other sections: append a dated block for the partial run
        text = out.read_text() + "\n\n---\n\n" + head + "\n\n".join(parts) + "\n"
    else:
        text = head + "\n\n".join(parts) + "\n"
    from synth.common.files import atomic_write_bytes

    atomic_write_bytes(out, text.encode())
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
