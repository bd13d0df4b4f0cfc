"""A golden record of what loggrasp computes, to prove a refactor behaviour-preserving
(issue 19, "Behaviour preserved, measurably"):

    .venv/bin/python scripts/golden.py record /tmp/golden-base        # at the base commit
    .venv/bin/python scripts/golden.py compare /tmp/golden-base       # after: records anew, compares
    .venv/bin/python scripts/golden.py compare /tmp/golden-base OTHER # two records already made

``record DIR`` writes into DIR (which must not exist):

* ``trials.json``: :func:`synth.physics.trial.run_trial` on ~50 fixed (pile, grasp) pairs: from
  the first chunks of the committed grasp store (``--store``, default data/paper-v3), the first
  few stored trials of each outcome class, at most two from one pile, the first three also with
  ``careful``; on a hand-built one-log pile, a full trial with ``fast`` and ``careful``, a count
  target, a miss, ``on_phase`` callbacks and ``should_abort`` firing in each phase.
  Each record is ``TrialResult.to_dict()``.
* ``demo/``: ``loggrasp demo``'s ``plan.json``, and ``command.json``: the command's fields and
  the bytes the laptop puts on the link for it (E2E-protected frame with command id 1 and counter
  0: the link draws both at random, and its SecOC key is new each run).
* ``reconstruction/``: ``loggrasp reconstruct`` of the bundled demo scan: ``pile.json``,
  ``ortho.npz``.
* ``dataset/``: ``loggrasp synth dataset`` of 2 piles (64 px): manifest, pile specs, shards and
  their done records (shard names without the worker's process id).
* ``eval/``: ``loggrasp eval`` of 24 piles (2 and 3 logs, with and without obstacles, 6 each;
  the network planner, f3): one record file per pile.
* ``logs/``: what the commands printed (not compared).

Everything is in-process and fast (~3 minutes on 2 busy cores). ``compare DIR`` records into a
temporary folder, kept when it differs.

``compare`` compares every file: JSON value by value (floats bit by bit), npz array by array
(dtype, shape, bytes; a uint8 JSON header as JSON), anything else byte by byte. It ignores only
the fields in :data:`VOLATILE` (timings, the worker's process id, the sha256 of a zip whose member
dates are the writing time), says "bit-identical" or names each differing file and field, and
exits 1 on a difference.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import json
import math
import shutil
import struct
import sys
import tempfile
from fnmatch import fnmatch
from pathlib import Path

import numpy as np

from synth.data.datastore import chunk_path, open_store, read_chunk
from synth.physics.trial import TrialConfig, run_trial
from synth.physics.trial_spec import TRIAL_REVISION
from synth.geometry.grasp import Grasp
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, quat_from_x_axis

ROOT = Path(__file__).resolve().parents[1]
CHUNKS = range(4)  # first chunks of the store to draw from
PER_OUTCOME = 5  # stored trials per outcome class ...
PER_PILE = 2  # ... at most this many from one pile
CAREFUL_STORE_TRIALS = 3  # the first few store trials also run with TrialConfig.careful()
SHOWN_PER_FILE = 10  # differing fields named per file
COMMAND_ID = 1  # the demo's frame is encoded with this id (the link draws a random one per command)

#: fields compare ignores: (file pattern, key) -> why
VOLATILE = {
    ("*", "elapsed_s"): "wall time", ("*", "wall_time_s"): "wall time", ("*", "cpu_time_s"): "CPU time",
    ("*", "wall_s"): "wall time", ("*", "trial_wall_s"): "wall time",
    ("eval/*", "plan_s"): "wall time", ("eval/*", "trial_s"): "wall time",
    ("dataset/*", "sha256"): "of a shard's zip, which holds its writing time",
    ("dataset/*", "worker"): "the worker's process id", ("dataset/*", "file"): "a shard's name holds the worker",
    ("dataset/*", "bytes"): "a shard's size: its header holds the worker",
    **{("dataset/manifest.json", k): "worker time" for k in ("worker_s", "trial_worker_s", "worker_s_per_pile",
                                                               "trials_per_worker_s")},
}


# -- trials -----------------------------------------------------------------------------------------
def comparable(result, **extra) -> dict:
    return result.to_dict() | extra


def store_cases(store_dir: str) -> list[tuple[str, PileSpec, Grasp, tuple[int, ...], str]]:
    """(name, pile, grasp, targets, stored outcome) for the first PER_OUTCOME trials per class."""
    _, chunks, store = open_store(store_dir)
    taken: dict[str, int] = {}
    cases = []
    per_pile: dict[tuple[str, str], int] = {}
    for k in CHUNKS:
        if k not in chunks:
            continue
        rec = read_chunk(chunk_path(store_dir, k), store["params_sha256"])
        for p in rec["piles"]:
            pile = PileSpec.from_dict(p["pile"])
            for si, s in enumerate(p["subsets"]):
                for ti, t in enumerate(s["trials"]):
                    key = (p["pile_id"], t["o"])
                    if taken.get(t["o"], 0) >= PER_OUTCOME or per_pile.get(key, 0) >= PER_PILE:
                        continue
                    taken[t["o"]] = taken.get(t["o"], 0) + 1
                    per_pile[key] = per_pile.get(key, 0) + 1
                    cases.append((f"{p['pile_id']}/s{si}/t{ti}", pile, Grasp(*t["g"]), tuple(s["targets"]), t["o"]))
    return cases


def one_log_pile() -> PileSpec:
    heights = tuple(tuple(0.0 for _ in range(32)) for _ in range(32))
    log = LogSpec(centre_m=(0.0, 0.0, 0.41 * 0.16), orientation=quat_from_x_axis((0, 1, 0)), length_m=2.5,
                  diameter_m=0.16)
    return PileSpec(terrain=TerrainSpec(resolution=32, heights_m=heights), logs=(log,), rocks=())


def after(n_steps: int):
    """A should_abort that turns True at its n-th call (one call per simulation step)."""
    calls = itertools.count(1)
    return lambda: next(calls) >= n_steps


def hand_built_records() -> dict[str, dict]:
    pile, grasp = one_log_pile(), Grasp(0.0, 0.0, 0.0, 0.6)
    out: dict[str, dict] = {}
    for preset, cfg in (("fast", TrialConfig.fast()), ("careful", TrialConfig.careful())):
        full = run_trial(pile, grasp, [0], cfg)
        out[f"one_log/{preset}/full"] = comparable(full)
        dt = cfg.physics.dt_s
        steps = {ph: round(full.phase_s[ph] / dt) for ph in ("lower", "close", "lift", "hold")}
        start = 0
        for ph, n in steps.items():  # abort in the middle of each phase and on its last step
            for at in (start + max(1, n // 2), start + n):
                r = run_trial(pile, grasp, [0], cfg, should_abort=after(at))
                out[f"one_log/{preset}/abort_{ph}_at_{at}"] = comparable(r)
            start += n
    out["one_log/fast/count_target"] = comparable(run_trial(pile, grasp, 1, TrialConfig.fast()))
    out["one_log/fast/miss"] = comparable(run_trial(pile, Grasp(0.9, 0.0, 0.0, 0.6), [0], TrialConfig.fast()))
    phases: list[str] = []
    r = run_trial(pile, grasp, [0], TrialConfig.fast(), on_phase=lambda name, world, grapple: phases.append(name))
    out["one_log/fast/on_phase"] = comparable(r, on_phase_calls=phases)
    return out


def record_trials(store_dir: str, out: Path) -> str:
    job, _, _ = open_store(store_dir)
    cfg = job.trial_config()
    records: dict[str, dict] = {}
    cases = store_cases(store_dir)
    for name, pile, grasp, targets, stored in cases:
        records[name] = comparable(run_trial(pile, grasp, targets, cfg), stored_outcome=stored)
    for name, pile, grasp, targets, _ in cases[:CAREFUL_STORE_TRIALS]:
        records[f"{name}/careful"] = comparable(run_trial(pile, grasp, targets, TrialConfig.careful()))
    records |= hand_built_records()
    write_json(out / "trials.json", {"trial_revision": TRIAL_REVISION, "n": len(records), "records": records})
    agree = sum(r["outcome"] == r["stored_outcome"] for r in records.values() if "stored_outcome" in r)
    n_store = sum("stored_outcome" in r for r in records.values())
    return f"{len(records)} trials; store trials agreeing with the stored outcome {agree}/{n_store}"


# -- the commands -----------------------------------------------------------------------------------
def write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=1) + "\n")


def loggrasp(log: Path, *args) -> None:
    """``loggrasp ARGS`` in this process (its one error handler), its output into ``log``."""
    from field.cli import run

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = run([str(a) for a in args])
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text(out.getvalue())
    if code != 0:
        raise SystemExit(f"loggrasp {' '.join(map(str, args[:2]))} failed (exit {code}); see {log}")


def command_record(trial: Path) -> dict:
    """The demo's command: its fields and the frame the laptop sends for it (before SecOC)."""
    from field.link.codec import encode
    from field.link.messages import GraspCommand

    rec = json.loads((trial / "record.json").read_text())
    cmd = GraspCommand(command_id=COMMAND_ID, **rec["command"])
    kind, frame = encode(cmd, counter=0)
    verification = rec.get("verification") or {}
    return {"command_id": COMMAND_ID, "fields": rec["command"], "kind": kind, "frame_hex": frame.hex(),
            "chosen_rank": rec.get("chosen_rank"), "verified": rec.get("verified"),
            "verification_timed_out": verification.get("timed_out"), "outcome": rec.get("outcome")}


