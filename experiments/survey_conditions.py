"""Reconstruction under three survey conditions (issue 18): the same fresh twin scans reconstructed
with the twin's default survey (2 RTK float ends), an all-fixed one and a degraded one (half the ends
float, one log not surveyed); every log measured against the truth. ``bench/bench_reconstruct.py
--survey-scans N`` is its command (``--survey-report`` the tables and figure of a record).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


# -- survey conditions: the same scans with the twin's default survey, an all-fixed one, a degraded one --
SURVEY_CONDITIONS = {
    "default": "the twin's default survey: 2 RTK float ends (sigma 25 cm h, 40 cm v), the rest fixed",
    "fixed": "every end RTK fixed (1.5 cm h, 2.5 cm v)",
    "degraded": "half the ends float and one log (one the scan shows well) not surveyed at all",
}
SURVEY_BENCH_FORMAT = "loggrasp.bench-survey-conditions"
#: 2.2: each reconstructed condition has ``obstacles`` (:func:`obstacle_entry`); 2.1 records lack it
SURVEY_BENCH_VERSION = "2.2"

# -- the tuning set and the held-out set (issue 37): other seeds, other pile shapes --
#: pile shapes: ``make_twin_scan`` keyword arguments. "dropped" is the generator's default stack (the
#: tuning set's only shape); "packed": aligned logs side by side, touching; "loose": the dropped stack
#: with its log centres and yaws scattered twice as far (0.6 m, 0.7 rad against 0.3 m, 0.35 rad)
PILE_SHAPES = {
    "dropped": {},
    "packed": {"packed": True},
    "loose": {"pile_spread_m": 0.6, "yaw_spread_rad": 0.7},
}
#: the survey-conditions sets. "tuning": the scans the fitting's rules were written against (seeds from
#: 1,100,000, one shape); "heldout": scans no rule was written against (seeds from 3,300,000, the three
#: shapes in turn: seed - seed0 modulo 3 picks one) - but the joint estimator's revisions 6-8 looked at
#: held-out scans 3,300,005, 3,300,010 and 3,300,011; "final": the same shapes from 5,500,000, for the
#: decision to ship an estimator, run only once it is frozen and never read scan by scan before
SURVEY_SETS = {
    "tuning": {"seed0": 1_100_000, "shapes": ("dropped",)},
    "heldout": {"seed0": 3_300_000, "shapes": ("packed", "loose", "dropped")},
    "final": {"seed0": 5_500_000, "shapes": ("packed", "loose", "dropped")},
}
#: seeds each set owns: a run of one set may not start inside another's (the tuning benches used up to
#: 1,100,199)
SET_SEED_RANGES = {"tuning": (1_100_000, 1_200_000), "heldout": (3_300_000, 3_400_000),
                   "final": (5_500_000, 5_600_000)}
TUNING_SEED_RANGE = SET_SEED_RANGES["tuning"]


def survey_set_key(survey_set: str, seed0: int | None = None, estimator: str = "rules22",
                   joint_options: dict | None = None) -> dict:
    """The part of a survey-conditions record's key that says which set (and estimator) it measured; the
    tuning set with revision 22 adds nothing (its records from before the held-out set resume as they
    are). A held-out or final run whose seeds start inside another set's (:data:`SET_SEED_RANGES`) is a ValueError.
    ``joint_options``: ``JointConfig`` fields set away from their defaults (the joint estimator only; recorded
    as ``joint_options``, so such a run neither resumes nor is taken for one with the defaults)."""
    if joint_options and estimator != "joint":
        raise ValueError(f"JointConfig options ({', '.join(sorted(joint_options))}) need --survey-estimator joint, "
                         f"got {estimator!r}")
    if survey_set not in SURVEY_SETS:
        raise ValueError(f"--survey-set must be one of {', '.join(SURVEY_SETS)}, got {survey_set!r}")
    seed0 = SURVEY_SETS[survey_set]["seed0"] if seed0 is None else int(seed0)
    for other, (lo, hi) in SET_SEED_RANGES.items():
        if other != survey_set and survey_set != "tuning" and lo <= seed0 < hi:
            raise ValueError(f"--survey-seed {seed0} lies in the {other} set's seeds ({lo}..{hi - 1}); "
                             f"the {survey_set} set needs its own")
    key: dict = {}
    if survey_set != "tuning":
        key.update(set=survey_set, shapes=list(SURVEY_SETS[survey_set]["shapes"]))
    if estimator != "rules22":
        from reconstruct.fitting.joint_config import JOINT_REVISION

        key.update(estimator=estimator, estimator_revision=JOINT_REVISION)
    if joint_options:
        key.update(joint_options=dict(sorted(joint_options.items())))
    return key


class SurveyBenchInputError(ValueError):
    """A survey-conditions run asked for something its settings do not allow (e.g. a seed outside its range)."""


def survey_pairs_key(pairs: str) -> dict:
    """The part of a record's key that says how its scans' pairs were laid out: nothing for the twin's
    fixed 2x2 grid (every record before the planned scans resumes as it is), ``pairs: auto`` and the plan's
    config for a grid planned from the survey; anything else is a ValueError."""
    import dataclasses
    import json

    from reconstruct.scan.plan import ScanPlanConfig

    if pairs == "2x2":
        return {}
    if pairs == "auto":
        return {"pairs": "auto", "plan": json.loads(json.dumps(dataclasses.asdict(ScanPlanConfig())))}
    raise ValueError(f"--survey-pairs must be 2x2 or auto, got {pairs!r}")


def _plan_kw(pairs: str) -> dict:
    """``make_twin_scan`` keywords of a ``pairs`` setting (:func:`survey_pairs_key`)."""
    from reconstruct.scan.plan import ScanPlanConfig

    return {"plan": ScanPlanConfig()} if pairs == "auto" else {}


def pile_shape(key: dict, seed: int) -> str:
    """The pile shape of ``seed`` in a record of ``key``: the set's shapes in turn."""
    shapes = key.get("shapes", ["dropped"])
    return shapes[(seed - key["seed0"]) % len(shapes)]


