"""The ``loggrasp`` command. Sub-commands are thin wrappers over library functions; every heavy
import happens inside a command so that ``loggrasp --help`` is instant.

:func:`run` is the one place errors are printed: a command (or the library under it) raises, and
:func:`run` writes one line ``error: …`` on standard error — the problem, with the flag or file
to fix — and returns the documented exit code (``synth.common.cli.EXIT_CODES``). :func:`main`
(the console script) also keeps C libraries quiet unless ``--verbose``.
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path
from typing import Callable, Literal

import typer

from field.audit.cli import audit_app
from field.controller import ControllerConfig, ReachEnvelope
from field.demo import CRANE_OFFSET_SOUTH_M, DEMO_DATA, crane_config, default_crane_base
from field.link.cli import INSECURE_LINK, link_key_command, link_security_note, secured_link
from field.trial import TrialOptions
from planner.cli import MODEL, OBJECTIVE_HELP, VIEW_SPREAD, VIEWS, eval_command, plan_command, train_command
from reconstruct.cli import compare_command, gnss_crs_warning, reconstruct_command, scan_command
from reconstruct.survey.cli import GNSS_HELP, GNSS_WINDOWS_HELP, gnss_source, survey_command
from synth.cli import APP_SETTINGS, JSON
from synth.cli import app as synth_app
from synth.common.cli import (EXIT_CODES, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_LINK,
                              EXIT_REPLAY_DIFFERS, EXIT_TRIAL, CliError, Output, check_input, check_output_dir,
                              check_output_file, field_default, flag_of_path, option, to_flags)

LINK_FORMS = ("can://virtual/CH, can://socketcan/can0, can://remote/127.0.0.1:PORT/CH, can://, "
              "zenoh://HOST:PORT/CRANE, zenoh://CRANE?config=PATH.json5, twin://")
TWIN_PARAMETERS = (
    "twin:// runs a crane controller twin inside this process behind a simulated CAN bus. Its "
    "parameters (URL query, e.g. twin://?executor=pybullet&pile=truth/pile.json&trial=fast): "
    "crane_base=E,N,H (SWEREF 99 TM [m], ellipsoidal h [m]; trial fills it from --base, else 5 m "
    "south of the surveyed logs), crane_max_reach_m=M (trial: --max-reach), crane_max_pile_age_s=S "
    "(the twin crane's own staleness limit; trial: --max-pile-age, replay: the record's age), "
    "executor=fixed|pybullet (fixed: always the outcome=SUCCESS|COLLISION|... after delay_ms=MS; "
    "pybullet: a grasp trial on pile=PILE.json with trial=fast|careful), and the link options "
    "record=PATH.blf, heartbeat_ms, heartbeat_timeout_ms, connect_timeout_s, max_pile_age_s, secoc_key=KEYFILE "
    "(authenticated frames, SecOC style: both ends use the key; see `loggrasp link-key`), crane_key=CRANE.pub "
    "(laptop: the crane's public key, its answers are signed) and signing_key=CRANE (crane: its signing key; "
    "`loggrasp link-key --crane-signing CRANE` writes both); a can:// or zenoh:// link needs them unless "
    "insecure=1 / --insecure-link opts out.")
ROOT_HELP = f"""loggrasp — multi-log grasp planning for forestry cranes, from simulator twin to field.

\b
Exit codes:
""" + "\n".join(f"  {code:>3}  {what}" for code, what in EXIT_CODES.items()) + """

