"""Reconstruction accuracy and speed on twin scans (``make bench`` section "reconstruct"; run
alone: ``.venv/bin/python bench/bench_reconstruct.py --piles 3``).

For each seed: a settled pile (:func:`synth.generate.generate_pile`, 5 logs, 2 obstacles), a
2x2 grid of ZED 2-like pairs 3 m above it (1280x720, 50 deg, 0.12 m baseline; one pair does not
cover a 5-log pile of 2.5 m logs), an RTK survey of the log end centres (1.5 cm horizontal,
2.5 cm vertical, 1 sigma), :func:`reconstruct.pipeline.reconstruct`, then
:func:`reconstruct.compare.compare_piles` against the truth. Also run with the scan pose
disturbed (5 cm and 1 deg about the pile centre), to show the registration refinement. Speed of a single-pair scan is
measured on a smaller pile of short logs that one pair covers. Wall times depend on other load
on the 2 cores: the load average is printed, and CPU seconds of this process are given beside.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _load() -> str:
    try:
        return "load average " + " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "load average ?"


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values, dtype=float), q)) if values else math.nan


def accuracy(n_piles: int = 3, workdir: Path | None = None) -> dict:
    from reconstruct.compare import compare_piles, simulate_scan
    from reconstruct.errors import ReconstructError
    from reconstruct.pipeline import ReconstructConfig, read_scan_pose, reconstruct
    from synth.frames import make_T, rot_z
    from synth.generate import GenerationConfig, generate_pile

    ep, dia, iou, walls, cpus, regs, failures = [], [], [], [], [], [], []
    det = tot = 0
    pose_err_rows = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for seed in range(n_piles):
            pile, _ = generate_pile(100 + seed, GenerationConfig(n_logs=5, n_obstacles=2))
            d = Path(tmp) / f"p{seed}"
            scan, gnss, truth = simulate_scan(pile, d, grid=(2, 2), seed=seed)
            for disturbed in (False, True):
                cfg = ReconstructConfig()
                if disturbed:
                    pose = read_scan_pose(scan)
                    # 4 cm / 3 cm and 1 deg about the scan's own origin (the pile centre)
                    c = pose.matrix()[:3, 3]
                    dist = make_T(t=c) @ make_T(rot_z(math.radians(1.0)), (0.04, -0.03, 0.0)) @ make_T(t=-c)
                    T = dist @ pose.matrix()
                    cfg = replace(cfg, scan_pose=replace(pose, T_site_scan=tuple(tuple(float(v) for v in r) for r in T)))
                t0, c0 = time.perf_counter(), time.process_time()
                try:
                    res = reconstruct(scan, gnss, d / ("out_d" if disturbed else "out"), cfg)
                except ReconstructError as exc:
                    failures.append(f"seed {100 + seed}{' (disturbed pose)' if disturbed else ''}: {exc}")
                    continue
                wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                c = compare_piles(truth, res.pile)
                reg = res.report["registration"]
                if disturbed:
                    pose_err_rows.append((100 + seed, reg["total_correction_m"], reg["total_correction_deg"],
                                          reg["residual_rms_before_m"], reg["residual_rms_after_m"],
                                          c["summary"]["endpoint_err_m"]["median"]))
                    continue
                walls.append(wall)
                cpus.append(cpu)
                regs.append(reg["residual_rms_after_m"])
                ep += [e["endpoint_err_m"] for e in c["logs"]]
                dia += [abs(e["diameter_err_m"]) for e in c["logs"]]
                iou += [e["mask_iou"] for e in c["logs"] if e["mask_iou"] is not None]
                det += c["summary"]["obstacles_detected"]
                tot += c["summary"]["n_truth_obstacles"]
    return {"ep": ep, "dia": dia, "iou": iou, "walls": walls, "cpus": cpus, "regs": regs, "det": det,
            "tot": tot, "pose": pose_err_rows, "failures": failures, "n": n_piles}


def single_pair_speed(repeats: int = 3, workdir: Path | None = None) -> dict:
    """Wall and CPU time of reconstruct() on one pair over a pile of 3 short logs."""
    from reconstruct.compare import simulate_scan
    from reconstruct.pipeline import reconstruct
    from synth.pile import LogSpec, PileSpec, TerrainSpec

    terrain = TerrainSpec(seed=7, extent_m=5.0, resolution=64, amplitude_m=0.05)
    g = terrain.height_grid()
    from synth.pile import height_at

    def ground_log(p0, p1, d):
        z0 = float(height_at(g, 5.0, p0[0], p0[1])) + d / 2 + 0.01
        z1 = float(height_at(g, 5.0, p1[0], p1[1])) + d / 2 + 0.01
        return LogSpec.from_endpoints((*p0, z0), (*p1, z1), d)

    pile = PileSpec(terrain=terrain, logs=(ground_log((-0.6, -0.45), (0.6, -0.45), 0.16),
                                           ground_log((-0.6, 0.0), (0.6, 0.05), 0.18),
                                           ground_log((-0.5, 0.45), (0.7, 0.4), 0.14)))
    walls, cpus, stages = [], [], []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        scan, gnss, _ = simulate_scan(pile, Path(tmp), seed=1)
        for k in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            res = reconstruct(scan, gnss, Path(tmp) / f"out{k}")
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            stages.append(res.report["timings_s"])
    return {"walls": walls, "cpus": cpus, "stages": stages[-1]}


def markdown(n_piles: int = 3, repeats: int = 3) -> str:
    load0 = _load()
    a = accuracy(n_piles)
    s = single_pair_speed(repeats)
    load1 = _load()
    lines = [
        "### Reconstruction (stereo scan + RTK ends -> PileSpec), twin scans",
        f"{a['n']} generated piles (5 logs, 2 obstacles each), 2x2 pairs at 3 m, RTK noise 1.5/2.5 cm. "
        f"Targets: diameter error <= 1 cm median, log mask IoU >= 0.9, < 10 s per single-pair scan. "
        f"{load0} before, {load1} after.\n",
        "| measure | median | p95 | max | n |", "|---|---|---|---|---|",
        f"| end point error [m] | {_pct(a['ep'], 50):.3f} | {_pct(a['ep'], 95):.3f} | {max(a['ep'], default=math.nan):.3f} | {len(a['ep'])} |",
        f"| abs mean-diameter error [m] | {_pct(a['dia'], 50):.4f} | {_pct(a['dia'], 95):.4f} | {max(a['dia'], default=math.nan):.4f} | {len(a['dia'])} |",
        f"| log mask IoU (128 px) | {_pct(a['iou'], 50):.3f} | p5 {_pct(a['iou'], 5):.3f} | min {min(a['iou'], default=math.nan):.3f} | {len(a['iou'])} |",
        f"| GNSS end -> fitted axis RMS after registration [m] | {_pct(a['regs'], 50):.3f} | | {max(a['regs'], default=math.nan):.3f} | {len(a['regs'])} |",
        f"| reconstruct() wall, 4 pairs [s] | {_pct(a['walls'], 50):.1f} | | {max(a['walls'], default=math.nan):.1f} | {len(a['walls'])} |",
        f"| reconstruct() CPU of this process, 4 pairs [s] | {_pct(a['cpus'], 50):.1f} | | {max(a['cpus'], default=math.nan):.1f} | {len(a['cpus'])} |",
        "",
        f"Obstacles detected: {a['det']} / {a['tot']}.",
    ]
    if a["pose"]:
        lines += ["", "Scan pose disturbed by (4, -3) cm and 1 deg (about the pile centre) before refinement:", "",
                  "| seed | total correction [m] | [deg] | residual RMS before [m] | after [m] | median end error [m] |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {r[0]} | {r[1]:.3f} | {r[2]:.2f} | {r[3]:.3f} | {r[4]:.3f} | {r[5]:.3f} |" for r in a["pose"]]
    if a["failures"]:
        lines += ["", "Failures:"] + [f"- {f}" for f in a["failures"]]
    st = s["stages"]
    lines += ["", f"Single pair (3 logs of 1.2 m), {len(s['walls'])} runs: wall median "
              f"{statistics.median(s['walls']):.1f} s (CPU {statistics.median(s['cpus']):.1f} s); last run's stages [s]: "
              + ", ".join(f"{k} {st[k]:.2f}" for k in ("survey_s", "stereo_s", "registration_s", "fit_s", "outputs_s")
                          if k in st)]
    return "\n".join(lines)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--piles", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(markdown(args.piles, args.repeats))
