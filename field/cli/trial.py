"""``loggrasp trial``, ``replay`` and ``demo``: a grasp planned on a scan and sent to a crane, a recorded
trial again, and the whole chain on the bundled demo data."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable, Literal

import typer

from field.cli.options import (BASE_HELP, MAX_PILE_AGE, MAX_REACH, NO_RANKER, NO_VERIFY, RANKER, SEND_RANK,
                                VERIFY_BUDGET, VERIFY_COPIES, VERIFY_K, VERIFY_WORKERS, ask_yes_no, base_from_survey,
                                check_link, link_option, outcome_words, parse_base, ranker_fields, show_plan,
                                trial_options, twin_url, verify_fields)
from field.link.cli import INSECURE_LINK, link_security_note, secured_link
from field.trial import TrialOptions
from planner.cli import (F3_SIGMA_B, MODEL, OBJECTIVE_HELP, PRECISION, VIEW_SPREAD, VIEWS, f3_balance_option,
                         f3_objective)
from planner.inference import PRODUCT_F3_BALANCE
from reconstruct.cli import gnss_crs_warning
from reconstruct.survey.cli import GNSS_HELP, GNSS_WINDOWS_HELP, gnss_source
from synth.cli import JSON
from synth.common.cli import (EXIT_INPUT, EXIT_INTERRUPTED, EXIT_LINK, EXIT_REPLAY_DIFFERS, EXIT_TRIAL, CliError,
                              Output, check_input, check_output_dir, option)


# -- trial ----------------------------------------------------------------------------------------
FOXGLOVE = option("--foxglove", "Also serve the trial live to Foxglove (WebSocket, 127.0.0.1) on this port while it "
                  "runs; the record's trial.mcap is written either way.", default=None, metavar="PORT",
                  min=1, max=65535, names=["foxglove_port"])
F3_BALANCE_TRIAL = f3_balance_option(PRODUCT_F3_BALANCE)
_TRIAL_CODES = {"input": EXIT_INPUT, "link": EXIT_LINK, "refused": EXIT_TRIAL, "declined": EXIT_TRIAL,
                "interrupted": EXIT_INTERRUPTED}


def _run_trial(o: Output, record: Path, trial: Callable[[], dict]) -> dict:
    """Run ``trial()`` (a field trial recorded in ``record``); a trial that stopped before sending
    becomes a :class:`CliError` saying where its record is."""
    from field.trial import TrialAborted

    try:
        return trial()
    except TrialAborted as exc:
        recorded = (Path(record) / "record.json").is_file()
        if recorded:
            import json

            _result(o, json.loads((Path(record) / "record.json").read_text()), record)
        where = f"; record: {record}" if recorded else "; nothing was recorded"
        raise CliError(f"{exc}{where}", _TRIAL_CODES.get(exc.kind, EXIT_TRIAL)) from exc
    except KeyboardInterrupt as exc:
        where = f"; record: {record}" if (Path(record) / "record.json").is_file() else "; nothing was recorded"
        raise CliError(f"interrupted (Ctrl-C){where}", EXIT_INTERRUPTED) from exc


def _result(o: Output, rec: dict, record: Path) -> None:
    o.result("loggrasp.trial-result", {
        "record": str(record), "final_state": rec.get("final_state"), "command_id": rec.get("command_id"),
        "accepted": rec.get("accepted"), "reject_reason": rec.get("reject_reason"), "reason": rec.get("reason"),
        "outcome": rec.get("outcome"), "command": rec.get("command"), "geo": rec.get("geo"),
        "warnings": rec.get("warnings", []), "chosen_rank": rec.get("chosen_rank"), "verified": rec.get("verified"),
        "verification": rec.get("verification")})


def _finish_trial(o: Output, rec: dict, record: Path) -> None:
    """The trial's result: JSON, a summary line, and exit 4 unless the grasp succeeded."""
    from field.trial import REJECT_EXPLANATIONS

    state = rec.get("final_state")
    targets = (rec.get("command") or {}).get("target_log_count")
    _result(o, rec, record)
    if state == "SUCCESS":
        o.say(f"trial {record}: {outcome_words(rec.get('outcome'), targets)}")
        return
    if state == "REJECTED":
        why = rec.get("reject_reason")
        raise CliError(f"the crane rejected the command ({why}): {REJECT_EXPLANATIONS.get(why, 'see the controller')}; "
                       f"record: {record}", EXIT_TRIAL)
    if rec.get("outcome"):
        raise CliError(f"the grasp did not succeed: {outcome_words(rec.get('outcome'), targets)}; record: {record}",
                       EXIT_TRIAL)
    raise CliError(f"{state}; record: {record}", EXIT_TRIAL)


