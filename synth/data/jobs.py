"""The ``synth piles`` job: many piles, each in its own folder, resumable and parallel.

Layout of the output folder::

    OUT/job.json              the job's parameters (a resumed job must use the same ones)
    OUT/pile_00000/pile.json  the settled pile
    OUT/pile_00000/ortho.npz  orthographic renders (intensity, depth, instance)
    OUT/pile_00000/preview.png
    OUT/pile_00000/stereo/    with ``stereo=True``: stereo pair + calibration

Each pile is built in a temporary sibling folder and renamed into place when complete, so a
killed job never leaves a half-written pile; re-running skips finished piles.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from synth.common.files import atomic_write_bytes, make_writable_dir
from synth.common.runner import run_tasks
from synth.errors import OutputError

JOB_FORMAT_VERSION = "1.0"


@dataclass(frozen=True)
class PileJob:
    count: int  # number of piles [-]
    logs: tuple[int, int] = (4, 4)  # inclusive range of logs per pile [-]
    obstacles: tuple[int, int] = (0, 0)  # inclusive range of obstacles per pile [-]
    seed: int = 0
    packed: bool = False
    size_px: int = 128  # orthographic render size [px]
    n_renders: int = 3  # renders per pile [-]
    stereo: bool = False  # also write a stereo pair + calibration

    def __post_init__(self) -> None:
        if not 1 <= self.count <= 1_000_000:
            raise ValueError(f"--count must be between 1 and 1,000,000, got {self.count}")
        for name, (lo, hi), top in (("--logs", self.logs, 16), ("--obstacles", self.obstacles, 12)):
            if not (0 <= lo <= hi <= top):
                raise ValueError(f"{name} must be a range A-B with 0 <= A <= B <= {top}, got {lo}-{hi}")
        if self.logs[0] < 1:
            raise ValueError("--logs must start at 1 or more")
        if not 16 <= self.size_px <= 2048 or self.size_px % 16:
            raise ValueError(f"--size must be a multiple of 16 in [16, 2048] px, got {self.size_px}")
        if not 1 <= self.n_renders <= 64:
            raise ValueError(f"--renders must be in [1, 64], got {self.n_renders}")

    def pile_params(self, k: int) -> tuple[int, int, int]:
        """(seed, n_logs, n_obstacles) of pile ``k`` — a pure function of (job seed, k)."""
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, k, 0x9113]))
        pile_seed = int(rng.integers(0, 2**31 - 1))
        return (pile_seed, int(rng.integers(self.logs[0], self.logs[1] + 1)),
                int(rng.integers(self.obstacles[0], self.obstacles[1] + 1)))


def pile_dir_name(k: int) -> str:
    return f"pile_{k:05d}"


def build_one(out: str, job: PileJob, k: int) -> dict:
    """Generate, render and write pile ``k`` (into a temp folder, renamed when complete)."""
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.render.preview import preview_image, write_png
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.scene.pile import write_pile
    from synth.physics.world import World

    out_dir = Path(out)
    final = out_dir / pile_dir_name(k)
    if final.exists():
        return {"k": k, "skipped": True}
    tmp = out_dir / f".{pile_dir_name(k)}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        seed, n_logs, n_obst = job.pile_params(k)
        pile, report = generate_pile(seed, GenerationConfig(n_logs=n_logs, n_obstacles=n_obst, packed=job.packed))
        write_pile(pile, tmp / "pile.json")
        with World(pile) as world:
            obs = render_ortho(world, OrthoRenderConfig(size_px=job.size_px, n_renders=job.n_renders), seed=seed)
            obs.meta.update({"pile_seed": seed})
            obs.save(tmp / "ortho.npz")
            if job.stereo:
                from synth.render.stereo import StereoRigConfig, render_stereo

                render_stereo(world, StereoRigConfig()).save(tmp / "stereo")
        write_png(tmp / "preview.png", preview_image(obs))
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)  # never a half-made pile folder left behind
        raise
    return {"k": k, "skipped": False, "attempts": report.attempts, "settle_s": report.settle_time_s}


def _check_out_dir(out: Path, job: PileJob) -> None:
    try:
        make_writable_dir(out)
    except OSError as exc:
        raise OutputError(f"cannot write to output folder {out}: {exc.strerror or exc}; choose another --out") from exc
    meta = out / "job.json"
    want = {"format": "loggrasp.piles", "format_version": JOB_FORMAT_VERSION, **asdict(job)}
    want["logs"], want["obstacles"] = list(job.logs), list(job.obstacles)
    finished = any(out.glob("pile_[0-9]*"))
    if meta.exists() and finished:  # a job file without any finished pile binds nothing
        try:
            have = json.loads(meta.read_text())
        except ValueError as exc:
            raise OutputError(f"{meta} is corrupt ({exc}); delete it or choose a new --out") from exc
        keys = [k for k in want if k != "count"]
        diff = [k for k in keys if have.get(k) != want[k]]
        if diff:
            raise OutputError(
                f"{out} holds a job with other parameters ({', '.join(diff)} differ); "
                "resume with the same parameters or choose a new --out"
            )
    atomic_write_bytes(meta, json.dumps(want, indent=1).encode())
    for stale in out.glob(".pile_*.tmp-*"):
        shutil.rmtree(stale, ignore_errors=True)


def run_pile_job(out: str | Path, job: PileJob, workers: int = 0,
                 progress: Callable[[int, int], None] | None = None) -> dict:
    """Generate ``job.count`` piles under ``out``; resumable; parallel over ``workers`` processes
    (0 = all cores). ``progress(done, total)`` is called after each pile."""
    out = Path(out)
    _check_out_dir(out, job)
    todo = [k for k in range(job.count) if not (out / pile_dir_name(k)).exists()]
    done = job.count - len(todo)
    if progress:
        progress(done, job.count)
    stats = {"generated": 0, "skipped": done, "attempts": 0}

    def finished(k: int, r: dict) -> None:
        nonlocal done
        stats["generated"] += 1
        stats["attempts"] += r.get("attempts", 0)
        done += 1
        if progress:
            progress(done, job.count)

    run_tasks(build_one, {k: (str(out), job, k) for k in todo}, finished, workers=workers)
    return stats
