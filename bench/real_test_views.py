"""The real test again on kept scans, with other planner settings: does averaging test-time views
(and a lower confidence bound on U over them) close the f3 gap on big piles?

Why: the real test (``bench/bench_reconstruct.py --real-only``) found reconstruction-planned f3
grasps 5.8 points less successful than truth-planned ones, the gap growing with the pile (-14 pp on
6 logs). Planning on hybrids of the truth in its own frame (:func:`_decompose_pile`: the reconstruction's
logs and terrain, its colours, its obstacles, or the truth turned into the reconstruction's frame)
costs a few points each, and none explains the whole gap: f3 picks the best of up to 63 subsets
from a network whose U is noisy, and the more the input departs from the one the grasp will meet,
the more the winner is one whose U was over-estimated (a winner's curse). Averaging 8 dihedral
views lowers the noise; lowering U by its spread over the views prefers grasps the views agree on.

Scans and reconstructions come from a real-test work folder (``bench_reconstruct.py --work-dir``;
:func:`experiments.real_test.real_test_pile` reuses them), so a variant costs only planning and trials.
Run (2 cores, 2 workers: 178 piles of 5–6 logs took 65 min for f1 and f3 with 8 views, on a loaded CPU):

    .venv/bin/python bench/bench_reconstruct.py --real-only --real-piles 500 --work-dir runs/rt-work
    .venv/bin/python bench/real_test_views.py --work-dir runs/rt-work --min-logs 5 \\
        --variants 1:0,8:2 --objectives f1,f3 --out runs/real_test_views.json
    .venv/bin/python bench/real_test_views.py --work-dir runs/rt-work --min-logs 5 --decompose \\
        --out runs/real_test_decompose.json
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import replace
from pathlib import Path

import numpy as np


WORKER: dict = {}


def kept_seeds(work_dir: Path, min_logs: int = 1, max_logs: int = 1000) -> list[int]:
    """Seeds whose scan (and reconstruction or its error) the work folder keeps, with
    ``min_logs``..``max_logs`` logs."""
    from synth.scene.pile import read_pile

    seeds = []
    for key in sorted(work_dir.glob("scan_*.key.json")):
        seed = int(key.name.split("_")[1].split(".")[0])
        if min_logs <= read_pile(work_dir / f"scan_{seed}" / "truth" / "pile.json").n_logs <= max_logs:
            seeds.append(seed)
    return seeds


def init_worker(model: str, views: int, k: float) -> None:
    import torch

    from planner.inference import load_planner
    from synth.common.processes import exit_with_parent

    exit_with_parent()
    torch.set_num_threads(1)
    WORKER["planner"] = load_planner(model, device="cpu", views=views, view_spread_k=k)


def _pile(seed: int, work_dir: str, cfg) -> list[dict]:
    from experiments.real_test import real_test_pile

    return real_test_pile(seed, work_dir, WORKER["planner"], cfg)


# -- hybrids --------------------------------------------------------------------------------------
def moved(pile, T_new_old: np.ndarray):
    """``pile`` expressed in another frame (``T_new_old``: a turn about z and a shift); the
    terrain is resampled on the new frame's grid (bilinear), outside the old patch clamped."""
    from synth.scene.pile import LogSpec, quat_multiply

    T = np.asarray(T_new_old, dtype=float)
    yaw = math.atan2(T[1, 0], T[0, 0])
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))

    def f(p):
        return np.asarray(p, dtype=float) @ T[:3, :3].T + T[:3, 3]

    logs = []
    for lg in pile.logs:
        b, t = f(np.stack(lg.endpoints_m()))
        logs.append(LogSpec.from_endpoints(b, t, lg.diameter_m, lg.top_diameter_m, lg.colour))
    n, e = pile.terrain.resolution, pile.terrain.extent_m
    xs = np.linspace(-e / 2, e / 2, n)
    X, Y = np.meshgrid(xs, xs)  # [iy, ix]: rows along +y
    Ti = np.linalg.inv(T)
    P = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1) @ Ti[:3, :3].T + Ti[:3, 3]
    z = pile.terrain.height_at(P[:, 0], P[:, 1])
    heights = f(np.stack([P[:, 0], P[:, 1], z], 1))[:, 2].reshape(n, n)
    terrain = replace(pile.terrain, heights_m=tuple(tuple(float(v) for v in row) for row in heights))
    stumps = tuple(replace(s, position_m=tuple(float(v) for v in f([*s.position_m, 0.0])[:2]),
                           roots=tuple(replace(r, azimuth_rad=r.azimuth_rad + yaw) for r in s.roots))
                   for s in pile.stumps)
    rocks = tuple(replace(r, position_m=tuple(float(v) for v in f(r.position_m)),
                          orientation=quat_multiply(q, r.orientation))
                  for r in pile.rocks)
    return replace(pile, logs=tuple(logs), terrain=terrain, stumps=stumps, rocks=rocks)


