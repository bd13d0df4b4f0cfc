"""A field trial: scan + RTK endpoints → reconstructed pile → plan → GNSS grasp → crane.

:func:`prepare_trial` does everything up to the command (reconstruction, planning, the grasp in
SWEREF 99 TM, the safety checks, pictures and GeoJSON); :func:`execute_trial` sends it over a
crane link and waits for the acknowledgement and the outcome. :mod:`field.trial_record` probes the
link first, then does both and writes the *trial record*, and replays one.

With a ``zenoh://`` link the plan and the sent grasp are also published as ROS 2 messages
(:mod:`field.ros2`).

Nothing unsafe is sent: no RTK fix (the survey reader refuses float/no-fix points unless
allowed), a grasp out of reach or over the lift capacity, stale pile data, an operator who does
not confirm — each stops with a clear :class:`TrialAborted` before anything goes on the link.

Verified planning (``TrialOptions.verify_k`` > 0, the default): before anything is shown or sent,
the twin tries the plan's best grasps on the reconstructed pile (:mod:`planner.verify`) and the
command carries the best one that succeeded there. When none did, nothing is sent
(:class:`NotVerified`, with every candidate's outcome) unless the operator explicitly names a plan
rank (``operator_rank``); that grasp is then sent marked *not verified* in the summary and the
record. A verification stopped by its time budget chooses only among the candidates it checked and
says which those were. The record stores every verification trial (``verification`` in
``record.json`` and ``plan/verification.json``); :func:`field.trial_record.replay_record` runs
them again without the budget and compares them trial by trial, bit for bit but for their times.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from field.errors import FieldError
from field.link.messages import GraspCommand
from field.trial_options import TrialOptions



class TrialAborted(FieldError):
    """The trial stopped before or instead of sending a command; the message says why.

    ``kind`` says whose move it is: ``"input"`` (a scan, survey or model that cannot be used: fix
    the file or flag), ``"link"`` (the crane link: URL, controller unreachable or not ready),
    ``"refused"`` (a safety check: stale data, reach, lift capacity, no grasp), ``"declined"``
    (the operator said no or gave no answer) or ``"interrupted"`` (Ctrl-C)."""

    def __init__(self, message: str, kind: str = "refused", verification=None, plan=None):
        super().__init__(message)
        self.kind = kind
        self.verification = verification  # planner.verify.Verification when the twin's trials ran
        self.plan = plan  # the planner.inference.Plan those trials were of


class NotVerified(TrialAborted):
    """No grasp the twin checked on the reconstruction succeeded (``verification`` says what each
    did), and the operator did not name a plan rank to send anyway."""

    def __init__(self, message: str, verification, plan=None) -> None:
        super().__init__(message, kind="refused", verification=verification, plan=plan)


#: why a crane controller rejects a command (``RejectReason`` name -> what to do), for the record
#: and the operator
REJECT_EXPLANATIONS = {
    "STALE": "the pile data is older than the crane controller accepts (the crane's own limit: "
             "crane-sim --max-pile-age, twin://?crane_max_pile_age_s=S, or a real crane's configuration; "
             "trial --max-pile-age sets only the laptop's check): scan the pile again",
    "OUT_OF_REACH": "the grasp point is outside the crane's reach envelope (its base and reach: crane-sim "
                    "--base/--max-reach, twin://?crane_base=E,N,H&crane_max_reach_m=M, or a real crane's "
                    "configuration): move the crane or check --base",
    "WIDTH_RANGE": "the opening width is outside the grapple's range",
    "HEADING_RANGE": "the heading is outside the rotator's accepted range",
    "BUSY": "the crane is executing another command: wait for it and send a new trial",
    "ESTOP": "the crane is in emergency stop: reset it on the crane",
    "FAULT": "the crane controller is in FAULT: reset it on the crane",
    "DUPLICATE_ID": "the command id was already used: start a new trial",
    "COUNTER": "frames were lost or reordered on the link: check the link and start a new trial",
    "CRC": "a frame was corrupted on the link: check the link and start a new trial",
    "MALFORMED": "the crane could not read the command (protocol version or impossible values)",
    "UNSUPERVISED": "the crane heard no live heartbeat from this laptop: check the link and start a new trial",
}


@dataclass
class PreparedTrial:
    pile: object  # PileSpec (georeferenced)
    plan: object  # planner.inference.Plan
    geo: object  # field.geo.GraspGeo of the chosen grasp
    command_fields: dict  # GraspCommand fields except the id
    captured_utc_s: float  # when the pile data was captured [s since epoch]
    work_dir: Path
    report: dict = field(default_factory=dict)
    verification: object | None = None  # planner.verify.Verification; None: verification off
    chosen: object | None = None  # the PlannedGrasp the command carries; None = the plan's best

    @property
    def best(self):
        """The grasp the command carries: the verified one, the operator's choice, or the plan's best."""
        return self.chosen if self.chosen is not None else self.plan.best

    @property
    def chosen_rank(self) -> int:
        """The plan rank (1 = the network's best) of the grasp the command carries."""
        if self.chosen is None:
            return 1
        return next(i for i, g in enumerate(self.plan.grasps) if g is self.best) + 1

    @property
    def verified(self) -> bool:
        """Whether the command carries a grasp the twin checked and chose."""
        v = self.verification
        return v is not None and v.chosen is not None and v.chosen.planned is self.best

    def verification_lines(self) -> list[str]:
        """What the twin said about the grasp to be sent, first in the summary."""
        v = self.verification
        if v is None:
            return ["not verified in the twin (verification off)"
                    + (f"; plan rank {self.chosen_rank}, the operator's choice" if self.chosen_rank != 1 else "")]
        if self.verified:
            return [v.reason]
        rank = self.chosen_rank
        check = next((c for c in v.candidates if c.rank == rank - 1), None)
        twin = ("the twin did not try it" if check is None or not check.trials
                else f"in the twin it ended {check.outcome}" if check.checked
                else f"its twin trials were cut short ({check.status}, {check.outcome})")
        return [f"WARNING: NOT VERIFIED: {v.reason}",
                f"WARNING: sending plan rank {rank}, the operator's explicit choice (--send-rank); {twin}"]

    def summary_lines(self) -> list[str]:
        best = self.best
        g = self.geo
        return self.verification_lines() + [
            f"targets: logs {list(best.targets)} ({len(best.targets)} of {self.pile.n_logs})",
            f"quality q={best.quality:.3f}  graspability u={best.graspability:.3f}  balance b={best.balance:.3f}",
            f"SWEREF 99 TM  E {g.easting_m:.3f}  N {g.northing_m:.3f}  h {g.h_ell_m:.3f} m (ellipsoidal)",
            f"heading (closing axis) {g.heading_grid_deg:.2f}° from grid north, "
            f"{g.heading_true_deg:.2f}° from true north",
            f"opening width {g.width_m:.3f} m",
        ] + [f"WARNING: {w}" for w in self.warnings()]

    def warnings(self) -> list[str]:
        """What the operator should check before confirming: target logs the scan hardly showed,
        the survey reader's warnings, plan constraints that removed or moved grasps."""
        out = [f"target log {i} was {how} (the reconstruction's report says how it was placed); "
               "check it on the pile before confirming" for i, how in self.doubtful_targets()]
        out += [f"GNSS survey: {w}" for w in self.report.get("survey_warnings", [])]
        for r in getattr(self.plan, "rejected", None) or []:
            if isinstance(r, dict) and r.get("action") == "removed":
                out.append(f"targets {r.get('targets')}: no grasp ({r.get('constraint')}: {r.get('detail')})")
        return out

    def doubtful_targets(self) -> list[tuple[int, str]]:
        """Target logs the scan showed only in part or not at all, or with an end placed on a weak
        estimate (an RTK float point the scan does not see, a survey point it contradicts, an end
        inferred): (index, how it was placed)."""
        fits = self.report.get("log_fits", [])
        weak = self.report.get("log_weak_ends", [])
        words = {"partial": "seen only in part (its radius from the visible top)",
                 "hidden": "hidden under other logs (diameter estimated, no scan points on it)"}
        out = []
        for i in self.best.targets:
            if i < len(fits) and fits[i] in words:
                out.append((i, words[fits[i]]))
            elif i < len(weak) and weak[i]:
                out.append((i, "placed on a weak estimate at " + ", ".join(weak[i])))
        return out


def captured_time(scan_dir: Path, gnss_path: Path) -> float:
    """When the pile data was captured: the scan's ``captured_utc`` (pair meta.json) if present,
    else the newest input file's modification time."""
    import datetime as dt

    for meta in sorted(scan_dir.rglob("meta.json")):
        try:
            d = json.loads(meta.read_text())
        except (OSError, ValueError):
            continue
        if "captured_utc" in d:
            return dt.datetime.fromisoformat(str(d["captured_utc"]).replace("Z", "+00:00")).timestamp()
    times = [p.stat().st_mtime for p in [*scan_dir.rglob("*.png"), gnss_path] if p.exists()]
    return max(times) if times else time.time()


def verify_trial_plan(the_plan, pile, options: TrialOptions, fits=(), recorded: dict | None = None,
                      say: Callable[[str], None] | None = None, end_sigmas_m=None):
    """The twin's verification of ``the_plan`` on ``pile`` (the reconstruction) with the options'
    settings (:func:`planner.verify.verify_plan`); ``fits``: the reconstruction's fit class of each
    log and ``end_sigmas_m`` its less certain end's sigma (per-log perturbation sigmas).

    ``recorded`` (a replay): the verification a trial record stores. The trials then run without a
    time budget and without pruning (so every trial the record holds runs again, whatever order
    the workers finish in), and the grasp is chosen by the same rule among the candidates the
    record checked: the record's own decision, reproduced from its own evidence.

    Raises :class:`TrialAborted` (``kind="input"``) for a pile the twin cannot use or a budget that
    ran out before one candidate was checked (with the trials that did run)."""
    from dataclasses import replace

    from planner.verify import (VerificationBudgetError, VerificationError, choose, measured_quality,
                                verify_plan)

    say = say or (lambda s: None)
    objective = options.objective_spec()
    ok = len(fits) == pile.n_logs
    cfg = options.verify_config(tuple(fits) if ok else (),
                                tuple(end_sigmas_m) if ok and end_sigmas_m is not None else None)
    if recorded is not None:
        cfg = replace(cfg, time_budget_s=None, prune=False)
    budget = "no time limit" if cfg.time_budget_s is None else f"{cfg.time_budget_s:g} s"
    copies = f", each also on {cfg.perturbation.copies} perturbed copies" if cfg.perturbation.copies else ""
    say(f"verifying: the twin tries the best {cfg.k} grasps on the reconstructed pile{copies} ({budget})")
    try:
        v = verify_plan(the_plan, pile, objective, cfg)
    except VerificationBudgetError as exc:
        n = len(exc.verification.candidates)
        raise TrialAborted(f"nothing was sent: the verification's time budget (verify_budget_s {cfg.time_budget_s:g} "
                           f"s) ran out before any of the {n} candidates was checked (one needs a twin trial on the "
                           "pile and on every perturbed copy); give a larger verify_budget_s, fewer verify_copies or "
                           "more verify_workers", kind="input", verification=exc.verification, plan=the_plan) from exc
    except VerificationError as exc:
        raise TrialAborted(f"verification failed: {exc}", kind="input", plan=the_plan) from exc
    if recorded is not None:
        ranks = {c["rank"] for c in recorded.get("candidates", []) if c.get("status") == "checked"}
        chosen = choose([c for c in v.candidates if c.rank in ranks], objective)
        v = replace(v, chosen=chosen, chosen_quality=(math.nan if chosen is None
                                                      else measured_quality(objective, chosen.nominal.result)))
    say(v.reason)
    return v


def prepare_trial(scan_dir: str | Path, gnss_path: str | Path, work_dir: str | Path, options: TrialOptions,
                  progress: Callable[[str], None] | None = None, now: float | None = None,
                  recorded_verification: dict | None = None, view=None) -> PreparedTrial:
    """Reconstruct, plan, verify in the twin, convert to SWEREF 99 TM and check safety. Raises
    :class:`TrialAborted` (:class:`NotVerified` when no checked grasp succeeded in the twin and
    the operator named no plan rank). ``recorded_verification``: a replay's recorded verification
    (:func:`verify_trial_plan`). ``view``: a :class:`field.trial_view.TrialView` each stage is
    logged to as it finishes."""
    from field.geo import grasp_to_gnss
    from reconstruct.report import log_end_sigmas

    say = progress or (lambda s: None)
    scan_dir, gnss_path, work = Path(scan_dir), Path(gnss_path), Path(work_dir)
    captured, age = _check_age(scan_dir, gnss_path, options, time.time() if now is None else now)
    planner, ranker = _load_trial_planner(options)  # first: a model that cannot load stops before the reconstruction
    result = _reconstruct_for(planner, scan_dir, gnss_path, work, options, say)
    pile, obs = result.pile, result.observation  # as written to reconstruction/ortho.npz, not read back
    if view is not None:
        view.reconstructed(result, captured)
    constraints = _constraints_for(pile, options)
    the_plan = _plan_subsets(obs, planner, ranker, pile, constraints, options, say)
    if view is not None:
        view.planned(the_plan, pile)
    log_fits = [log.get("fit", "scan") for log in result.report.get("logs", [])]
    try:
        best, verification = _choose_grasp(the_plan, pile, options, log_fits, recorded_verification, say,
                                           log_end_sigmas(result.report))
    except TrialAborted as exc:
        if view is not None:
            view.verified(exc.verification, pile)
        raise
    if view is not None:
        view.verified(verification, pile)
        view.chosen(best, pile, time.time())
    z = float(pile.terrain.height_at(best.grasp.x_m, best.grasp.y_m))
    geo = grasp_to_gnss(best.grasp, pile.georef, z)
    command = GraspCommand.from_grasp_geo(1, geo, len(best.targets), captured)  # the id is the link's, at sending
    command_fields = {k: v for k, v in asdict(command).items() if k != "command_id"}
    _write_plan_outputs(work / "plan", obs, the_plan, pile, best, verification, constraints, options)
    return PreparedTrial(pile=pile, plan=the_plan, geo=geo, command_fields=command_fields,
                         captured_utc_s=captured, work_dir=work,
                         report={"pile_age_s": age, "survey_warnings": list(result.report.get("survey_warnings", [])),
                                 "log_fits": log_fits, "log_weak_ends": weak_ends_by_log(result.report)},
                         verification=verification, chosen=best)


def _check_age(scan_dir: Path, gnss_path: Path, options: TrialOptions, now: float) -> tuple[float, float]:
    """(captured time, age) of the pile data [s]; refused over ``options.max_pile_age_s``."""
    captured = captured_time(scan_dir, gnss_path)
    age = now - captured
    if age > options.max_pile_age_s:
        raise TrialAborted(f"the pile data is {age:.0f} s old (captured {time.ctime(captured)}), over the "
                           f"{options.max_pile_age_s:.0f} s limit (--max-pile-age): scan the pile again before "
                           "grasping",
                           kind="refused")
    return captured, age


def _load_trial_planner(options: TrialOptions):
    """(the network, the ranker or None) the options name."""
    from planner.checkpoint import DEFAULT_MODEL, DEFAULT_RANKER
    from planner.errors import PlannerError
    from planner.inference import load_planner
    from planner.ranker import load_ranker

    try:
        net = load_planner(options.model or DEFAULT_MODEL, precision=options.precision, views=options.views,
                           view_spread_k=options.view_spread_k)
        return net, (load_ranker(options.ranker or DEFAULT_RANKER) if options.rerank else None)
    except (PlannerError, ValueError) as exc:  # ValueError: a precision this machine cannot run
        raise TrialAborted(f"planning failed: {exc}", kind="input") from exc


def _reconstruct_for(planner, scan_dir: Path, gnss_path: Path, work: Path, options: TrialOptions, say):
    """The reconstruction, re-rendered at the network's pixel pitch, into ``work/reconstruction``."""
    from reconstruct.errors import ReconstructError
    from reconstruct.config import ReconstructConfig
    from reconstruct.pipeline import reconstruct
    from synth.errors import SynthError

    say("reconstructing the pile from the scan and the RTK endpoints")
    try:
        return reconstruct(scan_dir, gnss_path, work / "reconstruction",
                           ReconstructConfig(allow_float=options.allow_float, render_size_px=planner.config.size_px,
                                             render_extent_m=planner.config.extent_m), progress=say)
    except (ReconstructError, SynthError, ValueError) as exc:
        raise TrialAborted(f"reconstruction failed: {exc}", kind="input") from exc


def _constraints_for(pile, options: TrialOptions):
    """Lift capacity, obstacles under the claws, and the reach from the crane base when it is known."""
    from planner.constraints import Constraints
    from synth.geometry.geodesy import sweref_tm_to_pile

    common = dict(lift_capacity_kg=options.lift_capacity_kg, wood_density_kg_m3=options.wood_density_kg_m3,
                  clear_obstacles=options.clear_obstacles, claw_plate_m=options.claw_plate_m,
                  claw_width_m=options.claw_width_m)
    if options.crane_base_tm is None:
        return Constraints(**common)
    e, n, h = options.crane_base_tm
    base_pile = np.asarray(sweref_tm_to_pile(pile.georef, e, n, h), dtype=float).reshape(3)
    return Constraints(crane_base_xy_m=(float(base_pile[0]), float(base_pile[1])),
                       min_reach_m=options.min_reach_m, max_reach_m=options.max_reach_m, **common)


def _plan_subsets(obs, planner, ranker, pile, constraints, options: TrialOptions, say):
    """Every target subset through the network, the best re-scored by ``ranker`` (when not None);
    refused when no grasp satisfies the constraints."""
    from planner.errors import PlannerError
    from planner.ranker import plan_reranked

    say("planning: every target subset through the network"
        + (f", the best {options.rerank_k} by f1 and by f3 re-scored by the grasp ranker" if ranker else ""))
    try:
        the_plan = plan_reranked(obs, planner, options.objective_spec(), ranker, constraints,
                                 top_k=max(10, options.verify_k, options.operator_rank or 0),
                                 rerank_k=options.rerank_k, u_weight=options.ranker_u_weight, pile=pile)
    except (PlannerError, ValueError) as exc:  # ValueError: a precision this machine cannot run
        raise TrialAborted(f"planning failed: {exc}", kind="input") from exc
    if the_plan.best is None:
        why = "; ".join(f"{r['targets']}: {r['constraint']}" for r in the_plan.rejected[:5])
        raise TrialAborted("no grasp satisfies the constraints (reach, lift capacity, keep-out)"
                           + (f": {why}" if why else ""), kind="refused")
    return the_plan


def _choose_grasp(the_plan, pile, options: TrialOptions, log_fits, recorded_verification, say, end_sigmas_m=None):
    """(the grasp to send, the verification or None): the best that succeeded in the twin, else the
    operator's named plan rank, else :class:`NotVerified`; the plan's best with verification off."""
    verification = None
    best = the_plan.best
    if options.verify_k:
        verification = verify_trial_plan(the_plan, pile, options, log_fits, recorded_verification, say, end_sigmas_m)
        if verification.ok:
            best = verification.grasp
            if options.operator_rank is not None:
                say(f"the operator's plan rank {options.operator_rank} is not used: plan rank "
                    f"{verification.chosen.rank + 1} succeeded in the twin and is sent")
        elif options.operator_rank is None:
            raise NotVerified(f"nothing was sent: {verification.reason}; to send a grasp anyway, name its plan "
                              "rank (operator_rank)", verification, the_plan)
    if options.operator_rank is not None and (verification is None or not verification.ok):
        if options.operator_rank > len(the_plan.grasps):
            raise TrialAborted(f"operator_rank {options.operator_rank}: the plan has only {len(the_plan.grasps)} "
                               "grasps", kind="input", verification=verification, plan=the_plan)
        best = the_plan.grasps[options.operator_rank - 1]
    return best, verification


def _write_plan_outputs(plan_dir: Path, obs, the_plan, pile, best, verification, constraints,
                        options: TrialOptions) -> None:
    """plan.json, the pictures, the GeoJSON pair and verification.json a person checks before sending."""
    from field.geo import draw_grasp_map, write_geojson_pair
    from planner.pictures import draw_plan
    from synth.common.files import atomic_write_bytes, dumps_json

    plan_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(plan_dir / "plan.json", the_plan.to_json().encode())
    draw_plan(obs, the_plan, plan_dir / "plan.png", pile=pile, objective=options.objective_spec(),
              constraints=constraints)
    write_geojson_pair(pile, plan_dir, grasp=best.grasp, plan_extra={"target_logs": list(best.targets)})
    draw_grasp_map(pile, best.grasp, plan_dir / "grasp_map.png", target_logs=best.targets)
    if verification is not None:
        atomic_write_bytes(plan_dir / "verification.json", dumps_json(verification.to_dict()).encode())


def weak_ends_by_log(report: dict) -> list[list[str]]:
    """Per log of a reconstruction report, its ends placed on a weak estimate
    (:meth:`reconstruct.fitting.fuse.EndEstimate.weak`), e.g. ``"end b (rtk_float, scan: open, +-23 cm)"``."""
    from reconstruct.fitting.fuse import FuseConfig

    limit = FuseConfig().weak_sigma_m
    return [[f"end {end} ({e['source']}, scan: {e['scan']}, +-{e['sigma_m'] * 100:.0f} cm"
             + (", its survey point contradicted" if e["contradicted"] else "") + ")"
             for end, e in zip("ab", log.get("ends") or []) if e["sigma_m"] > limit or e["contradicted"]]
            for log in report.get("logs", [])]


@dataclass
class TrialOutcome:
    command_id: int
    accepted: bool
    reject_reason: str | None
    outcome: dict | None
    final_state: str
    messages: list[dict]


def execute_trial(prepared: PreparedTrial, link_url: str, options: TrialOptions,
                  record_traffic: Path | None = None, say: Callable[[str], None] | None = None,
                  view=None) -> TrialOutcome:
    """Send the prepared command over ``link_url`` and follow it to its final state. A link that
    speaks ROS 2 (``zenoh://``) also publishes the plan and the grasp as it is sent
    (:func:`field.ros2.publish_trial`); ``view`` logs the command when it is sent."""
    from field.errors import LinkError
    from field.link import open_link
    from field.link.base import LinkConfig
    from field.link.safety import SafetyConfig

    say = say or (lambda s: None)
    msgs: list[dict] = []

    def log(kind: str, **kw) -> None:
        msgs.append({"t_utc_s": time.time(), "kind": kind, **kw})

    cfg = LinkConfig(record_path=str(record_traffic) if record_traffic else None,
                     safety=SafetyConfig(max_pile_age_s=options.max_pile_age_s))
    try:
        link = open_link(link_url, cfg)
    except (LinkError, ValueError) as exc:
        raise TrialAborted(f"cannot open the crane link {link_url}: {exc}", kind="link") from exc
    with link:
        cid = link.new_command_id()
        cmd = GraspCommand(command_id=cid, **prepared.command_fields)
        log("command", **asdict(cmd))
        if view is not None:
            view.command(asdict(cmd), prepared.geo.to_dict(), msgs[-1]["t_utc_s"])
        ros2 = getattr(link, "ros2_publisher", None)
        if ros2 is not None and ros2() is not None:
            from field.ros2 import publish_trial

            publish_trial(ros2(), prepared, say)
        say(f"sending command {cid}")
        fate = link.execute(cmd, ack_timeout_s=options.ack_timeout_s, outcome_timeout_s=options.outcome_timeout_s)
        return _trial_outcome(fate, link, msgs, log, say)


def _trial_outcome(fate, link, msgs: list[dict], log: Callable[..., None], say: Callable[[str], None]) -> TrialOutcome:
    """What the record says: the controller's final state for the command (``CommandFate``)."""
    cid = fate.command_id
    for note in fate.notes:
        log("reconciled", note=note)
        say(f"NOTE: {note}")
    if link.laptops_heard > 1:
        log("second_laptop", laptops=link.laptops_heard)
        say(f"WARNING: the crane hears {link.laptops_heard} laptops; only one may command it")
    if fate.executed is None:
        log("unknown", summary=fate.summary)
        return TrialOutcome(cid, False, None, None, f"UNKNOWN: {fate.summary}", msgs)
    if not fate.executed:
        reason = None if fate.reason is None else fate.reason.name
        log("rejected" if reason else "not_executed", reason=reason, summary=fate.summary)
        return TrialOutcome(cid, False, reason, None, "REJECTED" if reason else f"NOT EXECUTED: {fate.summary}", msgs)
    log("ack", accepted=True)
    if fate.outcome is None:
        log("outcome_timeout", summary=fate.summary)
        return TrialOutcome(cid, True, None, None, f"OUTCOME UNKNOWN: {fate.summary}", msgs)
    out = fate.outcome
    od = {"class": out.outcome_class.name, "logs_grasped": out.logs_grasped, "cos_beta": out.balance_cos_milli / 1000.0}
    log("outcome", **od)
    return TrialOutcome(cid, True, None, od, out.outcome_class.name, msgs)


def software_versions() -> dict:
    import platform

    import synth

    v = {"loggrasp": synth.__version__, "python": platform.python_version()}
    try:
        import subprocess

        v["git"] = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                  cwd=Path(__file__).resolve().parents[1], timeout=5).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        v["git"] = None
    return v


def probe_link(link_url: str, options: TrialOptions) -> str:
    """Open the crane link, ask the controller for its status and close it again: called before
    the reconstruction so that a wrong URL or an unreachable crane stops the trial in seconds.
    Returns the controller's state name; raises :class:`TrialAborted` (``kind="link"``)."""
    from field.errors import LinkError
    from field.link import open_link
    from field.link.base import LinkConfig
    from field.link.safety import SafetyConfig

    try:
        with open_link(link_url, LinkConfig(safety=SafetyConfig(max_pile_age_s=options.max_pile_age_s))) as link:
            state = link.status(timeout_s=max(options.ack_timeout_s, 0.5)).state.name
    except (LinkError, ValueError) as exc:
        raise TrialAborted(f"cannot reach the crane controller at {link_url}: {exc}", kind="link") from exc
    if state in ("ESTOP", "FAULT"):
        raise TrialAborted(f"the crane controller at {link_url} is in {state}: reset it on the crane first",
                           kind="link")
    return state