def record_demo(out: Path, work: Path) -> str:
    loggrasp(out / "logs" / "demo.txt", "demo", "--out", work / "demo", "--json")
    trial = work / "demo" / "trial"
    (out / "demo").mkdir(parents=True)
    shutil.copy(trial / "plan" / "plan.json", out / "demo" / "plan.json")
    cmd = command_record(trial)
    write_json(out / "demo" / "command.json", cmd)
    return f"demo: command {cmd['kind']} {cmd['frame_hex']}, plan rank {cmd['chosen_rank']}"


def record_reconstruction(out: Path, work: Path) -> str:
    from field.demo import DEMO_DATA

    loggrasp(out / "logs" / "reconstruct.txt", "reconstruct", DEMO_DATA / "scan", "--gnss", DEMO_DATA / "gnss.csv",
             "--out", work / "recon", "--json")
    (out / "reconstruction").mkdir(parents=True)
    for name in ("pile.json", "ortho.npz"):
        shutil.copy(work / "recon" / name, out / "reconstruction" / name)
    return "reconstruction: pile.json, ortho.npz"


def record_dataset(out: Path, work: Path) -> str:
    src = work / "dataset"
    loggrasp(out / "logs" / "dataset.txt", "synth", "dataset", "--piles", "2", "--logs", "2", "--size", "64",
             "--renders", "1", "--max-trials-per-subset", "2", "--workers", "1", "--out", src, "--json")
    dst = out / "dataset"
    shutil.copytree(src / "piles", dst / "piles")
    shutil.copy(src / "manifest.json", dst / "manifest.json")
    for f in sorted(src.glob("shard_*")):  # shard_<worker>_<chunk>...: the worker is a process id
        shutil.copy(f, dst / ("shard_" + f.name.split("_", 2)[2]))
    return f"dataset: {len(list(dst.glob('shard_*.npz')))} shards"