def _decompose_pile(seed: int, work_dir: str) -> dict | None:
    """f3 planned on the truth, on hybrids and on the reconstruction; all executed on the truth."""
    from experiments.real_test import execute_on_truth, render_truth, grasp_to_truth_frame
    from planner.inference import Objective, plan
    from reconstruct.compare import T_truth_recon, compare_piles
    from synth.scene.pile import LogSpec, read_pile
    from synth.render.ortho import OrthoObservation

    work = Path(work_dir)
    if not (work / f"recon_{seed}" / "report.json").exists():
        return None
    truth = read_pile(work / f"scan_{seed}" / "truth" / "pile.json")
    recon = read_pile(work / f"recon_{seed}" / "pile.json")
    match = {e["recon_index"]: e["truth_index"] for e in compare_piles(truth, recon, render=False)["logs"]}
    T, _ = T_truth_recon(truth, recon)
    if T is None or len(match) != truth.n_logs or recon.n_logs != truth.n_logs:
        return None
    in_truth = moved(recon, T)  # the reconstruction in the truth's frame
    logs = list(truth.logs)
    for ri, ti in match.items():
        lg = in_truth.logs[ri]
        logs[ti] = LogSpec.from_endpoints(*lg.endpoints_m(), lg.diameter_m, lg.top_diameter_m, truth.logs[ti].colour)
    geometry = replace(truth, logs=tuple(logs), terrain=in_truth.terrain)
    recoloured = replace(geometry, logs=tuple(replace(geometry.logs[ti], colour=recon.logs[ri].colour)
                                              for ri, ti in sorted(match.items(), key=lambda kv: kv[1])))
    turned = replace(moved(truth, np.linalg.inv(T)), georef=recon.georef)
    variants = {
        "truth": (truth, None),
        "recon logs + terrain": (geometry, None),
        "... + recon colours": (recoloured, None),
        "... + recon obstacles": (replace(geometry, stumps=in_truth.stumps, rocks=in_truth.rocks), None),
        "truth in the recon frame": (turned, turned),
        "reconstruction": (None, recon),
    }
    row = {"seed": seed, "n_logs": truth.n_logs}
    for name, (pile, frame) in variants.items():
        obs = (OrthoObservation.load(work / f"recon_{seed}" / "ortho.npz") if pile is None
               else render_truth(pile, WORKER["planner"].config.size_px))
        best = plan(obs, WORKER["planner"], Objective(kind="f3"), top_k=1, pile=truth).best
        grasp, targets = best.grasp, tuple(best.targets)
        if frame is not None:
            grasp = grasp_to_truth_frame(grasp, frame, truth)
        if pile is None:
            targets = tuple(match.get(i, -1) for i in targets)
        row[name] = bool(-1 not in targets and execute_on_truth(truth, grasp, targets)["success"])
    return row


