"""Does the frame the planner sees a pile in matter? The real test's piles planned in frames turned
so the logs lie at a chosen angle, truth and reconstruction alike, executed on the truth.

Why: the truth is rendered in its generation frame, the reconstruction in the site's axes (or in a
frame of its own logs, ``ReconstructConfig.log_direction_deg``); the U-Net is not rotation
equivariant, so the two plans differ by the frames as well as by the reconstruction. Here both
piles are turned (:func:`real_test_views.moved`, terrain resampled) so their logs' mean direction
(:func:`reconstruct.config.logs_direction`) lies at ``--direction`` degrees, centred on the logs,
planned with one view, and both grasps executed on the true pile. Scans and reconstructions come
from a real-test work folder (``bench_reconstruct.py --work-dir``); reconstructions on a larger
patch than 5 m are left out (their terrain patch would need another pitch).

    .venv/bin/python bench/real_test_frames.py --work-dir runs/rt-work --min-logs 5 --direction 45 \\
        --out runs/real_test_frames_45.json

(2 cores, 2 workers: ~3 s per pile for f1 and f3.)
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


from real_test_views import WORKER, init_worker, kept_seeds, moved


def T_turned_pile(pile, direction_deg: float) -> np.ndarray:
    """``T_turned_pile``: a turn about z and a shift putting the logs' mean direction at
    ``direction_deg`` and the centre of their end points' bounding box at the origin."""
    from reconstruct.config import logs_direction
    from synth.geometry.frames import make_T, rot_z

    ends = {i: lg.endpoints_m() for i, lg in enumerate(pile.logs)}
    R = rot_z(math.radians(direction_deg) - logs_direction(ends))
    pts = np.array([p for e in ends.values() for p in e]) @ R.T
    centre = 0.5 * (pts.min(0) + pts.max(0))
    return make_T(R, -np.array([centre[0], centre[1], 0.0]))


def turned(pile, direction_deg: float):
    """``pile`` in the turned frame, its georeference following (so grasps map back through it)."""
    T = T_turned_pile(pile, direction_deg)
    T_site_turned = np.asarray(pile.georef.T_site_pile, dtype=float) @ np.linalg.inv(T)
    return replace(moved(pile, T), georef=replace(pile.georef, T_site_pile=tuple(tuple(float(v) for v in r)
                                                                                    for r in T_site_turned)))


def _pile(seed: int, work_dir: str, objectives: tuple[str, ...], direction_deg: float) -> list[dict]:
    from experiments.real_test import execute_on_truth, render_truth, grasp_to_truth_frame
    from planner.inference import Objective, plan
    from reconstruct.compare import compare_piles
    from synth.scene.pile import read_pile

    work = Path(work_dir)
    if not (work / f"recon_{seed}" / "report.json").exists():
        return []
    truth = read_pile(work / f"scan_{seed}" / "truth" / "pile.json")
    recon = read_pile(work / f"recon_{seed}" / "pile.json")
    if abs(recon.terrain.extent_m - truth.terrain.extent_m) > 1e-6:
        return []
    match = {e["recon_index"]: e["truth_index"] for e in compare_piles(truth, recon, render=False)["logs"]}
    t_turned, r_turned = turned(truth, direction_deg), turned(recon, direction_deg)
    size = WORKER["planner"].config.size_px
    obs_t, obs_r = render_truth(t_turned, size), render_truth(r_turned, size)
    rows = []
    for kind in objectives:
        best_t = plan(obs_t, WORKER["planner"], Objective(kind=kind), top_k=1, pile=t_turned).best
        best_r = plan(obs_r, WORKER["planner"], Objective(kind=kind), top_k=1, pile=r_turned).best
        targets_r = [match.get(i) for i in best_r.targets]
        back_t = grasp_to_truth_frame(best_t.grasp, t_turned, truth)
        ok_t = execute_on_truth(truth, back_t, tuple(best_t.targets))["success"]
        ok_r = (None not in targets_r
                and execute_on_truth(truth, grasp_to_truth_frame(best_r.grasp, r_turned, truth),
                                     tuple(targets_r))["success"])
        rows.append({"seed": seed, "n_logs": truth.n_logs, "objective": kind,
                     "truth": {"success": bool(ok_t)}, "recon": {"success": bool(ok_r)}})
    return rows


def main() -> None:
    from experiments.real_test import RealTestConfig, model_path, summarize
    from synth.common.files import atomic_write_bytes

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work-dir", type=Path, required=True, help="a real-test work folder (scans kept)")
    ap.add_argument("--min-logs", type=int, default=1)
    ap.add_argument("--max-logs", type=int, default=1000)
    ap.add_argument("--direction", type=float, default=45.0, help="the logs' mean direction in the turned frames [deg]")
    ap.add_argument("--objectives", default="f1,f3")
    ap.add_argument("--piles", type=int, default=None, help="only the first N kept piles")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, required=True, help="JSON record (written atomically after each pile)")
    args = ap.parse_args()
    seeds = kept_seeds(args.work_dir, args.min_logs, args.max_logs)[: args.piles]
    objectives = tuple(args.objectives.split(","))
    rec = {"work_dir": str(args.work_dir), "direction_deg": args.direction, "seeds": seeds, "rows": []}
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn"), initializer=init_worker,
                             initargs=(str(model_path(RealTestConfig())), 1, 0.0)) as pool:
        futures = [pool.submit(_pile, s, str(args.work_dir), objectives, args.direction) for s in seeds]
        for n, fut in enumerate(as_completed(futures), 1):
            rec["rows"] += fut.result()
            atomic_write_bytes(args.out, json.dumps(rec).encode())
            if n % 20 == 0 or n == len(futures):
                print(f"{n}/{len(futures)} piles, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    for kind in objectives:
        s = summarize([r for r in rec["rows"] if r["objective"] == kind])
        lo, hi = s["difference_ci95_pp"]
        print(f"{kind}: {s['n_piles']} piles, truth-planned {100 * s['success_truth']:.1f} %, recon-planned "
              f"{100 * s['success_recon']:.1f} %, difference {s['difference_pp']:+.1f} ± {s['difference_se_pp']:.1f} pp "
              f"[{lo:+.1f}, {hi:+.1f}]")


if __name__ == "__main__":
    main()
