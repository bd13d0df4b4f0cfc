"""Reconstruction accuracy and speed on twin scans (``make bench`` section "reconstruct", through
``bench/bench_reconstruct.py``, which is also its command: ``.venv/bin/python bench/bench_reconstruct.py --piles 3``).

For each seed: a settled pile (:func:`synth.scene.generate.generate_pile`, 5 logs, 2 obstacles), a
2x2 grid of ZED 2-like pairs 3 m above it (1280x720, 50 deg, 0.12 m baseline; one pair does not
cover a 5-log pile of 2.5 m logs), an RTK survey of the log end centres (1.5 cm horizontal,
2.5 cm vertical, 1 sigma), :func:`reconstruct.pipeline.reconstruct`, then
:func:`reconstruct.compare.compare_piles` against the truth. Also run with the scan pose
disturbed (5 cm and 1 deg about the pile centre), to show the registration refinement. Speed of a single-pair scan is
measured on a smaller pile of short logs that one pair covers. Wall times depend on other load
on the 2 cores: the load average is printed, and CPU seconds of this process are given beside.

Obstacles: every true obstacle of those piles, of 6 more with 3 obstacles (seeds 103-108) and of 3
without (seeds 110-112, false positives) is classed by what the scan could show: its top-view
area above 8 cm (orthographic instance render of the truth, 2 cm pixels) that is not hidden by
logs and that the scan covers. Detection is counted over all obstacles and over those with at
least 0.01 m^2 so seen.

The real test (:mod:`experiments.real_test`): twin scans with 3-6 logs and 0-2 obstacles (seeds
700000+), reconstructed; the shipped planner (or ``--model``) plans on the reconstruction's
re-render and on the truth's render; both grasps are executed on the TRUE pile. Run alone:
``.venv/bin/python bench/bench_reconstruct.py --real-only --real-piles 24 --model PATH``.
"""

from __future__ import annotations

import math
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from experiments.measure import load_average, percentile


def accuracy(n_piles: int = 3, workdir: Path | None = None) -> dict:
    from reconstruct.compare import compare_piles, simulate_scan
    from reconstruct.errors import ReconstructError
    from reconstruct.config import ReconstructConfig
    from reconstruct.pipeline import reconstruct
    from reconstruct.registration import read_scan_pose
    from synth.geometry.frames import make_T, rot_z
    from synth.scene.generate import GenerationConfig, generate_pile

    ep, dia, iou, walls, cpus, regs, failures = [], [], [], [], [], [], []
    det = tot = 0
    obstacle_rows: list[dict] = []
    fps = 0
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
                obstacle_rows += obstacle_visibility(truth, res, c, 100 + seed)
                fps += c["summary"]["obstacle_false_positives"]
    return {"ep": ep, "dia": dia, "iou": iou, "walls": walls, "cpus": cpus, "regs": regs, "det": det,
            "tot": tot, "pose": pose_err_rows, "failures": failures, "n": n_piles,
            "obstacle_rows": obstacle_rows, "fps": fps}


def obstacle_visibility(truth, res, comparison: dict, seed: int, min_height_m: float = 0.08) -> list[dict]:
    """Per true obstacle: its top-view area above ``min_height_m`` not hidden by logs
    (orthographic instance render of the truth, 256 px), the part of it the scan covers (a scan
    point within 3 cm), and whether the reconstruction found it."""
    from scipy.spatial import cKDTree

    from synth.geometry.frames import OrthoGrid, apply_T, invert_T
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import OBSTACLE_BASE, World

    T_truth_scan = invert_T(truth.georef.matrix()) @ np.asarray(res.report["T_site_scan_refined"])
    pts = apply_T(T_truth_scan, res.cloud.points)
    tree = cKDTree(pts[:, :2])
    with World(truth) as world:
        obs = render_ortho(world, OrthoRenderConfig(size_px=256, n_renders=1))
    grid = OrthoGrid(256, truth.terrain.extent_m)
    X, Y = grid.pixel_centres()
    high = obs.height() - truth.terrain.height_at(X, Y) > min_height_m
    px_m2 = grid.pixel_m ** 2
    kinds = ["stump"] * len(truth.stumps) + ["rock"] * len(truth.rocks)
    rows = []
    for j, kind in enumerate(kinds):
        m = (obs.instance == OBSTACLE_BASE + j) & high
        if m.any():
            d, _ = tree.query(np.column_stack([X[m], Y[m]]))
            scanned = float((d < 0.03).sum()) * px_m2
        else:
            scanned = 0.0
        match = comparison["obstacles"][j]
        rows.append({"seed": seed, "kind": kind, "visible_m2": float(m.sum()) * px_m2, "seen_m2": scanned,
                     "detected": match["recon_index"] is not None, "recon_kind": match["recon_kind"]})
    return rows