def trial_command(
    scan: Path = option("--scan", "Scan folder (stereo pair folders + scan_pose.json).", default=..., metavar="DIR"),
    gnss: list[Path] = option("--gnss", GNSS_HELP, default=..., metavar="FILE"),
    gnss_windows: Path = option("--gnss-windows", GNSS_WINDOWS_HELP, default=None, metavar="FILE"),
    link: str = link_option(),
    record: Path = option("--record", "Trial record folder to create (must not exist).", default=..., metavar="DIR"),
    objective: Literal["f1", "f2", "f3"] = option("--objective", OBJECTIVE_HELP, field=(TrialOptions, "objective"),
                                                  metavar="f1|f2|f3"),
    f3_balance: Literal["network", "hang"] = F3_BALANCE_TRIAL,
    f3_sigma_b: float = F3_SIGMA_B,
    model: Path = MODEL,
    views: int = VIEWS,
    view_spread: float = VIEW_SPREAD,
    precision: Literal["auto", "bf16", "fp32", "int8", "int8-bf16-top"] = PRECISION,
    yes: bool = option("--yes", "Do not ask for confirmation before sending.", default=False),
    allow_float: bool = option("--allow-float", "Accept RTK float endpoints.", field=(TrialOptions, "allow_float")),
    max_pile_age: float = MAX_PILE_AGE,
    base: str = option("--base", f"{BASE_HELP}, for the laptop's reach check (and a twin:// crane's position).",
                       default=None, metavar="E,N,H", names=["crane_base_tm"]),
    max_reach: float = MAX_REACH,
    capacity: float = option("--capacity", "Lift capacity.", field=(TrialOptions, "lift_capacity_kg"), min=1.0),
    verify: int = VERIFY_K,
    no_verify: bool = NO_VERIFY,
    verify_copies: int = VERIFY_COPIES,
    verify_budget: float = VERIFY_BUDGET,
    verify_workers: int = VERIFY_WORKERS,
    send_rank: int = SEND_RANK,
    ranker: Path = RANKER,
    no_ranker: bool = NO_RANKER,
    over_obstacles: bool = option("--grasp-over-obstacles", "Allow grasps whose claws come down on a rock or stump "
                                  "the reconstruction shows (by default the planner moves them off it).", default=False),
    foxglove: int = FOXGLOVE,
    insecure_link: bool = INSECURE_LINK,
    as_json: bool = JSON,
) -> None:
    """Field trial: reconstruct, plan, verify in the twin, show, confirm, send, wait for the outcome, record everything.

    The link is checked and the controller reached before the reconstruction. Before anything is
    shown, the twin tries the plan's best grasps (--verify K) on the reconstructed pile and the
    best that succeeded there is the one offered; when none did, nothing is sent (exit 4) unless
    --send-rank N names a plan rank to send anyway. The operator sees the plan table with each
    tried grasp's twin outcome, the warnings and the pictures (in the record's plan/ folder)
    before saying yes; a trial that is refused, declined, not answered or interrupted still leaves
    a complete record saying so, with every verification trial. Exit 0 only when the grasp
    succeeded (4: not sent, rejected or failed).

    \b
    Example: loggrasp trial --scan s3/scan --gnss s3/gnss.csv --link can://virtual/ch0 --record trials/t1
    Example: loggrasp trial --scan s3/scan --gnss rover.ubx --gnss-windows windows.csv --link can://virtual/ch0 \\
               --record trials/t4
    Example: loggrasp trial --scan s3/scan --gnss s3/gnss.csv --record trials/t2 --yes \\
               --link "twin://?executor=pybullet&pile=s3/truth/pile.json"
    Example: loggrasp trial --scan s3/scan --gnss s3/gnss.csv --link can://virtual/ch0 --record trials/t3 \\
               --verify 16 --verify-copies 3 --verify-budget 30
    Example: loggrasp trial --scan s3/scan --gnss s3/gnss.csv --link zenoh://127.0.0.1:7447/crane1 \
               --record trials/t4 --foxglove 8765
    """
    from field.trial_record import run_trial_record
    from planner.inference import check_views

    o = Output(as_json)
    parsed = check_link(link)
    link = secured_link(link, parsed, insecure_link)
    base_tm = parse_base(base)
    gnss = _check_trial_paths(scan, gnss, gnss_windows, model, record, allow_float)
    check_views(views, view_spread)
    f3_objective(objective, f3_balance, f3_sigma_b)  # a bad --f3-sigma-b named before any work
    opts = trial_options(objective, model, allow_float, max_pile_age, base_tm, max_reach, capacity, views, view_spread,
                          f3_balance=f3_balance, f3_sigma_b=f3_sigma_b, precision=precision,
                          **verify_fields(verify, no_verify, verify_copies, verify_budget, verify_workers, send_rank),
                          clear_obstacles=not over_obstacles, **ranker_fields(ranker, no_ranker))
    warning = gnss_crs_warning(gnss)
    if warning:
        o.warn(warning)
    if parsed.scheme == "twin":
        link, opts = _twin_crane(o, link, gnss, opts)
    note = link_security_note(link)
    if note:
        o.warn(note)

    def ask(prepared) -> bool:
        return _ask_to_send(prepared, note)

    rec = _run_trial(o, record, lambda: run_trial_record(scan, gnss, link, record, opts,
                                                         confirm=None if yes else ask, progress=o.progress,
                                                         foxglove_port=foxglove))
    _finish_trial(o, rec, record)