def record_eval(out: Path, work: Path) -> str:
    loggrasp(out / "logs" / "eval.txt", "eval", "--per-cell", "6", "--logs", "2-3", "--obstacles", "both",
             "--objectives", "f3", "--baselines", "", "--workers", "2", "--out", work / "eval")
    shutil.copytree(work / "eval" / "records", out / "eval" / "records")
    return f"eval: {len(list((out / 'eval' / 'records').glob('*.json')))} pile records"


def record(out: Path, store_dir: str) -> None:
    if out.exists():
        raise SystemExit(f"{out} exists; record into a new folder")
    out.mkdir(parents=True)
    with tempfile.TemporaryDirectory(prefix="golden-") as tmp:
        work = Path(tmp)
        print(record_trials(store_dir, out), flush=True)
        for step in (record_reconstruction, record_dataset, record_eval, record_demo):
            print(step(out, work), flush=True)
    print(f"golden record -> {out}")


# -- compare ----------------------------------------------------------------------------------------
def volatile(rel: str, key: str) -> bool:
    return any(k == key and fnmatch(rel, pat) for pat, k in VOLATILE)


def same_float(a: float, b: float) -> bool:
    return struct.pack("<d", a) == struct.pack("<d", b) or (math.isnan(a) and math.isnan(b))


