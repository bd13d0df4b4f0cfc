"""The real test of a reconstruction: does a grasp planned on the reconstructed pile succeed on the
real pile as often as one planned on the real pile itself?

For each of ``n_piles`` twin scans (:func:`reconstruct.scan.twin_scan.make_twin_scan`: a generated
pile with known truth, a grid of stereo pairs, an RTK survey of the log ends):

1. reconstruct the pile (:func:`reconstruct.pipeline.reconstruct`; its own pile frame and its
   ``ortho.npz`` re-render, exactly what the field stack plans on, :mod:`field.trial`);
2. plan with the same model and objective on (a) that re-render and (b) an orthographic render
   of the TRUE pile (same render settings: size of the model, three renders, seed 0);
3. express the grasp planned on the reconstruction in the true pile's frame (both piles carry a
   site georeference ``T_site_pile``; the grasp centre and a point along its closing axis go
   through the site frame, or through geodetic coordinates when the site origins differ) and
   its target logs as true log indices (logs matched by :func:`reconstruct.compare.compare_piles`;
   a target without a true match makes the grasp fail);
4. execute both grasps on the TRUE pile in the twin (:func:`synth.physics.trial.run_trial`,
   ``TrialConfig.fast()``), success = exactly the intended logs held.

:func:`run_real_test` returns (and :func:`write_real_test` / :func:`read_real_test` store, format
``loggrasp.real-test`` 1.0) one row per pile and objective and a summary per objective: success
rates with their binomial standard errors, the difference (reconstruction minus truth) in
percentage points with the standard error of the *paired* difference, per-pile agreement, and
how far the two chosen grasps lie apart (position, angle, width). A failed reconstruction counts
as a failed grasp (the field stack would not send one) and is counted separately.

The issue's criterion: the reconstruction-planned rate lies within 3 percentage points of the
truth-planned rate. With a paired design the uncertainty of the difference shrinks with the
agreement of the two plans; the summary says whether ``n_piles`` resolves 3 points.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from experiments.measure import paired_se
from field.errors import FieldError
from reconstruct.fitting.fit import FIT_REVISION
from synth.common.formats import VersionedJson
from synth.common.runner import run_tasks

REAL_TEST_FORMAT = "loggrasp.real-test"
REAL_TEST_VERSION = "1.0"
REAL_TEST = VersionedJson(REAL_TEST_FORMAT, REAL_TEST_VERSION, "real-test record", FieldError)
OBJECTIVES = ("f1", "f2", "f3")


@dataclass(frozen=True)
class RealTestConfig:
    """What the real test runs on (units in the names/comments)."""

    n_piles: int = 24  # twin scans [-]
    seed: int = 700000  # pile k uses seed + k (far from training seeds) [-]
    logs: tuple[int, int] = (3, 6)  # logs per pile, inclusive range [-]
    obstacles: tuple[int, int] = (0, 2)  # stumps + rocks per pile, inclusive range [-]
    objectives: tuple[str, ...] = ("f1", "f3")  # planner objectives, each planned and executed
    model: str | None = None  # planner checkpoint; None = the shipped default
    n_float: int = 0  # RTK float end points per survey (they need allow_float) [-]
    grid: tuple[int, int] = (2, 2)  # stereo pairs per scan [-]
    workers: int = 1  # processes (each loads the model once) [-]
    views: int = 1  # dihedral views the planner averages (planner.inference.Planner.views) [-]
    view_spread_k: float = 0.0  # U logit lowered by k x its spread over the views (Planner.view_spread_k) [-]
    log_direction_deg: float | None = 45.0  # reconstructed pile frames turned so the logs lie at this angle
    # (reconstruct.config.ReconstructConfig.log_direction_deg) [deg]; None: site axes

    def __post_init__(self) -> None:
        if self.n_piles < 1:
            raise ValueError(f"n_piles must be >= 1, got {self.n_piles}")
        if not 1 <= self.logs[0] <= self.logs[1] <= 16:
            raise ValueError(f"logs must be an increasing range inside [1, 16], got {self.logs}")
        if not 0 <= self.obstacles[0] <= self.obstacles[1] <= 12:
            raise ValueError(f"obstacles must be an increasing range inside [0, 12], got {self.obstacles}")
        if not self.objectives or any(o not in OBJECTIVES for o in self.objectives):
            raise ValueError(f"objectives must be a non-empty subset of {OBJECTIVES}, got {self.objectives}")
        if self.n_float < 0 or self.workers < 1:
            raise ValueError("n_float must be >= 0 and workers >= 1")
        from planner.inference import check_views

        check_views(self.views, self.view_spread_k)
        if self.log_direction_deg is not None and not -180.0 <= self.log_direction_deg <= 180.0:
            raise ValueError(f"log_direction_deg must be in [-180, 180] deg or None, got {self.log_direction_deg}")

    def scan_key(self) -> dict:
        """The settings a twin scan depends on (a kept one is reused only when they agree)."""
        return {"logs": list(self.logs), "obstacles": list(self.obstacles), "n_float": self.n_float,
                "grid": list(self.grid)}

    def reconstruction_key(self, planner_config: Any) -> dict:
        """The settings a kept scan's reconstruction depends on besides the scan: the re-render's
        grid (the network's), the pile frame's turn and the fitting's revision."""
        return {"render_size_px": planner_config.size_px, "render_extent_m": planner_config.extent_m,
                "log_direction_deg": self.log_direction_deg, "fit_revision": FIT_REVISION}


# -- frames ------------------------------------------------------------------------------------
def grasp_to_truth_frame(grasp: Any, recon: Any, truth: Any) -> Any:
    """A :class:`synth.geometry.grasp.Grasp` in ``recon``'s pile frame expressed in ``truth``'s pile frame
    through both piles' georeferences (the site frame when the origins agree, else geodetic
    coordinates). The grasp centre sits on the reconstructed terrain; the angle follows the
    closing axis (pi-periodic); the width is kept."""
    from synth.geometry import geodesy
    from synth.geometry.grasp import Grasp

    if recon.georef is None or truth.georef is None:
        raise FieldError("both piles need a georeference to compare grasps across their frames; "
                         "reconstruct with a scan pose and generate the truth with a site")
    z = float(recon.terrain.height_at(grasp.x_m, grasp.y_m))
    a = grasp.closing_axis()
    p = np.array([[grasp.x_m, grasp.y_m, z], [grasp.x_m + a[0], grasp.y_m + a[1], z]])
    g_r, g_t = recon.georef, truth.georef
    if (abs(g_r.origin_lat_deg - g_t.origin_lat_deg) < 1e-12 and abs(g_r.origin_lon_deg - g_t.origin_lon_deg) < 1e-12
            and abs(g_r.origin_h_m - g_t.origin_h_m) < 1e-9):
        q = geodesy.site_to_pile(g_t, geodesy.pile_to_site(g_r, p))
    else:
        lat, lon, h = geodesy.pile_to_geodetic(g_r, p)
        q = geodesy.geodetic_to_pile(g_t, lat, lon, h)
    q = np.asarray(q, dtype=float).reshape(2, 3)
    d = q[1, :2] - q[0, :2]
    return Grasp(float(q[0, 0]), float(q[0, 1]), math.atan2(d[1], d[0]), grasp.width_m)


def _angle_diff_deg(a: float, b: float) -> float:
    """Difference of two pi-periodic grasp angles [deg], in [0, 90]."""
    d = (a - b + math.pi / 2) % math.pi - math.pi / 2
    return abs(math.degrees(d))


# -- one pile ----------------------------------------------------------------------------------
def render_truth(truth: Any, size_px: int) -> Any:
    """The true pile's orthographic render with the reconstruction's render settings."""
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    with World(truth) as world:
        return render_ortho(world, OrthoRenderConfig(size_px=size_px, n_renders=3), seed=0)


def execute_on_truth(truth: Any, grasp: Any, targets: tuple[int, ...]) -> dict:
    """Run ``grasp`` (truth frame) for ``targets`` (true log indices) on the TRUE pile
    (:func:`synth.physics.trial.run_trial`, ``TrialConfig.fast()``): success, outcome, logs held, cos beta, CPU."""
    from synth.physics.trial import TrialConfig, run_trial

    res = run_trial(truth, grasp, targets, TrialConfig.fast())
    return {"success": res.success, "outcome": res.outcome.value, "grasped": list(res.grasped),
            "cos_beta": res.cos_beta, "cpu_s": res.cpu_time_s}


@dataclass
class RealTestCase:
    """One twin scan, ready to plan on: the truth and its render, the reconstruction (None when it
    failed: ``recon_error`` says why) with its re-render and report, and the log matching."""

    seed: int
    truth: Any  # PileSpec
    obs_truth: Any  # OrthoObservation of the truth (the reconstruction's render settings)
    recon: Any | None  # PileSpec
    obs_recon: Any | None  # OrthoObservation (ortho.npz of the reconstruction)
    report: dict | None  # the reconstruction's report.json
    match: dict  # reconstructed log index -> true log index
    recon_error: str | None
    cpu_s: dict  # scan_s, reconstruct_s, render_s [s]

    def base_row(self) -> dict:
        row = {"seed": self.seed, "n_logs": self.truth.n_logs,
               "n_obstacles": len(self.truth.stumps) + len(self.truth.rocks)}
        if self.recon is not None:
            row.update({"n_matched_logs": len(self.match), "recon_extent_m": float(self.obs_recon.extent_m),
                        "recon_obstacles": len(self.recon.stumps) + len(self.recon.rocks)})
        return row

    def recon_to_truth(self, grasp: Any, targets) -> tuple[Any, list[int | None]]:
        """A grasp planned on the reconstruction in the truth's frame, and its targets as true log
        indices (None: a log without a true match)."""
        return grasp_to_truth_frame(grasp, self.recon, self.truth), [self.match.get(i) for i in targets]


def prepare_case(seed: int, work_dir: str | Path, planner_config: Any, cfg: RealTestConfig) -> RealTestCase:
    """Make (or reuse) twin scan ``seed`` and its reconstruction in ``work_dir`` and render the truth.
    ``planner_config``: the network's :class:`planner.model.UNetConfig` (the re-render's grid).

    The scan and its reconstruction stay in ``work_dir`` (``scan_SEED``, ``recon_SEED``, and
    ``scan_SEED.key.json`` with the settings they were made with, written once both are done): a
    later run with the same scan settings reuses the scan, and with the same reconstruction
    settings (:meth:`RealTestConfig.reconstruction_key`) the reconstruction, so trying another
    planner on the same scans costs only the planning and the trials."""
    from planner.errors import ObservationError
    from planner.inference import check_grid
    from reconstruct.compare import compare_piles
    from reconstruct.errors import ReconstructError
    from reconstruct.config import ReconstructConfig
    from reconstruct.report import read_report
    from reconstruct.pipeline import reconstruct
    from reconstruct.scan.twin_scan import make_twin_scan
    from synth.common.files import atomic_write_bytes
    from synth.scene.pile import read_pile
    from synth.render.ortho import OrthoObservation

    work = Path(work_dir)
    c0 = time.process_time()
    scan_root, recon_dir = work / f"scan_{seed}", work / f"recon_{seed}"
    key_path, error_path = work / f"scan_{seed}.key.json", work / f"recon_{seed}.error.txt"
    size = planner_config.size_px
    scan_key, recon_key = cfg.scan_key(), cfg.reconstruction_key(planner_config)
    old = json.loads(key_path.read_text()) if key_path.exists() else None
    old = None if old is None else {"render_extent_m": 5.0, "log_direction_deg": None, "fit_revision": 1,
                                    **old}  # keys before them
    kept_scan = (old is not None and all(old.get(k) == v for k, v in scan_key.items())
                 and (scan_root / "scan").is_dir() and (scan_root / "gnss.csv").is_file())  # not only its truth
    kept = kept_scan and all(old.get(k) == v for k, v in recon_key.items())  # the reconstruction too
    if not kept:
        shutil.rmtree(recon_dir, ignore_errors=True)
        error_path.unlink(missing_ok=True)
    if not kept_scan:
        shutil.rmtree(scan_root, ignore_errors=True)
        make_twin_scan(scan_root, seed, logs=cfg.logs, obstacles=cfg.obstacles, n_float=cfg.n_float, grid=cfg.grid)
    truth = read_pile(scan_root / "truth" / "pile.json")
    cpu = {"scan_s": time.process_time() - c0}
    c0 = time.process_time()
    recon = obs_r = report = None
    recon_error = None
    if kept and (recon_dir / "report.json").exists():  # the report is written last: a whole reconstruction
        obs_r = OrthoObservation.load(recon_dir / "ortho.npz")
        try:
            check_grid(obs_r.depth.shape[0], obs_r.extent_m, planner_config)
            recon = read_pile(recon_dir / "pile.json")
            report = read_report(recon_dir)
        except ObservationError:  # kept from before re-renders kept the network's pitch: made again
            obs_r = None
            shutil.rmtree(recon_dir)
    elif kept and error_path.exists():
        recon_error = error_path.read_text()
    if recon is None and recon_error is None:
        try:
            res = reconstruct(scan_root / "scan", scan_root / "gnss.csv", recon_dir,
                              ReconstructConfig(allow_float=cfg.n_float > 0, render_size_px=size,
                                                render_extent_m=planner_config.extent_m,
                                                log_direction_deg=cfg.log_direction_deg))
            recon, report = res.pile, res.report
            obs_r = OrthoObservation.load(res.files["ortho"])
        except ReconstructError as exc:
            recon_error = str(exc)
            atomic_write_bytes(error_path, recon_error.encode())
        atomic_write_bytes(key_path, json.dumps({**scan_key, **recon_key}).encode())
    cpu["reconstruct_s"] = time.process_time() - c0
    match: dict[int, int] = {}
    if recon is not None:
        cmp = compare_piles(truth, recon, render=False)
        match = {e["recon_index"]: e["truth_index"] for e in cmp["logs"]}
    c0 = time.process_time()
    obs_t = render_truth(truth, planner_config.size_px)
    cpu["render_s"] = time.process_time() - c0
    return RealTestCase(seed, truth, obs_t, recon, obs_r, report, match, recon_error, cpu)


def real_test_pile(seed: int, work_dir: str | Path, planner: Any, cfg: RealTestConfig) -> list[dict]:
    """The real test on one twin scan (``seed``): one row per objective (see the module
    docstring). ``planner``: a loaded :class:`planner.inference.Planner`. Scans and
    reconstructions are kept in ``work_dir`` and reused (:func:`prepare_case`)."""
    from planner.errors import PlannerError
    from planner.inference import Objective, plan

    case = prepare_case(seed, work_dir, planner.config, cfg)
    truth, obs_t, recon, obs_r = case.truth, case.obs_truth, case.recon, case.obs_recon
    base = case.base_row()
    rows = []
    for kind in cfg.objectives:
        row: dict[str, Any] = {**base, "objective": kind, "recon_error": case.recon_error}
        c0 = time.process_time()
        try:
            best_t = plan(obs_t, planner, Objective(kind=kind), top_k=1, pile=truth).best
        except PlannerError as exc:
            best_t, row["truth_plan_error"] = None, str(exc)
        best_r = None
        if obs_r is not None:
            try:
                best_r = plan(obs_r, planner, Objective(kind=kind), top_k=1, pile=recon).best
            except PlannerError as exc:
                row["recon_plan_error"] = str(exc)
        row["plan_cpu_s"] = time.process_time() - c0
        c0 = time.process_time()
        if best_t is not None:
            row["truth"] = {"grasp": best_t.grasp.to_dict(), "targets": list(best_t.targets),
                            **_execute_row(truth, best_t.grasp, best_t.targets)}
        if best_r is not None:
            g, targets = case.recon_to_truth(best_r.grasp, best_r.targets)
            entry = {"grasp": g.to_dict(), "grasp_recon_frame": best_r.grasp.to_dict(),
                     "recon_targets": list(best_r.targets), "targets": targets}
            if any(t is None for t in targets):
                entry.update({"success": False, "outcome": "unmatched_target", "grasped": []})
            else:
                entry.update(_execute_row(truth, g, tuple(targets)))
            row["recon"] = entry
        row["trial_cpu_s"] = time.process_time() - c0
        if best_t is not None and best_r is not None:
            gt, gr = row["truth"]["grasp"], row["recon"]["grasp"]
            row["diff"] = {
                "position_m": math.hypot(gt["x_m"] - gr["x_m"], gt["y_m"] - gr["y_m"]),
                "angle_deg": _angle_diff_deg(gt["phi_rad"], gr["phi_rad"]),
                "width_m": gr["width_m"] - gt["width_m"],
                "same_targets": sorted(row["truth"]["targets"]) == sorted(t for t in row["recon"]["targets"] if t is not None)
                and None not in row["recon"]["targets"],
            }
        row["cpu_s"] = dict(case.cpu_s)
        rows.append(row)
    return rows


def _execute_row(truth: Any, grasp: Any, targets) -> dict:
    """:func:`execute_on_truth` as the real test's rows have stored it (no cos beta)."""
    r = execute_on_truth(truth, grasp, tuple(targets))
    r.pop("cos_beta")
    return r


# -- many piles ----------------------------------------------------------------------------------
_WORKER: dict = {}


def model_path(cfg: RealTestConfig) -> Path:
    """The checkpoint the real test plans with: its own, or the shipped default."""
    from planner.checkpoint import DEFAULT_MODEL

    return Path(cfg.model or DEFAULT_MODEL)


def _worker_planner(model: str, threads: int | None, views: int, view_spread_k: float):
    """This process's planner, loaded once (a pool worker keeps it for all its piles)."""
    key = (model, threads, views, view_spread_k)
    if _WORKER.get("key") != key:
        from planner.inference import load_planner

        if threads is not None:
            import torch

            torch.set_num_threads(threads)
        _WORKER["planner"] = load_planner(model, device="cpu", views=views, view_spread_k=view_spread_k)
        _WORKER["key"] = key
    return _WORKER["planner"]


def _worker_pile(seed: int, work_dir: str, cfg: RealTestConfig, model: str, threads: int | None) -> list[dict]:
    planner = _worker_planner(model, threads, cfg.views, cfg.view_spread_k)
    return real_test_pile(seed, work_dir, planner, cfg)


def _record(cfg: RealTestConfig, model: Path, model_sha: str, rows: list[dict], failures: list[str],
            wall_s: float, cpu_s: float) -> dict:
    rows = sorted(rows, key=lambda r: (r["seed"], r["objective"]))
    return {
        "format": REAL_TEST_FORMAT, "format_version": REAL_TEST_VERSION,
        "config": asdict(cfg), "model": {"path": str(model), "sha256": model_sha},
        "fit_revision": FIT_REVISION, "rows": rows, "failures": failures,
        "piles_done": len({r["seed"] for r in rows}),
        "summary": {kind: summarize([r for r in rows if r["objective"] == kind]) for kind in cfg.objectives},
        "wall_s": wall_s, "cpu_s_main_process": cpu_s,
    }


def _same_test(old: dict, cfg: RealTestConfig, model_sha: str) -> bool:
    """Whether a stored record ran the same test (all settings but n_piles and workers, same model)."""
    mine = {k: v for k, v in json.loads(json.dumps(asdict(cfg))).items() if k not in ("n_piles", "workers", "model")}
    theirs = {k: v for k, v in old.get("config", {}).items() if k not in ("n_piles", "workers", "model")}
    theirs.setdefault("views", 1)  # records from before test-time views planned with one view
    theirs.setdefault("view_spread_k", 0.0)
    theirs.setdefault("log_direction_deg", None)  # and reconstructed in site axes
    return (mine == theirs and old.get("model", {}).get("sha256") == model_sha
            and old.get("fit_revision", 1) == FIT_REVISION)  # and the piles were fitted alike


def run_real_test(cfg: RealTestConfig | None = None, work_dir: str | Path | None = None,
                  progress: Callable[[str], None] | None = None, record_path: str | Path | None = None) -> dict:
    """Run the real test on ``cfg.n_piles`` twin scans; returns the record (rows + summary).

    ``work_dir``: where scans and reconstructions go (a temporary folder, removed, when None); kept
    ones made with the same scan settings are reused (:func:`real_test_pile`).
    ``record_path``: the record is written there after every pile (an interrupted run keeps what
    it measured), and a record already there from the same test and the same model (by its
    sha256) is resumed: its piles are not run again."""
    from synth.common.files import sha256_file

    cfg = cfg or RealTestConfig()
    say = progress or (lambda s: None)
    model = model_path(cfg)
    if not model.exists():
        raise FieldError(f"planner model {model} not found; pass --model PATH to a checkpoint")
    model_sha = sha256_file(model)
    t0, c0 = time.perf_counter(), time.process_time()
    seeds = [cfg.seed + k for k in range(cfg.n_piles)]
    rows: list[dict] = []
    failures: list[str] = []
    if record_path is not None and Path(record_path).exists():
        old = read_real_test(record_path)
        if _same_test(old, cfg, model_sha):
            rows = [r for r in old["rows"] if r["seed"] in seeds]
            failures = [f for f in old.get("failures", []) if int(f.split()[1].rstrip(":")) in seeds]
            done = {r["seed"] for r in rows} | {int(f.split()[1].rstrip(":")) for f in failures}
            say(f"resuming {record_path}: {len(done)} piles done")
            seeds = [s for s in seeds if s not in done]

    def save() -> None:
        if record_path is not None:
            write_real_test(_record(cfg, model, model_sha, rows, failures, time.perf_counter() - t0,
                                    time.process_time() - c0), record_path)

    tmp = None
    if work_dir is None:
        tmp = tempfile.mkdtemp(prefix="loggrasp-real-test-")
        work_dir = tmp
    Path(work_dir).mkdir(parents=True, exist_ok=True)
    try:
        threads = None if cfg.workers == 1 or len(seeds) == 1 else 1  # one torch thread a pool worker
        tasks = {seed: (seed, str(work_dir), cfg, str(model), threads) for seed in seeds}
        n_done = 0

        def finished(seed: int, pile_rows: list[dict]) -> None:
            nonlocal n_done
            rows.extend(pile_rows)
            save()
            n_done += 1
            say(f"pile {n_done}/{len(seeds)} (seed {seed}) done")

        def failed(seed: int, exc: Exception) -> None:  # a pile the generator or the twin could not make
            failures.append(f"seed {seed}: {type(exc).__name__}: {exc}")
            finished(seed, [])

        run_tasks(_worker_pile, tasks, finished, workers=cfg.workers, on_error=failed)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    rec = _record(cfg, model, model_sha, rows, failures, time.perf_counter() - t0, time.process_time() - c0)
    save()
    return rec


def summarize(rows: list[dict]) -> dict:
    """Success rates, their difference and the grasp differences over rows of one objective.

    Piles whose truth plan failed (no grasp) are left out; a failed reconstruction or plan on
    it counts as a failed grasp."""
    rows = [r for r in rows if "truth" in r]
    n = len(rows)
    if n == 0:
        return {"n_piles": 0}
    s_t = np.array([bool(r["truth"]["success"]) for r in rows], dtype=float)
    s_r = np.array([bool(r.get("recon", {}).get("success", False)) for r in rows], dtype=float)
    p_t, p_r = float(s_t.mean()), float(s_r.mean())
    se_diff = paired_se(s_t, s_r)
    diffs = [r["diff"] for r in rows if "diff" in r]

    def stats(v: list[float]) -> dict:
        a = np.asarray(v, dtype=float)
        if a.size == 0:
            return {"median": None, "p90": None, "max": None}
        return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "max": float(a.max())}

    half95 = 1.96 * se_diff
    diff_pp = 100 * (p_r - p_t)
    if abs(diff_pp) + 100 * half95 <= 3.0:
        verdict = "within 3 pp (95 % interval inside +-3 pp)"
    elif abs(diff_pp) - 100 * half95 > 3.0:
        verdict = "NOT within 3 pp (95 % interval outside +-3 pp)"
    else:
        verdict = "not resolved at this number of piles (95 % interval wider than the 3 pp margin)"
    return {
        "n_piles": n,
        "success_truth": p_t, "success_truth_se": math.sqrt(p_t * (1 - p_t) / n),
        "success_recon": p_r, "success_recon_se": math.sqrt(p_r * (1 - p_r) / n),
        "difference_pp": diff_pp, "difference_se_pp": 100 * se_diff,
        "difference_ci95_pp": [diff_pp - 100 * half95, diff_pp + 100 * half95],
        "verdict": verdict,
        "outcome_agreement": float(np.mean(s_t == s_r)),
        "both_succeed": int(((s_t == 1) & (s_r == 1)).sum()), "only_truth": int(((s_t == 1) & (s_r == 0)).sum()),
        "only_recon": int(((s_t == 0) & (s_r == 1)).sum()), "neither": int(((s_t == 0) & (s_r == 0)).sum()),
        "reconstruction_failures": sum(r.get("recon_error") is not None for r in rows),
        "unmatched_targets": sum(r.get("recon", {}).get("outcome") == "unmatched_target" for r in rows),
        "same_targets": (float(np.mean([x["same_targets"] for x in diffs])) if diffs else None),
        "position_diff_m": stats([x["position_m"] for x in diffs]),
        "angle_diff_deg": stats([x["angle_deg"] for x in diffs]),
        "abs_width_diff_m": stats([abs(x["width_m"]) for x in diffs]),
        "position_diff_same_targets_m": stats([x["position_m"] for x in diffs if x["same_targets"]]),
        "angle_diff_same_targets_deg": stats([x["angle_deg"] for x in diffs if x["same_targets"]]),
    }


# -- the record --------------------------------------------------------------------------------
def write_real_test(record: dict, path: str | Path) -> Path:
    """Write a :func:`run_real_test` record as JSON, atomically. Returns the path."""
    from synth.common.files import atomic_write_bytes

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, json.dumps(record, indent=1, default=float).encode())
    return path


def read_real_test(path: str | Path) -> dict:
    """Read a record written by :func:`write_real_test` (format and major version checked)."""
    return REAL_TEST.read(path)