def _check_trial_paths(scan: Path, gnss: list[Path], gnss_windows: Path | None, model: Path | None, record: Path,
                       allow_float: bool):
    """The inputs checked before anything is written; returns the survey source (raw logs are
    averaged and checked here, so bad logs or windows stop the trial with nothing recorded)."""
    check_input(scan, "--scan", "dir")
    source = gnss_source(gnss, gnss_windows)
    if model is not None:
        check_input(model, "--model", "file")
    if record.exists():
        raise CliError(f"--record {record} already exists; choose a new --record folder")
    check_output_dir(record, "--record")
    if not isinstance(source, Path):
        from reconstruct.survey.gnss import read_gnss

        read_gnss(source, allow_float=allow_float, require_both_ends=False)
    return source


def _twin_crane(o: Output, link: str, gnss, opts):
    """A twin:// link: the crane stands at --base (default: south of the surveyed pile) with the
    trial's reach and staleness limit; returns the full twin URL and the options with that base."""
    from dataclasses import replace

    base_tm = opts.crane_base_tm or base_from_survey(gnss)
    link = twin_url(link, base_tm, opts.max_reach_m, opts.max_pile_age_s)
    o.progress(f"twin crane at E {base_tm[0]:.3f} N {base_tm[1]:.3f} h {base_tm[2]:.3f} m, reach {opts.max_reach_m:g} m, "
               f"pile age limit {opts.max_pile_age_s:g} s ({link})")
    return link, replace(opts, crane_base_tm=base_tm)


def _ask_to_send(prepared, link_note: str | None = None) -> bool:
    """The operator's confirmation: the plan table (and ``link_note``: an unauthenticated link),
    then y/n; no answer is a declined trial."""
    from field.trial import TrialAborted

    show_plan(prepared)
    if link_note:
        print(f"WARNING: {link_note}", file=sys.stderr, flush=True)
    answer = ask_yes_no("send this grasp to the crane?")
    if answer is None:
        raise TrialAborted("no answer at the confirmation prompt (standard input closed or interrupted): nothing "
                           "was sent; answer y at the prompt, or pass --yes", kind="declined")
    return answer