def json_diffs(a, b, rel: str, where: str = ""):
    """The paths at which two parsed JSON values differ (floats bit by bit)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b), key=str):
            if volatile(rel, str(k)):
                continue
            if k not in a or k not in b:
                yield f"{where}.{k} only in {'the golden' if k in a else 'the new'} record"
            else:
                yield from json_diffs(a[k], b[k], rel, f"{where}.{k}")
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield f"{where}: {len(a)} items, now {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            yield from json_diffs(x, y, rel, f"{where}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        if not same_float(a, b):
            yield f"{where}: {a!r} -> {b!r}"
    elif type(a) is not type(b) or a != b:
        yield f"{where}: {a!r} -> {b!r}"


def npz_diffs(pa: Path, pb: Path, rel: str):
    with np.load(pa, allow_pickle=False) as za, np.load(pb, allow_pickle=False) as zb:
        for name in sorted(set(za.files) | set(zb.files)):
            if name not in za.files or name not in zb.files:
                yield f"array {name} only in {'the golden' if name in za.files else 'the new'} record"
                continue
            x, y = za[name], zb[name]
            if x.dtype == np.uint8 and y.dtype == np.uint8 and x.ndim == y.ndim == 1:
                try:
                    yield from json_diffs(json.loads(x.tobytes()), json.loads(y.tobytes()), rel, name)
                    continue
                except ValueError:
                    pass
            if x.dtype != y.dtype or x.shape != y.shape:
                yield f"array {name}: {x.dtype}{x.shape} -> {y.dtype}{y.shape}"
            elif x.tobytes() != y.tobytes():
                same = (x == y) | (np.isnan(x) & np.isnan(y)) if x.dtype.kind == "f" else x == y
                yield f"array {name}: {int(np.sum(~same))} of {x.size} values differ"


def file_diffs(pa: Path, pb: Path, rel: str):
    if pa.suffix == ".json":
        yield from json_diffs(json.loads(pa.read_text()), json.loads(pb.read_text()), rel)
    elif pa.suffix == ".npz":
        yield from npz_diffs(pa, pb, rel)
    elif pa.read_bytes() != pb.read_bytes():
        yield "bytes differ"


def compare(golden: Path, new: Path) -> int:
    def files(d: Path) -> set[str]:
        return {str(p.relative_to(d)) for p in d.rglob("*") if p.is_file() and p.relative_to(d).parts[0] != "logs"}

    fa, fb = files(golden), files(new)
    differing = 0
    for rel in sorted(fa ^ fb):
        print(f"{rel}: only in {'the golden' if rel in fa else 'the new'} record")
        differing += 1
    for rel in sorted(fa & fb):
        diffs = list(file_diffs(golden / rel, new / rel, rel))
        if diffs:
            differing += 1
            print(f"{rel}: {len(diffs)} differing field(s)")
            for d in diffs[:SHOWN_PER_FILE]:
                print(f"    {d}")
    if differing:
        print(f"{differing} of {len(fa | fb)} files differ ({golden} vs {new})")
        return 1
    print(f"bit-identical: {len(fa)} files ({golden} vs {new}; ignored only {len(VOLATILE)} volatile fields)")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="verb", required=True)
    rec = sub.add_parser("record", help="record into a new folder")
    rec.add_argument("dir", type=Path)
    cmp_ = sub.add_parser("compare", help="record anew (or take OTHER) and compare with DIR")
    cmp_.add_argument("dir", type=Path)
    cmp_.add_argument("other", type=Path, nargs="?")
    for p in (rec, cmp_):
        p.add_argument("--store", default=str(ROOT / "data" / "paper-v3"), help="the committed grasp store")
    args = ap.parse_args(argv)
    if args.verb == "record":
        record(args.dir, args.store)
        return 0
    if not args.dir.is_dir():
        raise SystemExit(f"{args.dir}: no golden record there (make one with `golden.py record DIR`)")
    if args.other is not None:
        if not args.other.is_dir():
            raise SystemExit(f"{args.other}: no record there")
        return compare(args.dir, args.other)
    new = Path(tempfile.mkdtemp(prefix="golden-new-")) / "new"
    record(new, args.store)
    code = compare(args.dir, new)
    if code == 0:
        shutil.rmtree(new.parent)
    else:
        print(f"the new record is kept in {new}")
    return code


if __name__ == "__main__":
    sys.exit(main())