# -- runs -------------------------------------------------------------------------------------------
def run(work_dir: Path, seeds: list[int], views: int, k: float, objectives: tuple[str, ...], workers: int,
        decompose: bool = False, save=None, log_direction_deg: float | None = 45.0) -> list[dict]:
    """Rows of every pile; ``save(rows)`` is called after each pile (an interrupted run keeps them).
    ``log_direction_deg``: the reconstructions' pile frame (kept ones made otherwise are made again)."""
    from experiments.real_test import RealTestConfig, model_path

    cfg = RealTestConfig(objectives=objectives, views=views, view_spread_k=k, log_direction_deg=log_direction_deg)
    rows: list[dict] = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=init_worker,
                             initargs=(str(model_path(cfg)), views, k)) as pool:
        futures = [pool.submit(_decompose_pile, s, str(work_dir)) if decompose else
                   pool.submit(_pile, s, str(work_dir), cfg) for s in seeds]
        for n, fut in enumerate(as_completed(futures), 1):
            r = fut.result()
            if r:
                rows += [r] if decompose else r
                if save is not None:
                    save(rows)
            if n % 20 == 0 or n == len(futures):
                print(f"{n}/{len(futures)} piles, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    return rows


def markdown(rec: dict) -> list[str]:
    from experiments.real_test import summarize

    lines = []
    if rec.get("decompose"):
        rows = rec["rows"]
        names = [k for k in rows[0] if k not in ("seed", "n_logs")]
        lines += [f"f3 on {len(rows)} piles with >= {rec['min_logs']} logs (all logs matched), planned on each "
                  "input, executed on the truth:", "", "| planned on | success | vs truth [pp] |", "|---|---|---|"]
        t = np.array([r["truth"] for r in rows], dtype=float)
        for name in names:
            s = np.array([r[name] for r in rows], dtype=float)
            b, c = float(((t == 1) & (s == 0)).sum()) + 0.5, float(((t == 0) & (s == 1)).sum()) + 0.5
            se = math.sqrt(max(b + c - (c - b) ** 2 / len(rows), 0.0)) / len(rows)
            lines.append(f"| {name} | {100 * s.mean():.1f} % | {100 * (s.mean() - t.mean()):+.1f} ± {100 * se:.1f} |")
        return lines
    lines += ["| views | U less k x spread | objective | logs | piles | truth-planned | recon-planned | "
              "difference [pp] | 95 % interval [pp] |", "|---|---|---|---|---|---|---|---|---|"]
    for v in rec["variants"]:
        for kind in v["objectives"]:
            rows = [r for r in v["rows"] if r["objective"] == kind]
            for n in ["all"] + sorted({r["n_logs"] for r in rows}):
                s = summarize([r for r in rows if n == "all" or r["n_logs"] == n])
                if not s.get("n_piles"):
                    continue
                lo, hi = s["difference_ci95_pp"]
                lines.append(f"| {v['views']} | {v['k']:g} | {kind} | {n} | {s['n_piles']} | "
                             f"{100 * s['success_truth']:.1f} % | {100 * s['success_recon']:.1f} % | "
                             f"{s['difference_pp']:+.1f} ± {s['difference_se_pp']:.1f} | [{lo:+.1f}, {hi:+.1f}] |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work-dir", type=Path, required=True, help="a real-test work folder (scans kept)")
    ap.add_argument("--min-logs", type=int, default=1, help="only piles with at least this many logs")
    ap.add_argument("--max-logs", type=int, default=1000, help="only piles with at most this many logs")
    ap.add_argument("--seeds", default=None, help="only these seeds (comma-separated) of the kept ones")
    ap.add_argument("--variants", default="1:0,8:0,8:1", help="VIEWS:K,... (K: U less K x its spread over the views)")
    ap.add_argument("--objectives", default="f3")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--decompose", action="store_true", help="plan f3 on hybrids of truth and reconstruction")
    ap.add_argument("--log-direction", default="45",
                    help="reconstructed pile frames turned so the logs lie at this angle [deg], or 'site' for the "
                         "site's axes (default 45, ReconstructConfig's)")
    ap.add_argument("--out", type=Path, required=True, help="JSON record (written atomically)")
    args = ap.parse_args()
    from reconstruct.config import parse_log_direction

    try:
        log_direction = parse_log_direction(args.log_direction)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    from synth.common.files import atomic_write_bytes

    if not args.work_dir.is_dir():
        raise SystemExit(f"{args.work_dir} is not a folder; make one with bench_reconstruct.py --real-only --work-dir")
    seeds = kept_seeds(args.work_dir, args.min_logs, args.max_logs)
    if args.seeds:
        wanted = {int(s) for s in args.seeds.split(",")}
        if wanted - set(seeds):
            raise SystemExit(f"seeds {sorted(wanted - set(seeds))} are not kept in {args.work_dir} with "
                             f"{args.min_logs}..{args.max_logs} logs")
        seeds = [s for s in seeds if s in wanted]
    if not seeds:
        raise SystemExit(f"{args.work_dir} keeps no scans with {args.min_logs}..{args.max_logs} logs")
    rec: dict = {"work_dir": str(args.work_dir), "min_logs": args.min_logs, "max_logs": args.max_logs, "seeds": seeds,
                 "log_direction_deg": log_direction}
    def write() -> None:
        atomic_write_bytes(args.out, json.dumps(rec, default=float).encode())

    if args.decompose:
        rec.update(decompose=True, rows=[])
        rec["rows"] = run(args.work_dir, seeds, 1, 0.0, ("f3",), args.workers, decompose=True,
                          save=lambda rows: (rec.update(rows=rows), write()))
    else:
        rec["variants"] = []
        for spec in args.variants.split(","):
            views, k = spec.split(":")
            v = {"views": int(views), "k": float(k), "objectives": tuple(args.objectives.split(",")), "rows": []}
            rec["variants"].append(v)
            v["rows"] = run(args.work_dir, seeds, v["views"], v["k"], v["objectives"], args.workers,
                            save=lambda rows, v=v: (v.update(rows=rows), write()), log_direction_deg=log_direction)
    write()
    print("\n".join(markdown(rec)))


if __name__ == "__main__":
    main()