# -- replay ----------------------------------------------------------------------------------------
def replay_command(
    record: Path = typer.Argument(..., metavar="RECORD", help="A trial record folder."),
    out: Path = option("--out", "Work folder for the re-run, kept (default: a temporary folder, removed).",
                       default=None, metavar="DIR"),
    link: str = option("--link", "Re-send the recorded command over this link (a twin:// crane accepts the old data; "
                       "see trial --help for twin:// parameters).", default=None, metavar="URL"),
    realtime: bool = option("--realtime", "Replay the recorded CAN traffic with its original timing.", default=False),
    insecure_link: bool = INSECURE_LINK,
    as_json: bool = JSON,
) -> None:
    """Re-run reconstruction, planning and verification from a trial record; say whether the command is bit-identical.

    The recorded inputs are checked against their sha256 in record.json first; a changed,
    missing or added input file is named. Every verification trial the record holds runs again
    (without the time budget) and must give the same result bit for bit (its times aside). Exit 0:
    identical; 5: the re-run differs (the command, the plan or a verification trial).

    \b
    Example: loggrasp replay trials/t1 --json
    Example: loggrasp replay trials/t1 --link "twin://?executor=fixed"
    """
    import tempfile
    import time

    from field.trial_record import read_record, replay_record

    o = Output(as_json)
    check_input(record, "RECORD", "dir")
    parsed = check_link(link) if link is not None else None
    if parsed is not None:
        link = secured_link(link, parsed, insecure_link)
        parsed = check_link(link)
    rec = read_record(record)
    if parsed is not None and rec.get("command") is None:
        raise CliError(f"--link: {record} sent no command ({rec.get('final_state')}: {rec.get('reason')}); there is "
                       "nothing to re-send")
    if out is not None:
        check_output_dir(out, "--out")
    if realtime and not (record / "link" / "traffic.blf").exists():
        raise CliError(f"{record} has no CAN recording (link/traffic.blf): --realtime needs a trial over can://")
    with tempfile.TemporaryDirectory(prefix="loggrasp-replay-") as tmp:
        work = Path(out) if out is not None else Path(tmp) / "work"
        result = replay_record(record, work, progress=o.progress)
    doc = {"record": str(record), **result}
    if realtime:
        from field.link.can_backend import replay as replay_can

        n = sum(1 for _ in replay_can(record / "link" / "traffic.blf", realtime=True))
        doc["realtime_frames"] = n
        o.say(f"replayed {n} recorded frames with their original timing")
    if parsed is not None:
        doc["resent"] = _resend(o, rec, link, parsed, time.time())
    o.result("loggrasp.replay", doc)
    vtrials = sum(len(c.get("trials", [])) for c in (rec.get("verification") or {}).get("candidates", []))
    checked = f", and its {vtrials} verification trials" if vtrials else ""
    if result["identical"]:
        what = "the command and the plan" if result["command_sent"] is not None else "the refusal to send, the plan"
        o.say(f"replay of {record}: identical ({what}{checked} are bit-identical)")
        return
    what = list(result["differences"])
    if result["plan_identical"] is False:
        what.append("the plan")
    what += [f"verification {d}" for d in result.get("verification_differences", [])]
    raise CliError(f"the replay of {record} differs from the record: {'; '.join(what) or 'the plan'}",
                   EXIT_REPLAY_DIFFERS)


