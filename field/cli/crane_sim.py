"""``loggrasp crane-sim``: a crane controller served on a link (the twin plays the crane)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from field.cli.options import BASE_HELP, MAX_REACH, check_link, link_option, parse_base
from field.controller import ControllerConfig
from field.demo import crane_config, default_crane_base
from field.link.cli import INSECURE_LINK, link_security_note, secured_link
from field.trial import TrialOptions
from synth.common.cli import CliError, Output, check_input, option


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
