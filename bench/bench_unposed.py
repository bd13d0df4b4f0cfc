"""Unposed scans (no pair poses, no scan pose) against posed ones, on twin scans (``make bench``
section "unposed"; run alone:
``.venv/bin/python bench/bench_unposed.py --piles 3``).

For each seed (100, 101, ...): a settled pile (5 logs, 2 obstacles) scanned by a 2x2 grid of
ZED 2-like pairs (1280x720, 50 deg, 0.12 m baseline, ~3 m up) with the rig moved between pairs as
by hand (positions +-15 cm, heights +-20 cm, yaw +-8 deg, tilts +-4 deg), and an RTK survey of the
log ends (no float fixes). The *same images* are reconstructed twice:

* **posed**: the calibrations carry the true pair poses and ``scan_pose.json`` the scan's pose
  with the crane's usual error (3 cm / 0.5 deg, 1 sigma) -> refinement only;
* **unposed**: no pose anywhere -> pair poses by pycolmap SfM anchored to the pairs' stereo
  depth (:mod:`reconstruct.scan.sfm`), the scan placed from the GNSS end points alone
  (:func:`reconstruct.scan.coarse_pose.coarse_scan_pose`) and then refined as usual.

Both are compared with the truth (:func:`reconstruct.compare.compare_piles`); the SfM pair
poses with the true ones. Wall times depend on other load on the 2 cores: the load average is
printed, CPU seconds of this process beside (pycolmap's threads included).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments.measure import load_average, percentile


def _pose_errors(scan: Path, report: dict) -> tuple[list[float], list[float]]:
    """Position [m] and rotation [deg] errors of the SfM pair poses (relative to the first pair)."""
    true = {k: np.asarray(v) for k, v in json.loads((scan / "truth" / "poses.json").read_text())["T_pile_cam"].items()}
    first = min(true)
    pos, rot = [], []
    for k, T in report["sfm"]["T_scan_cam"].items():
        if k == first:
            continue
        T_true = np.linalg.inv(true[first]) @ true[k]
        T = np.asarray(T)
        pos.append(float(np.linalg.norm(T[:3, 3] - T_true[:3, 3])))
        dR = T_true[:3, :3].T @ T[:3, :3]
        rot.append(math.degrees(math.acos(float(np.clip((np.trace(dR) - 1) / 2, -1, 1)))))
    return pos, rot


def measure(n_piles: int = 3, first_seed: int = 100, workdir: Path | None = None) -> dict:
    from reconstruct.compare import compare_piles
    from reconstruct.errors import ReconstructError
    from reconstruct.pipeline import reconstruct
    from reconstruct.scan.twin_scan import make_twin_scan
    from synth.scene.pile import read_pile

    rows = {"posed": [], "unposed": []}
    failures = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for seed in range(first_seed, first_seed + n_piles):
            for mode in ("posed", "unposed"):
                d = make_twin_scan(Path(tmp) / f"{mode}{seed}", seed, logs=(5, 5), obstacles=(2, 2), n_float=0,
                                   unposed=(mode == "unposed"), handheld=True)
                truth = read_pile(d / "truth" / "pile.json")
                t0, c0 = time.perf_counter(), time.process_time()
                try:
                    res = reconstruct(d / "scan", d / "gnss.csv", d / "out")
                except ReconstructError as exc:
                    failures.append(f"seed {seed} ({mode}): {type(exc).__name__}: {exc}")
                    continue
                wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                c = compare_piles(truth, res.pile)
                rep = res.report
                reg = rep["registration"]
                row = {
                    "seed": seed, "wall_s": wall, "cpu_s": cpu, "sfm_s": rep["timings_s"].get("sfm_s", math.nan),
                    "ep": [e["endpoint_err_m"] for e in c["logs"]],
                    "dia": [abs(e["diameter_err_m"]) for e in c["logs"]],
                    "iou": [e["mask_iou"] for e in c["logs"] if e["mask_iou"] is not None],
                    "matched": c["summary"]["n_matched"], "n_truth": truth.n_logs,
                    "reg_before": reg.get("residual_rms_before_m", math.nan),
                    "reg_after": reg.get("residual_rms_after_m", math.nan),
                    "correction_m": reg.get("total_correction_m", math.nan),
                    "correction_deg": reg.get("total_correction_deg", math.nan),
                    "source": rep["scan_pose_source"],
                }
                if rep.get("sfm"):
                    pos, rot = _pose_errors(d, rep)
                    row.update(pose_pos=pos, pose_rot=rot, scale_spread=rep["sfm"]["scale_spread"],
                               anchor_rms=[a["residual_rms_m"] for a in rep["sfm"]["anchor"].values()])
                if rep.get("coarse_registration"):
                    cr = rep["coarse_registration"]
                    row.update(support=cr["support"], second=cr["second_peak_support"])
                rows[mode].append(row)
    return {"rows": rows, "failures": failures}


def markdown(n_piles: int = 3) -> str:
    load0 = load_average()
    m = measure(n_piles)
    load1 = load_average()
    lines = [
        "### Unposed scans (pycolmap SfM + GNSS georegistration) vs posed, twin scans",
        f"{n_piles} generated piles (seeds 100-{99 + n_piles}; 5 logs, 2 obstacles), 2x2 handheld pairs (the same "
        "images both ways), RTK noise 1.5/2.5 cm, no float fixes. Posed: true pair poses + scan pose with "
        f"3 cm / 0.5 deg error; unposed: nothing but images, calibrations without pose and the survey. "
        f"{load0} before, {load1} after.\n",
        "| measure | posed median | posed p95 | unposed median | unposed p95 | n (posed/unposed) |",
        "|---|---|---|---|---|---|",
    ]

    def cells(key: str, fmt: str, agg=None) -> str:
        out = []
        for mode in ("posed", "unposed"):
            vals = [v for r in m["rows"][mode] for v in (r[key] if isinstance(r.get(key), list) else [r.get(key)])
                    if v is not None and np.isfinite(v)]
            out.append((vals, f"{percentile(vals, 50):{fmt}}", f"{percentile(vals, 95):{fmt}}"))
        return (f"| {out[0][1]} | {out[0][2]} | {out[1][1]} | {out[1][2]} | {len(out[0][0])}/{len(out[1][0])} |")

    lines += [
        "| end point error [m] " + cells("ep", ".3f"),
        "| abs mean-diameter error [m] " + cells("dia", ".4f"),
        "| log mask IoU (128 px) " + cells("iou", ".3f"),
        "| GNSS end -> fitted axis RMS, before refinement [m] " + cells("reg_before", ".3f"),
        "| GNSS end -> fitted axis RMS, after refinement [m] " + cells("reg_after", ".3f"),
        "| refinement correction [m] " + cells("correction_m", ".3f"),
        "| refinement correction [deg] " + cells("correction_deg", ".2f"),
        "| SfM (pycolmap + stereo anchoring) [s] " + cells("sfm_s", ".1f"),
        "| reconstruct() wall [s] " + cells("wall_s", ".1f"),
        "| reconstruct() CPU of this process [s] " + cells("cpu_s", ".1f"),
    ]
    un = m["rows"]["unposed"]
    if un:
        pos = [v for r in un for v in r.get("pose_pos", [])]
        rot = [v for r in un for v in r.get("pose_rot", [])]
        lines += ["", "Unposed path details:", "",
                  f"- SfM pair poses vs truth (relative to the first pair, {len(pos)} poses): position error median "
                  f"{percentile(pos, 50) * 1000:.1f} mm, max {max(pos, default=math.nan) * 1000:.1f} mm; rotation error "
                  f"median {percentile(rot, 50):.3f} deg, max {max(rot, default=math.nan):.3f} deg.",
                  "- per pile: " + "; ".join(
                      f"seed {r['seed']}: scale spread {r.get('scale_spread', math.nan) * 100:.2f} %, anchor RMS "
                      f"{max(r.get('anchor_rms', [math.nan])) * 1000:.1f} mm, yaw support {r.get('support', math.nan):.2f} "
                      f"(second peak {r.get('second', math.nan):.2f}), logs matched {r['matched']}/{r['n_truth']}"
                      for r in un)]
    if m["failures"]:
        lines += ["", "Failures:"] + [f"- {f}" for f in m["failures"]]
    return "\n".join(lines)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--piles", type=int, default=3)
    args = ap.parse_args()
    print(markdown(args.piles))