def _resend(o: Output, rec: dict, link: str, parsed, now: float) -> dict:
    """Send the recorded command again (a new command id) and wait for its outcome."""
    from field.errors import CommandRejected
    from field.link import GraspCommand, open_link
    from field.link.base import LinkConfig
    from field.link.safety import SafetyConfig
    from field.trial import REJECT_EXPLANATIONS

    fields = dict(rec["command"])
    age = now - fields["plan_timestamp_ms"] / 1000.0
    if parsed.scheme == "twin":  # the twin crane is told the recorded data is old by design
        opts = rec.get("options", {})
        base = opts.get("crane_base_tm")
        if base is None:
            base = (fields["easting_mm"] / 1000.0, fields["northing_mm"] / 1000.0 - 5.0, fields["height_mm"] / 1000.0)
        link = twin_url(link, base, float(opts.get("max_reach_m", 10.0)), age + 3600.0)
    try:
        # the recorded plan is old by design: the laptop-side age check is lifted for a replay;
        # the controller keeps its own (a real crane refuses it)
        with open_link(link, LinkConfig(safety=SafetyConfig(max_pile_age_s=1e12))) as lk:
            cmd = GraspCommand(command_id=lk.new_command_id(), **fields)
            lk.send_grasp(cmd, timeout_s=2.0)
            res = lk.wait_outcome(cmd.command_id, timeout_s=120.0)
    except CommandRejected as exc:
        name = getattr(exc.reason, "name", str(exc.reason))
        raise CliError(f"the controller rejected the re-sent command ({name}): {REJECT_EXPLANATIONS.get(name, exc)}",
                       EXIT_LINK) from exc
    outcome = {"class": res.outcome_class.name, "logs_grasped": res.logs_grasped,
               "cos_beta": res.balance_cos_milli / 1000.0}
    o.say(f"re-sent as command {cmd.command_id}: {outcome_words(outcome, fields.get('target_log_count'))}")
    return {"link": link, "command_id": cmd.command_id, "outcome": outcome}


# -- demo -----------------------------------------------------------------------------------------
def demo(
    out: Path = option("--out", "Output folder (trial record, pictures); its trial/ is replaced.",
                       default=Path("out/demo"), metavar="DIR"),
    link: str = option("--link", "Link to the in-process crane twin: can://virtual/CH or zenoh://127.0.0.1:PORT/CRANE.",
                       default="can://virtual/loggrasp-demo", metavar="URL"),
    model: Path = MODEL,
    no_verify: bool = option("--no-verify", "Send the network's best grasp without trying the best ones in the twin "
                             "on the reconstruction first.", default=False),
    no_ranker: bool = NO_RANKER,
    foxglove: int = FOXGLOVE,
    as_json: bool = JSON,
) -> None:
    """The main job on the embedded default: a bundled recorded scan (stereo pair + RTK endpoints)
    is reconstructed, planned on, its best grasps tried in the twin on the reconstruction (unless
    --no-verify), the best that succeeded there sent as a SWEREF 99 TM grasp over simulated CAN to
    the crane controller twin, executed in pybullet on the true pile, and recorded.

    \b
    Example: loggrasp demo --out out/demo
    Example: loggrasp demo --out out/demo-unverified --no-verify
    Example: loggrasp demo --out out/demo --foxglove 8765   # watch it live in Foxglove (ws://127.0.0.1:8765)
    """
    import time as _time

    from field.demo import demo_options, prepare_demo, run_demo

    o = Output(as_json)
    t0 = _time.perf_counter()
    check_link(link, serve=True)
    if model is not None:
        check_input(model, "--model", "file")
    check_output_dir(out, "--out")
    setup = prepare_demo(out, link)
    for note in setup.notes:
        o.progress(note)

    def show(prepared) -> bool:
        show_plan(prepared)
        return True

    options = demo_options(setup, model, verify=not no_verify, rerank=not no_ranker)
    rec = _run_trial(o, setup.record_dir, lambda: run_demo(setup, options, confirm=show, progress=o.progress,
                                                           foxglove_port=foxglove))
    o.progress(f"record: {setup.record_dir} (plan pictures in {setup.record_dir / 'plan'}, the trial in time for "
               f"Foxglove in {setup.record_dir / 'trial.mcap'}); whole chain "
               f"{_time.perf_counter() - t0:.1f} s")
    _finish_trial(o, rec, setup.record_dir)