def obstacle_piles(seeds=range(103, 109), n_obstacles: int = 3, clean_seeds=(110, 111, 112),
                   workdir: Path | None = None) -> dict:
    """More piles for obstacle detection: ``seeds`` with ``n_obstacles`` each, ``clean_seeds``
    without any (false positives). Same scans as :func:`accuracy`."""
    from reconstruct.compare import compare_piles, simulate_scan
    from reconstruct.errors import ReconstructError
    from reconstruct.pipeline import reconstruct
    from synth.scene.generate import GenerationConfig, generate_pile

    rows: list[dict] = []
    fps = {"with": 0, "without": 0}
    n = {"with": 0, "without": 0}
    failures = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for seed, k in [(s, n_obstacles) for s in seeds] + [(s, 0) for s in clean_seeds]:
            pile, _ = generate_pile(seed, GenerationConfig(n_logs=5, n_obstacles=k))
            d = Path(tmp) / f"o{seed}"
            scan, gnss, truth = simulate_scan(pile, d, grid=(2, 2), seed=seed - 100)
            try:
                res = reconstruct(scan, gnss, d / "out")
            except ReconstructError as exc:
                failures.append(f"seed {seed}: {exc}")
                continue
            c = compare_piles(truth, res.pile, render=False)
            key = "with" if k else "without"
            n[key] += 1
            fps[key] += c["summary"]["obstacle_false_positives"]
            rows += obstacle_visibility(truth, res, c, seed)
    return {"rows": rows, "fps": fps, "n": n, "failures": failures}


def real_test(cfg, out: Path | None = None, work_dir: Path | None = None) -> dict:
    """The real test (:func:`experiments.real_test.run_real_test` with ``cfg``, a
    :class:`experiments.real_test.RealTestConfig`); the record is kept in ``out`` when given (written
    after every pile; a run of the same test and model there is resumed); scans and reconstructions
    kept in ``work_dir`` when given (reused by later runs)."""
    from experiments.real_test import run_real_test

    return run_real_test(cfg, record_path=out,
                         work_dir=work_dir, progress=lambda s: print(s, file=sys.stderr, flush=True))


