"""Reconstruction accuracy and speed on twin scans (``make bench`` section "reconstruct"; run
alone: ``.venv/bin/python bench/bench_reconstruct.py --piles 3``).

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

import argparse
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
    from reconstruct.pipeline import ReconstructConfig, reconstruct
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


# -- survey conditions: the same scans with the twin's default survey, an all-fixed one, a degraded one --
SURVEY_CONDITIONS = {
    "default": "the twin's default survey: 2 RTK float ends (sigma 25 cm h, 40 cm v), the rest fixed",
    "fixed": "every end RTK fixed (1.5 cm h, 2.5 cm v)",
    "degraded": "half the ends float and one log (one the scan shows well) not surveyed at all",
}
SURVEY_BENCH_FORMAT = "loggrasp.bench-survey-conditions"


def survey_bench(n_scans: int, seed0: int, work_dir: Path, out: Path, logs=(3, 7), obstacles=(0, 3),
                 progress=print, shard: tuple[int, int] = (0, 1)) -> dict:
    """Reconstruction under the three survey conditions (:data:`SURVEY_CONDITIONS`) on ``n_scans``
    fresh twin scans (``loggrasp synth scan`` piles, seeds ``seed0``...): the stereo cloud of each scan
    is matched once and reconstructed with each survey; every log is measured against the truth (worst
    end, mean diameter, mask IoU) and every end's source kept.

    ``out`` is a folder: one record per scan (``scans/<seed>.json``, written when the scan is done) and
    ``summary.json``. A run with the same settings skips the scans it has records of, so the same
    command with a larger ``n_scans`` extends the run. ``work_dir`` keeps each scan's images and
    stereo cloud (not needed to resume). ``shard`` (k, n): this process does the scans whose
    ``seed - seed0`` is k modulo n, so n processes with the same settings share one ``out``."""
    import json
    import os

    from reconstruct.compare import compare_piles
    from reconstruct.errors import ReconstructError
    from reconstruct.fitting.fit import FIT_REVISION
    from reconstruct.pipeline import ReconstructConfig, reconstruct
    from reconstruct.scan.stereo import ScanCloud, scan_cloud
    from reconstruct.scan.twin_scan import make_twin_scan, write_twin_survey
    from synth.common.files import atomic_write_bytes
    from synth.scene.pile import read_pile

    key = {"seed0": seed0, "logs": list(logs), "obstacles": list(obstacles), "fit_revision": FIT_REVISION}
    records = out / "scans"
    records.mkdir(parents=True, exist_ok=True)
    work_dir.mkdir(parents=True, exist_ok=True)
    k_shard, n_shard = shard
    for seed in range(seed0 + k_shard, seed0 + n_scans, n_shard):
        path = records / f"{seed}.json"
        if path.exists() and json.loads(path.read_text()).get("key") == key:
            continue
        root = work_dir / f"scan_{seed}"
        t0 = time.perf_counter()
        if not (root / "scan.json").exists():
            make_twin_scan(root, seed, logs=tuple(logs), obstacles=tuple(obstacles))
        surveys = {"default": root / "gnss.csv",
                   "fixed": write_twin_survey(root, root / "gnss_fixed.csv", n_float=0),
                   "degraded": write_twin_survey(root, root / "gnss_degraded.csv", n_float=-1, n_unsurveyed=1)}
        make_s = time.perf_counter() - t0
        truth = read_pile(root / "truth" / "pile.json")
        # the stereo cloud is kept with the scan (a re-run with another fitting matches no pairs again)
        kept, kept_t = root / "cloud.npz", root / "cloud_time.json"
        if kept.exists() and kept_t.exists():
            with np.load(kept) as z:
                cloud = ScanCloud(z["points"], z["colours"], camera_positions=z["cameras"])
            stereo = tuple(json.loads(kept_t.read_text()))
        else:
            t0, c0 = time.perf_counter(), time.process_time()
            cloud = scan_cloud(root / "scan")
            stereo = (time.perf_counter() - t0, time.process_time() - c0)
            np.savez(kept, points=cloud.points, colours=cloud.colours, cameras=cloud.camera_positions)
            atomic_write_bytes(kept_t, json.dumps(list(stereo)).encode())
        row = {"format": SURVEY_BENCH_FORMAT, "format_version": "2.0", "key": key,
               "seed": seed, "n_logs": truth.n_logs, "n_obstacles": len(truth.stumps) + len(truth.rocks),
               "n_pairs": int(len(cloud.camera_positions)), "cpus": os.cpu_count(), "processes": n_shard,
               "stereo_wall_s": stereo[0], "stereo_cpu_s": stereo[1], "scan_make_s": make_s,
               "load": os.getloadavg()[0], "conditions": {}}
        for cond, gnss in surveys.items():
            entry: dict = {}
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                res = reconstruct(root / "scan", gnss, root / f"recon_{cond}", ReconstructConfig(allow_float=True),
                                  cloud=cloud)
            except ReconstructError as exc:
                entry["error"] = f"{type(exc).__name__}: {exc}"
            else:
                entry["wall_s"], entry["cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
                cmp = compare_piles(truth, res.pile)
                by_recon = {lf["index"]: lf for lf in res.report["logs"]}
                entry["logs"] = [{
                    "truth_index": e["truth_index"], "log_id": by_recon[e["recon_index"]]["log_id"],
                    "worst_end_m": e["endpoint_max_err_m"],
                    "mean_end_m": e["endpoint_err_m"], "diameter_err_m": e["diameter_err_m"], "mask_iou": e["mask_iou"],
                    "true_diameter_m": e["true_diameter_m"], "axis_angle_err_deg": e["axis_angle_err_deg"],
                    "fit": by_recon[e["recon_index"]]["fit"],
                    "ends": [{k: end[k] for k in ("source", "scan", "sigma_m", "gnss_fix", "contradicted")}
                             for end in by_recon[e["recon_index"]]["ends"]]}
                    for e in cmp["logs"]]
                entry["unmatched_truth"] = cmp["unmatched_truth"]
                entry["unmatched_recon"] = cmp["unmatched_recon"]
                entry["new_logs"] = list(res.report["fusion"]["new_logs"])
                entry["weak_ends"] = len(res.report["weak_ends"])
                entry["contradicted_points"] = len(res.report["contradicted_points"])
                entry["registration"] = {k: res.report["registration"].get(k) for k in
                                         ("mode", "correction_m", "correction_deg", "residual_rms_after_m")}
            row["conditions"][cond] = entry
        atomic_write_bytes(path, json.dumps(row, indent=1).encode())
        errs = {c: e.get("error", "")[:80] for c, e in row["conditions"].items() if "error" in e}
        worst = {c: max((lg["worst_end_m"] for lg in e.get("logs", [])), default=float("nan"))
                 for c, e in row["conditions"].items()}
        progress(f"scan {seed}: {truth.n_logs} logs, worst end " + ", ".join(f"{c} {v * 100:.1f} cm" for c, v in worst.items())
                 + (f"; failed {errs}" if errs else ""))
    return read_survey_records(out, key)


def read_survey_records(out: Path, key: dict | None = None) -> dict:
    """The survey-conditions record of folder ``out``: every scan record (of ``key``'s settings; by
    default those of the most records), written to ``out/summary.json`` too."""
    import json

    from synth.common.files import atomic_write_bytes

    rows = [json.loads(p.read_text()) for p in sorted((out / "scans").glob("*.json"))]
    if key is None and rows:
        keys = [json.dumps(r["key"], sort_keys=True) for r in rows]
        key = json.loads(max(set(keys), key=keys.count))
    rows = sorted((r for r in rows if r.get("key") == key), key=lambda r: r["seed"])
    rec = {"format": SURVEY_BENCH_FORMAT, "format_version": "2.0", "key": key, "conditions": SURVEY_CONDITIONS,
           "scans": rows}
    if rows:
        atomic_write_bytes(out / "summary.json", json.dumps(
            {k: v for k, v in rec.items() if k != "scans"} | {"seeds": [r["seed"] for r in rows],
                                                              "summary": survey_summary(rec)}, indent=1).encode())
    return rec


def survey_summary(rec: dict) -> dict:
    """Per condition: failures, per-log worst-end / diameter error and mask IoU statistics, logs not
    reconstructed, end sources, times."""
    out = {}
    for cond in SURVEY_CONDITIONS:
        entries = [(r, r["conditions"][cond]) for r in rec["scans"] if cond in r["conditions"]]
        ok = [(r, e) for r, e in entries if "error" not in e]
        logs = [lg for _, e in ok for lg in e["logs"]]
        worst = [lg["worst_end_m"] for lg in logs]
        dia = [abs(lg["diameter_err_m"]) for lg in logs]
        iou = [lg["mask_iou"] for lg in logs if lg["mask_iou"] is not None]
        srcs: dict[str, int] = {}
        for lg in logs:
            for end in lg["ends"]:
                srcs[end["source"]] = srcs.get(end["source"], 0) + 1
        four = [(r["stereo_wall_s"] + e["wall_s"], r["stereo_cpu_s"] + e["cpu_s"]) for r, e in ok]
        out[cond] = {
            "scans": len(entries), "failures": len(entries) - len(ok),
            "failure_messages": [f"{r['seed']}: {e['error']}" for r, e in entries if "error" in e],
            "logs": len(logs), "missing_logs": sum(len(e["unmatched_truth"]) for _, e in ok),
            "extra_logs": sum(len(e["unmatched_recon"]) for _, e in ok),
            "worst_end_m": _stats(worst), "abs_diameter_m": _stats(dia), "mask_iou": _stats(iou, low=True),
            "sources": srcs, "weak_ends": sum(e["weak_ends"] for _, e in ok),
            "contradicted_points": sum(e["contradicted_points"] for _, e in ok),
            "scan_wall_s": _stats([w for w, _ in four]), "scan_cpu_s": _stats([c for _, c in four]),
            "recon_cpu_s": _stats([e["cpu_s"] for _, e in ok]),
        }
    return out


def _stats(v: list[float], low: bool = False) -> dict:
    if not v:
        return {"n": 0}
    a = np.asarray(v, dtype=float)
    d = {"n": int(a.size), "median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max())}
    if low:
        d.update(p5=float(np.percentile(a, 5)), min=float(a.min()))
    return d


def _seed_ranges(rec: dict) -> str:
    """The recorded scans' seeds as ranges, e.g. ``1100000..1100129, 1100131``: a run stopped and
    resumed out of order leaves gaps that ``first..first + n - 1`` would hide."""
    seeds = sorted(int(r["seed"]) for r in rec["scans"])
    runs: list[list[int]] = []
    for x in seeds:
        if runs and x == runs[-1][1] + 1:
            runs[-1][1] = x
        else:
            runs.append([x, x])
    return ", ".join(f"{a}..{b}" if b > a else f"{a}" for a, b in runs) or "-"


def survey_markdown(rec: dict, figure: Path | None = None) -> list[str]:
    s = survey_summary(rec)
    n = len(rec["scans"])
    loads = [r["load"] for r in rec["scans"]]
    lines = [
        "#### Reconstruction under three survey conditions (the same scans)",
        f"{n} fresh twin scans (`loggrasp synth scan` piles, seeds {_seed_ranges(rec)}, "
        f"{rec['key']['logs'][0]}-{rec['key']['logs'][1]} logs, {rec['key']['obstacles'][0]}-{rec['key']['obstacles'][1]} "
        "obstacles, 2x2 pairs at 3 m), each reconstructed with three surveys of its pile "
        f"(fitting revision {rec['key']['fit_revision']}). Per log: worst end error (the farther of its two ends "
        "from the truth), absolute mean-diameter error, mask IoU (128 px). Targets (issue 18): <= 1 % failures, "
        "worst end <= 3 cm median and <= 8 cm p95, diameter <= 1 cm median, <= 15 s per 4-pair scan. "
        f"{max(r.get('processes', 1) for r in rec['scans'])} bench process(es) on {rec['scans'][0].get('cpus', '?')} cores; "
        f"load average {min(loads):.1f}-{max(loads):.1f} "
        f"(median {statistics.median(loads):.1f}) while it ran.\n",
        "| survey | scans | failures | logs | not reconstructed | worst end median [cm] | p95 | max | "
        "abs diameter median [cm] | p95 | mask IoU median | p5 |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for cond, d in s.items():
        if not d["logs"]:
            continue
        w, di, io = d["worst_end_m"], d["abs_diameter_m"], d["mask_iou"]
        lines.append(f"| {cond} | {d['scans']} | {d['failures']} ({100 * d['failures'] / max(d['scans'], 1):.1f} %) | "
                     f"{d['logs']} | {d['missing_logs']} | {100 * w['median']:.1f} | {100 * w['p95']:.1f} | "
                     f"{100 * w['max']:.1f} | {100 * di['median']:.2f} | {100 * di['p95']:.1f} | {io['median']:.3f} | "
                     f"{io['p5']:.3f} |")
    lines += ["", "| survey | ends placed: scan / fixed / float / inferred | weak ends | survey points contradicted | "
              "4-pair scan wall median [s] | p95 | CPU median [s] | reconstruction CPU (stereo excluded) [s] |",
              "|---|---|---|---|---|---|---|---|"]
    for cond, d in s.items():
        if not d["logs"]:
            continue
        src = " / ".join(str(d["sources"].get(k, 0)) for k in ("scan", "fixed", "float", "inferred"))
        lines.append(f"| {cond} | {src} | {d['weak_ends']} | {d['contradicted_points']} | "
                     f"{d['scan_wall_s']['median']:.1f} | {d['scan_wall_s']['p95']:.1f} | {d['scan_cpu_s']['median']:.1f} | "
                     f"{d['recon_cpu_s']['median']:.1f} |")
    for cond, d in s.items():
        for m in d["failure_messages"]:
            lines.append(f"- {cond}, seed {m}")
    if figure is not None:
        lines += ["", f"![error distributions per survey condition]({figure})"]
    return lines


def survey_figure(rec: dict, path: Path) -> Path:
    """Histograms (cumulative) of the per-log worst end error and the diameter error, per condition."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for cond in SURVEY_CONDITIONS:
        logs = [lg for r in rec["scans"] for lg in r["conditions"].get(cond, {}).get("logs", [])]
        if not logs:
            continue
        for ax, key, scale in ((axes[0], "worst_end_m", 100), (axes[1], "diameter_err_m", 100)):
            v = np.sort(np.abs([lg[key] for lg in logs])) * scale
            ax.plot(v, np.arange(1, len(v) + 1) / len(v), label=f"{cond} ({len(v)} logs)")
    axes[0].axvline(3, color="grey", ls=":")
    axes[0].axvline(8, color="grey", ls="--")
    axes[0].set(xlabel="worst end error per log [cm]", ylabel="share of logs", xscale="log", xlim=(0.3, 100))
    axes[1].axvline(1, color="grey", ls=":")
    axes[1].set(xlabel="|mean diameter error| per log [cm]", xscale="log", xlim=(0.01, 30))
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    fig.suptitle(f"Reconstruction under three survey conditions, {len(rec['scans'])} twin scans", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--piles", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--real-piles", type=int, default=24, help="twin scans for the real test (0: skip it)")
    ap.add_argument("--model", default=None, help="planner checkpoint for the real test (default: the shipped one)")
    ap.add_argument("--workers", type=int, default=2, help="processes for the real test")
    ap.add_argument("--real-out", type=Path, default=None,
                    help="keep the real-test record (JSON) here: written after every pile, resumed when re-run")
    ap.add_argument("--real-only", action="store_true", help="run only the real test")
    ap.add_argument("--views", type=int, default=1, help="dihedral views the planner averages in the real test")
    ap.add_argument("--view-spread", type=float, default=0.0, help="U lowered by K x its spread over the views")
    ap.add_argument("--log-direction", default="45",
                    help="reconstructed pile frames turned so the logs lie at this angle [deg], or 'site' for the "
                         "site's axes (default 45, ReconstructConfig's)")
    ap.add_argument("--work-dir", type=Path, default=None,
                    help="keep the real test's scans and reconstructions here (reused when re-run)")
    ap.add_argument("--n-float", type=int, default=0,
                    help="RTK float ends per real-test survey (the twin's default survey has 2; reconstructed "
                         "with allow_float)")
    ap.add_argument("--survey-scans", type=int, default=0,
                    help="run only the survey-conditions bench on this many fresh twin scans (one process)")
    ap.add_argument("--survey-seed", type=int, default=1_100_000, help="first seed of the survey-conditions bench")
    ap.add_argument("--survey-work", type=Path, default=Path("runs/survey-work"), help="its scans and reconstructions")
    ap.add_argument("--survey-out", type=Path, default=Path("docs/results/survey-conditions"),
                    help="its record: a folder with one JSON per scan (kept: the same command with more "
                         "--survey-scans extends the run) and summary.json")
    ap.add_argument("--survey-shard", default="0/1", metavar="K/N",
                    help="do only the survey scans whose seed - --survey-seed is K modulo N (run N processes, "
                         "K = 0..N-1, on one --survey-out)")
    ap.add_argument("--figure", type=Path, default=None, help="write the error-distribution figure here")
    ap.add_argument("--survey-report", action="store_true",
                    help="print the markdown (and write --figure) of an existing --survey-out record, run nothing")
    args = ap.parse_args()
    if args.survey_scans > 0 or args.survey_report:
        import json

        try:
            shard = tuple(int(v) for v in args.survey_shard.split("/"))
            if len(shard) != 2 or not 0 <= shard[0] < shard[1]:
                raise ValueError
        except ValueError:
            raise SystemExit(f"--survey-shard must be K/N with 0 <= K < N, got {args.survey_shard!r}") from None

        rec = (read_survey_records(args.survey_out) if args.survey_report else
               survey_bench(args.survey_scans, args.survey_seed, args.survey_work, args.survey_out, shard=shard,
                            progress=lambda s: print(s, file=sys.stderr, flush=True)))
        fig = survey_figure(rec, args.figure) if args.figure is not None else None
        print("\n".join(survey_markdown(rec, fig)))
        raise SystemExit(0)
    from reconstruct.pipeline import parse_log_direction

    try:
        log_direction = parse_log_direction(args.log_direction)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    from experiments.real_test import RealTestConfig

    real_cfg = None if args.real_piles <= 0 else RealTestConfig(
        n_piles=args.real_piles, model=args.model, workers=args.workers, views=args.views,
        view_spread_k=args.view_spread, log_direction_deg=log_direction, n_float=args.n_float)
    if args.real_only:
        if real_cfg is None:
            raise SystemExit("--real-only needs --real-piles > 0")
        print("\n".join(real_test_markdown(real_test(real_cfg, args.real_out, args.work_dir))))
    else:
        print(markdown(args.piles, args.repeats, real_cfg, args.real_out, args.work_dir, real_piles=args.real_piles))