def survey_bench(n_scans: int, seed0: int | None, work_dir: Path, out: Path, logs=(3, 7), obstacles=(0, 3),
                 progress=print, shard: tuple[int, int] = (0, 1), survey_set: str = "tuning",
                 estimator: str = "rules22", joint_options: dict | None = None, pairs: str = "2x2",
                 only_shapes: tuple[str, ...] = (), only_seeds: tuple[int, ...] = ()) -> dict:
    """Reconstruction under the three survey conditions (:data:`SURVEY_CONDITIONS`) on ``n_scans``
    fresh twin scans (``loggrasp synth scan`` piles, seeds ``seed0``...): the stereo cloud of each scan
    is matched once and reconstructed with each survey; every log is measured against the truth (worst
    end, mean diameter, mask IoU) and every end's source kept.

    ``out`` is a folder: one record per scan (``scans/<seed>.json``, written when the scan is done) and
    ``summary.json``. A run with the same settings skips the scans it has records of, so the same
    command with a larger ``n_scans`` extends the run. ``work_dir`` keeps each scan's images and
    stereo cloud (not needed to resume). ``shard`` (k, n): this process does the scans whose
    ``seed - seed0`` is k modulo n, so n processes with the same settings share one ``out``.
    ``survey_set``: "tuning", "heldout" or "final" (:data:`SURVEY_SETS`: its first seed when ``seed0`` is None,
    its pile shapes); ``estimator``: ``ReconstructConfig.estimator``; ``joint_options``: ``JointConfig`` fields
    set away from their defaults (:func:`survey_set_key`). All go into the record's key.
    ``pairs``: "2x2" (the twin's fixed grid, every record before it) or "auto" (the grid planned from each
    scan's survey, :func:`reconstruct.scan.plan.plan_scan` with its default config, in the key).
    ``only_shapes`` / ``only_seeds``: do only the scans of these pile shapes / these seeds (in this order;
    each must lie in the run's range): a re-scan of some piles, not a new record key."""
    import json
    import os

    from reconstruct.fitting.fit import FIT_REVISION
    from synth.common.files import atomic_write_bytes

    set_key = survey_set_key(survey_set, seed0, estimator, joint_options)
    seed0 = SURVEY_SETS[survey_set]["seed0"] if seed0 is None else int(seed0)
    key = ({"seed0": seed0, "logs": list(logs), "obstacles": list(obstacles), "fit_revision": FIT_REVISION} | set_key
           | survey_pairs_key(pairs))
    k_shard, n_shard = shard
    seeds = [s for s in range(seed0 + k_shard, seed0 + n_scans, n_shard)]
    if only_seeds:
        outside = [s for s in only_seeds if s not in seeds]
        if outside:
            from experiments.survey_report import seed_ranges

            span = seed_ranges({"scans": [{"seed": s} for s in seeds]})
            raise SurveyBenchInputError(f"--survey-only-seeds {outside} lie outside this run's seeds ({span})")
        seeds = list(only_seeds)
    records = out / "scans"
    records.mkdir(parents=True, exist_ok=True)
    work_dir.mkdir(parents=True, exist_ok=True)
    for seed in seeds:
        path = records / f"{seed}.json"
        shape = pile_shape(key, seed)
        if only_shapes and shape not in only_shapes:
            continue
        if path.exists() and json.loads(path.read_text()).get("key") == key:
            continue
        root = work_dir / f"scan_{seed}"
        surveys, make_s, truth = _scan_and_surveys(root, seed, logs, obstacles, PILE_SHAPES[shape] | _plan_kw(pairs))
        cloud, stereo = _stereo_cloud(root)
        row = {"format": SURVEY_BENCH_FORMAT, "format_version": SURVEY_BENCH_VERSION, "key": key,
               "seed": seed, "set": survey_set, "shape": shape, "n_logs": truth.n_logs, "n_obstacles": len(truth.stumps) + len(truth.rocks),
               "n_pairs": int(len(cloud.camera_positions)), "cpus": os.cpu_count(), "processes": n_shard,
               "cloud_sha256": cloud_fingerprint(cloud),
               "stereo_wall_s": stereo[0], "stereo_cpu_s": stereo[1], "scan_make_s": make_s,
               "load": os.getloadavg()[0], "conditions": {}}
        for cond, gnss in surveys.items():
            row["conditions"][cond] = _condition_entry(root, cond, gnss, cloud, truth, estimator, joint_options)
        atomic_write_bytes(path, json.dumps(row, indent=1).encode())
        errs = {c: e.get("error", "")[:80] for c, e in row["conditions"].items() if "error" in e}
        worst = {c: max((lg["worst_end_m"] for lg in e.get("logs", [])), default=float("nan"))
                 for c, e in row["conditions"].items()}
        progress(f"scan {seed}: {truth.n_logs} logs, worst end " + ", ".join(f"{c} {v * 100:.1f} cm" for c, v in worst.items())
                 + (f"; failed {errs}" if errs else ""))
    return read_survey_records(out, key)