--json (where offered) prints one JSON document with a format name and version on standard output;
progress and warnings go to standard error. --verbose (anywhere on the line) shows what C libraries
print (pybullet, EGL/OpenGL, libpng) and the traceback of an internal error.
"""

app = typer.Typer(help=ROOT_HELP, **APP_SETTINGS)
synth_app.command("scan")(scan_command)
app.add_typer(synth_app, name="synth")
app.command("train")(train_command)
app.command("plan")(plan_command)
app.command("eval")(eval_command)
app.command("link-key")(link_key_command)
app.command("survey")(survey_command)
app.command("reconstruct")(reconstruct_command)
app.command("compare-piles")(compare_command)
app.add_typer(audit_app, name="audit")


def version_text() -> str:
    try:
        from importlib.metadata import version

        v = version("loggrasp")
    except Exception:  # running from a source tree that is not installed
        import synth

        v = synth.__version__
    return f"loggrasp {v}"


def _print_version(value: bool) -> None:
    if value:
        print(version_text())
        raise typer.Exit(0)


@app.callback()
def root(
    version: bool = typer.Option(False, "--version", help="Print loggrasp's version and exit.", is_eager=True,
                                 callback=_print_version),
    verbose: bool = typer.Option(False, "--verbose", help="Show C libraries' output and internal tracebacks "
                                 "(may be given anywhere on the line)."),
) -> None:
    """loggrasp — multi-log grasp planning for forestry cranes."""


# -- shared field flags ----------------------------------------------------------------------------
def link_option(help: str = f"Crane link URL: {LINK_FORMS}."):
    return option("--link", help, default=..., metavar="URL")


BASE_HELP = "Crane base E,N,H (SWEREF 99 TM easting, northing [m], ellipsoidal height [m])"
MAX_REACH = option("--max-reach", "Boom reach.", field=(ReachEnvelope, "max_reach_m"), min=0.1)
MAX_PILE_AGE = option("--max-pile-age", "Refuse plans on pile data older than this.",
                      field=(TrialOptions, "max_pile_age_s"), min=0.001)


def parse_base(text: str | None, flag: str = "--base") -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3 or not all(v == v for v in parts):
        raise CliError(f"{flag} must be E,N,H (SWEREF 99 TM easting and northing [m], ellipsoidal height [m]), "
                       f"e.g. 743497.0,7117716.0,249.8; got {text!r}")
    from synth.geometry.geodesy import check_sweref_tm

    check_sweref_tm(parts[0], parts[1], flag)
    return parts[0], parts[1], parts[2]


def check_link(url: str, flag: str = "--link", serve: bool = False):
    """The parsed link URL, or a :class:`CliError` (exit 3) before any work: empty, malformed, or a
    scheme with no backend (``serve``: one a controller can serve, i.e. not ``twin://``)."""
    from field.link.base import BACKENDS, CONTROLLER_TRANSPORTS, LinkURL

    if not url or not url.strip():
        raise CliError(f"{flag} is empty; give a crane link URL: {LINK_FORMS}", EXIT_LINK)
    try:
        parsed = LinkURL.parse(url)
    except ValueError as exc:
        raise CliError(f"{flag}: {exc}", EXIT_LINK) from exc
    registry = CONTROLLER_TRANSPORTS if serve else BACKENDS
    if parsed.scheme not in registry:
        if serve and parsed.scheme == "twin":
            raise CliError(f"{flag} {url}: twin:// is a crane twin inside the laptop's own process; a controller "
                           "serves can://... or zenoh://...", EXIT_LINK)
        raise CliError(f"{flag} {url}: unknown link scheme {parsed.scheme + '://'!r}; use one of {LINK_FORMS}",
                       EXIT_LINK)
    if parsed.scheme == "zenoh" and not parsed.path and "config" not in parsed.query:
        raise CliError(f"{flag} {url}: a Zenoh URL names the crane: zenoh://HOST:PORT/CRANE or "
                       "zenoh://CRANE?config=PATH.json5", EXIT_LINK)
    return parsed


def twin_url(url: str, base_tm, max_reach_m: float, max_pile_age_s: float) -> str:
    """A ``twin://`` URL with the twin crane's own limits filled in where the URL leaves them out,
    so the twin judges a command like the laptop does."""
    from urllib.parse import urlencode

    from field.link.base import LinkURL

    u = LinkURL.parse(url)
    q = dict(u.query)
    if "crane_base" not in q:
        q["crane_base"] = ",".join(f"{v:.3f}" for v in base_tm)
        q.setdefault("crane_max_reach_m", f"{max_reach_m:g}")
    q.setdefault("crane_max_pile_age_s", f"{max_pile_age_s:g}")
    return "twin://?" + urlencode(q, safe=",/:")


def base_from_survey(gnss) -> tuple[float, float, float]:
    """A crane base :data:`field.demo.CRANE_OFFSET_SOUTH_M` south (site frame) of the surveyed log
    ends' centre, at about ground height: the twin crane's default position, known before the
    reconstruction."""
    import numpy as np

    from reconstruct.survey.gnss import read_gnss
    from synth.geometry.geodesy import site_to_tm

    survey = read_gnss(gnss, allow_float=True)
    origin = survey.default_origin()
    ends = np.array([p for a_b in survey.endpoints_site(origin).values() for p in a_b], dtype=float)
    c = ends.mean(axis=0)
    point = np.array([c[0], c[1] - CRANE_OFFSET_SOUTH_M, float(ends[:, 2].min()) - 0.3])
    e, n, h = site_to_tm(origin, point)
    return float(np.ravel(e)[0]), float(np.ravel(n)[0]), float(np.ravel(h)[0])





def _trial_options(objective, model, allow_float, max_pile_age, base_tm, max_reach, capacity, views=1,
                   view_spread=0.0, **verify) -> TrialOptions:
    """The trial's options; ``verify``: the ``TrialOptions.verify_*`` / ``operator_rank`` fields."""
    return TrialOptions(objective=objective, model=None if model is None else str(model), allow_float=allow_float,
                        max_pile_age_s=max_pile_age, crane_base_tm=base_tm, max_reach_m=max_reach,
                        lift_capacity_kg=capacity, views=views, view_spread_k=view_spread, **verify)


# -- verified planning flags of trial and demo ------------------------------------------------------
NO_VERIFY = option("--no-verify", "Send without trying the grasps in the twin first (the network's best, or "
                   "--send-rank).", default=False)
VERIFY_K = option("--verify", "Grasps the twin tries on the reconstructed pile before one is sent; the best that "
                  "succeeded there is sent.", field=(TrialOptions, "verify_k"), metavar="K")
VERIFY_COPIES = option("--verify-copies", "Also try each grasp that succeeded on this many perturbed copies of the "
                       "reconstruction (its measured uncertainty, per log from how it was fitted).",
                       field=(TrialOptions, "verify_copies"), min=0, max=64)
VERIFY_BUDGET = option("--verify-budget", "Wall time for the twin's trials; no trial starts after it and only the "
                       "grasps checked by then can be sent (0 = no limit).", field=(TrialOptions, "verify_budget_s"),
                       names=["time_budget_s"])
VERIFY_WORKERS = option("--verify-workers", "Processes for the twin's trials (0 = all cores, 1 = in this process).",
                        field=(TrialOptions, "verify_workers"), min=0)
SEND_RANK = option("--send-rank", "When no grasp succeeded in the twin (or with --no-verify): send plan rank N "
                   "anyway, the operator's explicit choice, marked NOT VERIFIED.", default=None, min=1, metavar="N",
                   names=["operator_rank"])


def verify_fields(verify: int, no_verify: bool, copies: int, budget: float | None, workers: int,
                  send_rank: int | None) -> dict:
    """The ``TrialOptions`` fields of the verification flags, checked (exit 2) before any work."""
    from planner.cli import check_verify_flags

    if no_verify:
        return {"verify_k": 0, "operator_rank": send_rank}
    budget_s = check_verify_flags(verify, budget, off_hint="--no-verify turns verification off")
    return {"verify_k": verify, "verify_copies": copies, "verify_budget_s": budget_s, "verify_workers": workers,
            "operator_rank": send_rank}


def outcome_words(outcome: dict | None, targets: int | None = None) -> str:
    """A grasp outcome for people: ``SUCCESS: 4 logs held (4 targeted), balance cos β 0.999``."""
    if not outcome:
        return "no outcome"
    held = outcome.get("logs_grasped")
    text = f"{outcome.get('class')}: {held} log{'' if held == 1 else 's'} held"
    if targets is not None:
        text += f" ({targets} targeted)"
    if outcome.get("cos_beta") is not None:
        text += f", balance cos β {outcome['cos_beta']:.3f}"
    return text


def show_plan(prepared) -> None:
    """What the operator confirms: the plan table, the grasp in SWEREF 99 TM, the warnings and
    the pictures (paths that exist)."""
    from planner.cli import TWIN_COLUMNS, twin_cells
    from synth.common.cli import format_table

    v = prepared.verification
    shown = max([5, prepared.chosen_rank] + ([] if v is None else [c.rank + 1 for c in v.candidates]))
    rows = [[("*" if g is prepared.best else "") + str(i + 1), ",".join(map(str, g.targets)), f"{g.quality:.3f}",
             f"{g.graspability:.3f}", f"{g.balance:.3f}", f"{g.grasp.width_m:.2f}"]
            + ([] if v is None else twin_cells(v, i)) for i, g in enumerate(prepared.plan.grasps[:shown])]
    what = ("twin: its outcome on the reconstructed pile, held logs, beta" if v is not None
            else "not tried in the twin")
    print(format_table(f"plan: the best grasp of each target subset (*{prepared.chosen_rank} is sent; Q quality, "
                       f"U graspability, B balance; {what})",
                       ["#", "targets", "Q", "U", "B", "width m"] + ([] if v is None else TWIN_COLUMNS), rows),
          file=sys.stderr)
    for line in prepared.summary_lines():
        print(("  " if not line.startswith("WARNING") else "") + line, file=sys.stderr)
    plan_dir = Path(prepared.work_dir) / "plan"
    pictures = [p for p in (plan_dir / "plan.png", plan_dir / "grasp_map.png", plan_dir / "pile.geojson") if p.exists()]
    print("  look before sending: " + ", ".join(str(p) for p in pictures), file=sys.stderr, flush=True)


def ask_yes_no(question: str) -> bool | None:
    """Ask on standard error, read a line from standard input: True for y/yes, False for anything
    else, None when there is no answer (end of input, Ctrl-C). Standard output is left alone."""
    print(f"{question} [y/N]: ", end="", file=sys.stderr, flush=True)
    try:
        line = sys.stdin.readline() if sys.stdin is not None else ""
    except (KeyboardInterrupt, OSError, ValueError):
        line = ""
    if not line:
        print(file=sys.stderr, flush=True)
        return None
    return line.strip().lower() in ("y", "yes")


# -- crane-sim ----------------------------------------------------------------------------------
class _Announcing:
    """An executor that says, per command, what the crane does and how it ended. It wraps the
    executor API ``execute(cmd, should_abort) -> Outcome`` (:mod:`field.executor`), passing the
    controller's abort request through to the inner executor."""

    def __init__(self, inner, say):
        self.inner, self.say = inner, say

    def execute(self, cmd, should_abort):
        self.say(f"command {cmd.command_id}: accepted; grasping at E {cmd.easting_mm / 1000:.3f} N "
                 f"{cmd.northing_mm / 1000:.3f} h {cmd.height_mm / 1000:.3f} m, heading {cmd.heading_cdeg / 100:.2f}° "
                 f"(grid), opening {cmd.opening_width_mm / 1000:.2f} m, {cmd.target_log_count} target log(s)")
        execute = getattr(self.inner, "execute", None)
        out = execute(cmd, should_abort) if callable(execute) else self.inner(cmd)
        self.say(f"command {cmd.command_id}: {out.outcome_class.name}, {out.logs_grasped} log(s) held, "
                 f"balance cos β {out.balance_cos_milli / 1000:.3f}")
        return out


@app.command("crane-sim")
def crane_sim(
    link: str = link_option("Link URL the controller serves: can://virtual/CH, can://remote/127.0.0.1:PORT/CH "
                            "or zenoh://127.0.0.1:PORT/CRANE (it listens there)."),
    pile: Path = option("--pile", "The true, georeferenced pile.json the crane stands at.", default=...,
                        metavar="PILE.json"),
    base: str = option("--base", f"{BASE_HELP}; default: 5 m south of the pile.", default=None, metavar="E,N,H"),
    max_reach: float = MAX_REACH,
    max_pile_age: float = option("--max-pile-age", "This crane's own staleness limit: it rejects (STALE) commands "
                                 "planned on older pile data, whatever the laptop's --max-pile-age.",
                                 field=(TrialOptions, "max_pile_age_s"), min=0.001),
    journal: Path = option("--journal", "Burn every seen command id here (never run twice, across restarts); "
                           "default: a file per link under $XDG_STATE_HOME/loggrasp (~/.local/state/loggrasp).",
                           default=None, metavar="FILE"),
    no_journal: bool = option("--no-journal", "Opt out of the journal: command ids in memory only (a restart "
                              "forgets them; logged as a warning).",
                              default=False),
    trial: Literal["fast", "careful"] = option("--trial", "Trial preset of the grasps it executes.", default="fast",
                                                metavar="fast|careful"),
    max_mac_failures: int = option("--max-mac-failures", "More frames than this failing their MAC within 10 s put "
                                   "the crane in FAULT (a node without the key is on the bus: commands refused, the "
                                   "running grasp aborted, local reset).",
                                   field=(ControllerConfig, "max_mac_failures"), min=1),
    insecure_link: bool = INSECURE_LINK,
) -> None:
    """Run the crane controller twin: validates commands like a real controller and executes
    accepted grasps in pybullet on the given pile; says what it does with each command. Stops on
    Ctrl-C / SIGTERM. Authenticated frames: add ?secoc_key=KEYFILE&signing_key=CRANE to --link (the
    laptop uses the same KEYFILE and crane_key=CRANE.pub; see `loggrasp link-key`); without them it
    refuses to serve unless --insecure-link.
    It burns every command id in its journal and accepts a command only from a laptop whose
    heartbeat it hears.

    \b
    Example: loggrasp crane-sim --link zenoh://127.0.0.1:7447/crane1 --pile scans/s3/truth/pile.json
    """
    import signal
    import threading

    import field.controller
    from field.executor import PybulletTrialExecutor

    o = Output()
    link = secured_link(link, check_link(link, serve=True), insecure_link, serve=True)
    if link_security_note(link, serve=True):
        o.warn(link_security_note(link, serve=True))
    check_input(pile, "--pile", "file")
    base_tm = parse_base(base)
    journal = _crane_journal(link, journal, no_journal)
    executor = PybulletTrialExecutor(pile, trial=trial)
    base_tm = base_tm or default_crane_base(executor.pile)
    from dataclasses import replace

    config = replace(crane_config(base_tm, max_reach, max_pile_age, None if journal is None else str(journal),
                                  no_journal=no_journal), max_mac_failures=max_mac_failures)
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    watch = _CraneSimWatch(o, stop, f"crane controller twin serving {link}: base E {base_tm[0]:.3f} N {base_tm[1]:.3f} "
                           f"h {base_tm[2]:.3f} m, reach {max_reach:g} m, pile age limit {max_pile_age:g} s; "
                           f"journal {journal or 'OFF (ids forgotten on restart)'}; FAULT past {max_mac_failures} MAC "
                           f"failures in {config.mac_failure_window_s:g} s; Ctrl-C stops")
    try:
        final = field.controller.run_controller(link, _Announcing(executor, o.say), stop, config,
                                                on_serve=watch.serving)
    finally:
        stop.set()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    watch.report_rejections()  # the last ones, seen just before the stop
    cause = watch.controller.fault_cause if watch.controller else None
    o.say(f"stopped in state {final.state.name}" + (f" ({cause})" if cause else ""))


def _crane_journal(link: str, journal: Path | None, no_journal: bool) -> Path | None:
    """crane-sim's command-id journal: --journal, none with --no-journal, else the link's default file."""
    import field.controller

    if no_journal and journal is not None:
        raise CliError("give --journal PATH or --no-journal, not both")
    if journal is not None:
        check_input(journal.parent if str(journal.parent) else Path("."), "--journal", "dir")
        return journal
    return None if no_journal else field.controller.default_journal_path(link)


class _CraneSimWatch:
    """What crane-sim says while it serves: "serving" once the transport is up, then each rejection
    (with its explanation) and each new executor fault (with the way out), from a watcher thread."""

    def __init__(self, o: Output, stop, serving_line: str) -> None:
        import threading

        self.o, self.stop, self.serving_line = o, stop, serving_line
        self.controller = None
        self._lock = threading.Lock()
        self._seen = 0
        self._said_fault = None

    def serving(self, controller) -> None:
        import threading

        self.controller = controller
        self.o.say(self.serving_line)
        threading.Thread(target=self._loop, name="crane-sim-watch", daemon=True).start()

    def _loop(self) -> None:
        while not self.stop.wait(0.05):
            self.report_rejections()
            self.report_fault()

    def report_rejections(self) -> None:
        from field.trial import REJECT_EXPLANATIONS

        with self._lock:
            rejections = self.controller.rejections if self.controller else []
            while self._seen < len(rejections):
                cid, reason = rejections[self._seen]
                self._seen += 1
                why = REJECT_EXPLANATIONS.get(reason.name, "")
                self.o.say(f"command {cid}: REJECTED ({reason.name})" + (f": {why}" if why else ""))

    def report_fault(self) -> None:  # the executor's exception, once per fault, with the way out
        cause = self.controller.fault_cause if self.controller else None
        if cause is not None and cause != self._said_fault:
            self.o.say(f"controller FAULT: {cause}; every command is rejected until the crane is reset")
        self._said_fault = cause


# -- trial ----------------------------------------------------------------------------------------
FOXGLOVE = option("--foxglove", "Also serve the trial live to Foxglove (WebSocket, 127.0.0.1) on this port while it "
                  "runs; the record's trial.mcap is written either way.", default=None, metavar="PORT",
                  min=1, max=65535, names=["foxglove_port"])
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


@app.command("trial", epilog=TWIN_PARAMETERS)
def trial_command(
    scan: Path = option("--scan", "Scan folder (stereo pair folders + scan_pose.json).", default=..., metavar="DIR"),
    gnss: list[Path] = option("--gnss", GNSS_HELP, default=..., metavar="FILE"),
    gnss_windows: Path = option("--gnss-windows", GNSS_WINDOWS_HELP, default=None, metavar="FILE"),
    link: str = link_option(),
    record: Path = option("--record", "Trial record folder to create (must not exist).", default=..., metavar="DIR"),
    objective: Literal["f1", "f2", "f3"] = option("--objective", OBJECTIVE_HELP, field=(TrialOptions, "objective"),
                                                  metavar="f1|f2|f3"),
    model: Path = MODEL,
    views: int = VIEWS,
    view_spread: float = VIEW_SPREAD,
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
    from field.trial import run_trial_record
    from planner.inference import check_views

    o = Output(as_json)
    parsed = check_link(link)
    link = secured_link(link, parsed, insecure_link)
    base_tm = parse_base(base)
    gnss = _check_trial_paths(scan, gnss, gnss_windows, model, record, allow_float)
    check_views(views, view_spread)
    opts = _trial_options(objective, model, allow_float, max_pile_age, base_tm, max_reach, capacity, views, view_spread,
                          **verify_fields(verify, no_verify, verify_copies, verify_budget, verify_workers, send_rank))
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
@app.command("replay", epilog=TWIN_PARAMETERS)
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

    from field.trial import read_record, replay_record

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
@app.command("demo")
def demo(
    out: Path = option("--out", "Output folder (trial record, pictures); its trial/ is replaced.",
                       default=Path("out/demo"), metavar="DIR"),
    link: str = option("--link", "Link to the in-process crane twin: can://virtual/CH or zenoh://127.0.0.1:PORT/CRANE.",
                       default="can://virtual/loggrasp-demo", metavar="URL"),
    model: Path = MODEL,
    no_verify: bool = option("--no-verify", "Send the network's best grasp without trying the best ones in the twin "
                             "on the reconstruction first.", default=False),
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

    options = demo_options(setup, model, verify=not no_verify)
    rec = _run_trial(o, setup.record_dir, lambda: run_demo(setup, options, confirm=show, progress=o.progress,
                                                           foxglove_port=foxglove))
    o.progress(f"record: {setup.record_dir} (plan pictures in {setup.record_dir / 'plan'}, the trial in time for "
               f"Foxglove in {setup.record_dir / 'trial.mcap'}); whole chain "
               f"{_time.perf_counter() - t0:.1f} s")
    _finish_trial(o, rec, setup.record_dir)


# -- the one error handler ------------------------------------------------------------------------
_RUST_PATH = re.compile(r"\s*(?:\bat\s+)?\(?/[^\s()]*\.rs:\d+(?::\d+)?\)?\.?")


def clean_message(text: str) -> str:
    """One line: flags for Python names, no Rust source paths (Zenoh), no line breaks."""
    text = _RUST_PATH.sub("", str(text)).replace("Value error, ", "")
    text = " ".join(part.strip() for part in text.splitlines() if part.strip())
    return to_flags(text)


def classify(exc: BaseException) -> tuple[int, str]:
    """(exit code, message) of an exception that reached :func:`run`."""
    from field.errors import FieldError, KeyFileError, LinkError

    if isinstance(exc, CliError):
        return exc.code, str(exc)
    if isinstance(exc, KeyFileError):  # a key file named in a link URL: bad input, the message names it
        return EXIT_INPUT, f"crane link key: {exc}"
    if isinstance(exc, LinkError):
        return EXIT_LINK, f"crane link: {exc}"
    if isinstance(exc, OSError):
        flag = flag_of_path(exc.filename)
        what = f"{exc.filename}" + (f" ({flag})" if flag else "")
        return EXIT_INPUT, f"cannot use {what}: {exc.strerror or exc}" + (f"; choose another {flag}" if flag else "")
    from planner.errors import PlannerError
    from reconstruct.errors import ReconstructError
    from synth.errors import SynthError

    if isinstance(exc, (FieldError, SynthError, PlannerError, ReconstructError, ValueError)):
        return EXIT_INPUT, str(exc)
    return EXIT_INTERNAL, (f"internal error {type(exc).__name__}: {exc} (a bug; run again with --verbose for the "
                           "traceback and report it)")


def _pop_verbose(argv: list[str]) -> bool:
    end = argv.index("--") if "--" in argv else len(argv)
    found = "--verbose" in argv[:end] or os.environ.get("LOGGRASP_VERBOSE", "") not in ("", "0")
    argv[:end] = [a for a in argv[:end] if a != "--verbose"]
    return found


def run(argv: list[str] | None = None) -> int:
    """Run ``loggrasp`` with ``argv``; print any error as one line on standard error; return the
    exit code."""
    from typer import _click as click
    from typer.main import get_command

    from synth.common.cli import FLAG_OF_PATH

    argv = list(sys.argv[1:] if argv is None else argv)
    verbose = _pop_verbose(argv)
    FLAG_OF_PATH.clear()
    command = get_command(app)
    try:
        rv = command.main(args=argv, prog_name="loggrasp", standalone_mode=False)
        if rv == EXIT_INTERRUPTED:  # Ctrl-C (typer turns it into this exit code)
            print("error: interrupted", file=sys.stderr, flush=True)
        return rv if isinstance(rv, int) else 0
    except click.exceptions.NoArgsIsHelpError as exc:
        print(exc.ctx.get_help() if exc.ctx else "", file=sys.stdout)
        return 0
    except click.exceptions.UsageError as exc:
        where = exc.ctx.command_path if exc.ctx else "loggrasp"
        code, message = EXIT_INPUT, f"{clean_message(exc.format_message())} (see `{where} --help`)"
    except click.exceptions.ClickException as exc:  # e.g. a file typer could not open
        code, message = EXIT_INPUT, clean_message(exc.format_message())
    except (typer.Abort, KeyboardInterrupt):
        code, message = EXIT_INTERRUPTED, "interrupted"
    except typer.Exit as exc:
        return exc.exit_code
    except BaseException as exc:  # the one place errors are printed
        if isinstance(exc, SystemExit):
            return exc.code if isinstance(exc.code, int) else 1
        code, message = classify(exc)
        message = clean_message(message)
        if verbose:
            import traceback

            traceback.print_exception(exc, file=sys.stderr)
    try:
        sys.stdout.flush()
    except OSError:
        pass
    print(f"error: {message}", file=sys.stderr, flush=True)
    return code


def main() -> None:
    """The console script: C libraries quiet unless --verbose, then :func:`run`."""
    from synth.common.cli import quiet_c_streams

    argv = sys.argv[1:]
    if not _pop_verbose(list(argv)):
        quiet_c_streams()
    code = run(argv)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    raise SystemExit(code)


if __name__ == "__main__":
    main()