def real_test_markdown(rec: dict) -> list[str]:
    cfg = rec["config"]
    rows = rec["rows"]
    piles = sorted({r["seed"] for r in rows})
    cpu = [sum(r["cpu_s"].values()) + r["plan_cpu_s"] + r["trial_cpu_s"] for r in rows]
    lines = [
        "#### The real test: plan on the reconstruction, execute on the truth",
        f"{len(piles)} twin scans{'' if len(piles) == cfg['n_piles'] else ' (of ' + str(cfg['n_piles']) + ' asked for; the run was stopped)'} "
        f"(`loggrasp synth scan` piles, seeds {cfg['seed']}..{cfg['seed'] + cfg['n_piles'] - 1}, "
        f"{cfg['logs'][0]}-{cfg['logs'][1]} logs, {cfg['obstacles'][0]}-{cfg['obstacles'][1]} obstacles, "
        f"{cfg['grid'][0]}x{cfg['grid'][1]} pairs, "
        f"{'RTK fixed' if not cfg.get('n_float') else str(cfg['n_float']) + ' RTK float ends per survey, the rest fixed'}), "
        "reconstructed; model `{Path(rec['model']['path']).name}` "
        f"(sha256 {rec['model']['sha256'][:12]}, {cfg.get('views', 1)} view(s) averaged, U less "
        f"{cfg.get('view_spread_k', 0.0):g} x their spread; reconstructed pile frames "
        f"{'in site axes' if cfg.get('log_direction_deg') is None else 'turned so the logs lie at ' + format(cfg['log_direction_deg'], 'g') + ' deg'}) "
        "plans on the reconstruction's "
        "re-render and on the truth's render; "
        "the reconstruction's grasp is taken to the truth frame through both georeferences, its targets "
        "through the log matching; both grasps run on the TRUE pile (`TrialConfig.fast()`). "
        "Criterion (issue): the reconstruction-planned success rate within 3 percentage points of the "
        "truth-planned one. Uncertainties: binomial standard errors of the rates; for the difference, the "
        "standard error of the paired difference (discordant piles + 1/2 each).\n",
        "| objective | piles | success, truth-planned | success, recon-planned | difference [pp] | 95 % interval [pp] | "
        "same outcome | same targets | verdict |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for kind, s in rec["summary"].items():
        if not s.get("n_piles"):
            lines.append(f"| {kind} | 0 | | | | | | | no piles |")
            continue
        lo, hi = s["difference_ci95_pp"]
        lines.append(
            f"| {kind} | {s['n_piles']} | {100 * s['success_truth']:.1f} % ± {100 * s['success_truth_se']:.1f} | "
            f"{100 * s['success_recon']:.1f} % ± {100 * s['success_recon_se']:.1f} | {s['difference_pp']:+.1f} ± "
            f"{s['difference_se_pp']:.1f} | [{lo:+.1f}, {hi:+.1f}] | {100 * s['outcome_agreement']:.0f} % "
            f"({s['both_succeed']} both, {s['only_truth']} truth only, {s['only_recon']} recon only) | "
            f"{100 * s['same_targets']:.0f} % | {s['verdict']} |")
    lines += ["", "Grasp differences (recon-planned minus truth-planned, truth frame), all piles / piles where both chose the same target logs:", "",
              "| objective | position median [m] | p90 | angle median [deg] | p90 | abs width median [m] | p90 | same targets: position median [m] | angle median [deg] |",
              "|---|---|---|---|---|---|---|---|---|"]

    def f(v, fmt):
        return "–" if v is None else format(v, fmt)

    for kind, s in rec["summary"].items():
        if not s.get("n_piles"):
            continue
        lines.append(
            f"| {kind} | {f(s['position_diff_m']['median'], '.3f')} | {f(s['position_diff_m']['p90'], '.3f')} | "
            f"{f(s['angle_diff_deg']['median'], '.1f')} | {f(s['angle_diff_deg']['p90'], '.1f')} | "
            f"{f(s['abs_width_diff_m']['median'], '.3f')} | {f(s['abs_width_diff_m']['p90'], '.3f')} | "
            f"{f(s['position_diff_same_targets_m']['median'], '.3f')} | {f(s['angle_diff_same_targets_deg']['median'], '.1f')} |")
    rf = sum(r.get("recon_error") is not None for r in rows) // max(1, len(cfg["objectives"]))
    lines += ["", f"Reconstruction failures: {rf} of {len(piles)} piles (counted as failed grasps); piles the generator could "
              f"not make: {len(rec['failures'])}. CPU per pile and objective pair (scan + reconstruction + renders + plans + "
              f"trials, worker processes): median {statistics.median(cpu) if cpu else math.nan:.1f} s; "
              f"wall {rec['wall_s']:.0f} s with {cfg['workers']} worker(s)."]
    for fmsg in rec["failures"]:
        lines.append(f"- {fmsg}")
    return lines


def obstacle_markdown(a: dict, o: dict, min_seen_m2: float = 0.01) -> list[str]:
    rows = a["obstacle_rows"] + o["rows"]
    seen = [r for r in rows if r["seen_m2"] >= min_seen_m2]
    hidden = [r for r in rows if r["visible_m2"] < min_seen_m2]
    outside = [r for r in rows if r["visible_m2"] >= min_seen_m2 and r["seen_m2"] < min_seen_m2]
    n_with = a["n"] + o["n"]["with"]

    def rate(rs):
        return f"{sum(r['detected'] for r in rs)} / {len(rs)}"

    right = sum(r["detected"] and r["recon_kind"] == r["kind"] for r in rows)
    lines = [
        "", "Obstacles (seeds 100-102 above plus 103-108 with 3 obstacles each; stumps and rocks of the generator):", "",
        "| obstacles | detected |", "|---|---|",
        f"| all | {rate(rows)} |",
        f"| seen: >= {min_seen_m2} m^2 above 8 cm, not under logs, in the scan | {rate(seen)} |",
        f"| ... stumps | {rate([r for r in seen if r['kind'] == 'stump'])} |",
        f"| ... rocks | {rate([r for r in seen if r['kind'] == 'rock'])} |",
        f"| hidden under logs or lower than 8 cm | {rate(hidden)} |",
        f"| outside the scanned area | {rate(outside)} |",
        "",
        f"Kind right (stump/rock) for {right} of {sum(r['detected'] for r in rows)} detected. False positives: "
        f"{a['fps'] + o['fps']['with']} on {n_with} piles with obstacles, {o['fps']['without']} on "
        f"{o['n']['without']} piles without.",
    ]
    if o["failures"]:
        lines += ["Reconstruction failures:"] + [f"- {x}" for x in o["failures"]]
    return lines


def single_pair_speed(repeats: int = 3, workdir: Path | None = None) -> dict:
    """Wall and CPU time of reconstruct() on one pair over a pile of 3 short logs."""
    from reconstruct.compare import simulate_scan
    from reconstruct.pipeline import reconstruct
    from synth.scene.pile import LogSpec, PileSpec, TerrainSpec

    terrain = TerrainSpec(seed=7, extent_m=5.0, resolution=64, amplitude_m=0.05)
    g = terrain.height_grid()
    from synth.scene.pile import height_at

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


def markdown(n_piles: int = 3, repeats: int = 3, real_cfg=None, real_out: Path | None = None,
             work_dir: Path | None = None, real_piles: int = 24) -> str:
    """The section; the real test runs with ``real_cfg`` (a :class:`experiments.real_test.RealTestConfig`),
    or when it is None on ``real_piles`` scans with the defaults (0: skipped)."""
    from experiments.real_test import RealTestConfig

    if real_cfg is None and real_piles > 0:
        real_cfg = RealTestConfig(n_piles=real_piles, workers=2)
    load0 = load_average()
    a = accuracy(n_piles)
    o = obstacle_piles()
    s = single_pair_speed(repeats)
    rec = real_test(real_cfg, real_out, work_dir) if real_cfg is not None else None
    load1 = load_average()
    lines = [
        "### Reconstruction (stereo scan + RTK ends -> PileSpec), twin scans",
        f"{a['n']} generated piles (5 logs, 2 obstacles each), 2x2 pairs at 3 m, RTK noise 1.5/2.5 cm. "
        f"Targets: diameter error <= 1 cm median, log mask IoU >= 0.9, < 10 s per single-pair scan. "
        f"{load0} before, {load1} after.\n",
        "| measure | median | p95 | max | n |", "|---|---|---|---|---|",
        f"| end point error [m] | {percentile(a['ep'], 50):.3f} | {percentile(a['ep'], 95):.3f} | {max(a['ep'], default=math.nan):.3f} | {len(a['ep'])} |",
        f"| abs mean-diameter error [m] | {percentile(a['dia'], 50):.4f} | {percentile(a['dia'], 95):.4f} | {max(a['dia'], default=math.nan):.4f} | {len(a['dia'])} |",
        f"| log mask IoU (128 px) | {percentile(a['iou'], 50):.3f} | p5 {percentile(a['iou'], 5):.3f} | min {min(a['iou'], default=math.nan):.3f} | {len(a['iou'])} |",
        f"| GNSS end -> fitted axis RMS after registration [m] | {percentile(a['regs'], 50):.3f} | | {max(a['regs'], default=math.nan):.3f} | {len(a['regs'])} |",
        f"| reconstruct() wall, 4 pairs [s] | {percentile(a['walls'], 50):.1f} | | {max(a['walls'], default=math.nan):.1f} | {len(a['walls'])} |",
        f"| reconstruct() CPU of this process, 4 pairs [s] | {percentile(a['cpus'], 50):.1f} | | {max(a['cpus'], default=math.nan):.1f} | {len(a['cpus'])} |",
    ]
    lines += obstacle_markdown(a, o)
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
    if rec is not None:
        lines += [""] + real_test_markdown(rec)
    return "\n".join(lines)