def _scan_and_surveys(root: Path, seed: int, logs, obstacles, shape: dict):
    """The twin scan of ``seed`` in ``root`` (made once, its pile of ``shape``: :data:`PILE_SHAPES`) and its
    three surveys; returns the survey paths by condition, the seconds it took to make them, and the true pile."""
    from reconstruct.scan.twin_scan import make_twin_scan, write_twin_survey
    from synth.scene.pile import read_pile

    t0 = time.perf_counter()
    if not (root / "scan.json").exists():
        make_twin_scan(root, seed, logs=tuple(logs), obstacles=tuple(obstacles), **shape)
    surveys = {"default": root / "gnss.csv",
               "fixed": write_twin_survey(root, root / "gnss_fixed.csv", n_float=0),
               "degraded": write_twin_survey(root, root / "gnss_degraded.csv", n_float=-1, n_unsurveyed=1)}
    return surveys, time.perf_counter() - t0, read_pile(root / "truth" / "pile.json")


def cloud_fingerprint(cloud) -> str:
    """The first 16 hex digits of the sha256 of a stereo cloud's points: two records of one seed
    measured the same scan only when these agree (``work_dir`` keeps scans and clouds from run to
    run, and a kept one made by older code is reused as it is: compare records by this, not by seed)."""
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(cloud.points, dtype=np.float64).tobytes()).hexdigest()[:16]


def _stereo_cloud(root: Path):
    """The scan's stereo cloud, matched once and kept with the scan (a re-run with another fitting
    matches no pairs again); returns it and the (wall, CPU) seconds its matching took."""
    import json

    from reconstruct.scan.stereo import ScanCloud, scan_cloud
    from synth.common.files import atomic_write_bytes

    kept, kept_t = root / "cloud.npz", root / "cloud_time.json"
    if kept.exists() and kept_t.exists():
        with np.load(kept) as z:
            cloud = ScanCloud(z["points"], z["colours"], camera_positions=z["cameras"])
        return cloud, tuple(json.loads(kept_t.read_text()))
    t0, c0 = time.perf_counter(), time.process_time()
    cloud = scan_cloud(root / "scan")
    stereo = (time.perf_counter() - t0, time.process_time() - c0)
    np.savez(kept, points=cloud.points, colours=cloud.colours, cameras=cloud.camera_positions)
    atomic_write_bytes(kept_t, json.dumps(list(stereo)).encode())
    return cloud, stereo


def _condition_entry(root: Path, cond: str, gnss: Path, cloud, truth, estimator: str = "rules22",
                     joint_options: dict | None = None) -> dict:
    """One survey condition of a scan: the reconstruction's error (or its refusal), every log
    against the truth with its ends' sources, and what the report flagged (``joint_options``:
    :func:`survey_set_key`'s; the reconstruction kept in a folder named after them)."""
    from dataclasses import replace

    from reconstruct.compare import compare_piles
    from reconstruct.errors import ReconstructError
    from reconstruct.config import ReconstructConfig
    from reconstruct.pipeline import reconstruct

    entry: dict = {}
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        name = f"recon_{cond}" if estimator == "rules22" else f"recon_{cond}_{estimator}"
        config = ReconstructConfig(allow_float=True, **_estimator_kw(estimator))
        if joint_options:
            name += "".join(f"-{k}" for k in sorted(joint_options))
            config = replace(config, joint=replace(config.joint, **joint_options))
        res = reconstruct(root / "scan", gnss, root / name, config, cloud=cloud)
    except ReconstructError as exc:
        entry["error"] = f"{type(exc).__name__}: {exc}"
        return entry
    except ValueError as exc:  # a bug, not a refusal: counted as a failure, named as a crash, the run goes on
        entry["error"] = f"crash: {type(exc).__name__}: {exc}"
        return entry
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
    entry["obstacles"] = obstacle_entry(cmp)
    entry["unmatched_truth"] = cmp["unmatched_truth"]
    entry["unmatched_recon"] = cmp["unmatched_recon"]
    entry["new_logs"] = list(res.report["fusion"]["new_logs"])
    entry["weak_ends"] = len(res.report["weak_ends"])
    entry["contradicted_points"] = len(res.report["contradicted_points"])
    entry["registration"] = {k: res.report["registration"].get(k) for k in
                             ("mode", "correction_m", "correction_deg", "residual_rms_after_m")}
    return entry


def obstacle_entry(cmp: dict) -> dict:
    """A condition's obstacles against the truth, from :func:`reconstruct.compare.compare_piles`'s one-to-one
    matching (:func:`reconstruct.compare.match_obstacles`, its default gate :data:`reconstruct.compare.OBSTACLE_GATE_M`):
    the pairs, ``phantom_obstacles`` (reconstructed ones no true one explains) and ``missed_obstacles`` (true ones
    not reconstructed: hidden under logs or outside the scan as well as not found), as indices into each pile."""
    from reconstruct.compare import OBSTACLE_GATE_M

    matches = cmp["obstacles"]
    used = {m["recon_index"] for m in matches if m["recon_index"] is not None}
    return {"gate_m": OBSTACLE_GATE_M, "n_truth": len(matches), "n_recon": cmp["summary"]["n_recon_obstacles"],
            "matched": [{k: m[k] for k in ("truth_index", "recon_index", "kind", "recon_kind", "distance_m")}
                        for m in matches if m["recon_index"] is not None],
            "phantom_obstacles": [j for j in range(cmp["summary"]["n_recon_obstacles"]) if j not in used],
            "missed_obstacles": [m["truth_index"] for m in matches if m["recon_index"] is None]}


def _estimator_kw(estimator: str) -> dict:
    """``ReconstructConfig`` keywords of an estimator name (revision 22 is the config's default)."""
    return {} if estimator == "rules22" else {"estimator": estimator}


def read_survey_records(out: Path, key: dict | None = None, write: bool = True) -> dict:
    """The survey-conditions record of folder ``out``: every scan record (of ``key``'s settings; by
    default those of the most records), written to ``out/summary.json`` too (unless ``write`` is off)."""
    import json

    from synth.common.files import atomic_write_bytes

    rows = [json.loads(p.read_text()) for p in sorted((out / "scans").glob("*.json"))]
    if key is None and rows:
        keys = [json.dumps(r["key"], sort_keys=True) for r in rows]
        key = json.loads(max(set(keys), key=keys.count))
    rows = sorted((r for r in rows if r.get("key") == key), key=lambda r: r["seed"])
    rec = {"format": SURVEY_BENCH_FORMAT, "format_version": SURVEY_BENCH_VERSION, "key": key,
           "set": (key or {}).get("set", "tuning"), "conditions": SURVEY_CONDITIONS, "scans": rows}
    if rows and write:
        from experiments.survey_report import survey_summary

        atomic_write_bytes(out / "summary.json", json.dumps(
            {k: v for k, v in rec.items() if k != "scans"} | {"seeds": [r["seed"] for r in rows],
                                                              "summary": survey_summary(rec)}, indent=1).encode())
    return rec
