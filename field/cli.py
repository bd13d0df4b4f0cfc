"""The ``loggrasp`` command. Sub-commands are thin wrappers over library functions; every heavy
import happens inside a command so that ``loggrasp --help`` is instant."""

from __future__ import annotations

from pathlib import Path

import typer

from field.link.messages import DEFAULT_MAX_PILE_AGE_S
from planner.cli import eval_command, plan_command, train_command
from reconstruct.cli import compare_command, reconstruct_command, scan_command
from synth.cli import app as synth_app
from synth.cli import fail

app = typer.Typer(
    help="loggrasp — multi-log grasp planning for forestry cranes, from simulator twin to field.",
    no_args_is_help=True, pretty_exceptions_enable=False,
)
synth_app.command("scan")(scan_command)
app.add_typer(synth_app, name="synth")
app.command("train")(train_command)
app.command("plan")(plan_command)
app.command("eval")(eval_command)
app.command("reconstruct")(reconstruct_command)
app.command("compare-piles")(compare_command)


def _parse_triple(text: str, name: str) -> tuple[float, float, float]:
    parts = [float(v) for v in text.split(",")]
    if len(parts) != 3:
        raise ValueError(f"{name} must be E,N,H (SWEREF 99 TM easting, northing [m], ellipsoidal height [m])")
    return parts[0], parts[1], parts[2]


@app.command("crane-sim")
def crane_sim(
    link: str = typer.Option(..., "--link", help="Link URL the controller serves, e.g. zenoh://127.0.0.1:7447/crane1."),
    pile: str = typer.Option(..., "--pile", help="The true, georeferenced pile.json the crane stands at."),
    base: str = typer.Option(None, "--base", help="Crane base E,N,H (SWEREF 99 TM, ellipsoidal h); default: 5 m "
                                                  "south of the pile."),
    max_reach: float = typer.Option(10.0, "--max-reach", help="Boom reach [m]."),
    max_pile_age: float = typer.Option(DEFAULT_MAX_PILE_AGE_S, "--max-pile-age", help="Refuse plans on older pile data [s]."),
    journal: str = typer.Option(None, "--journal", help="Burn every seen command id here (never run twice, across "
                                                        "restarts); default: a file per link under ~/.local/state/loggrasp."),
    no_journal: bool = typer.Option(False, "--no-journal", help="Remember ids in memory only (a restart forgets them)."),
    trial: str = typer.Option("fast", "--trial", help="Trial preset: fast or careful."),
) -> None:
    """Run the crane controller twin: validates commands like a real controller and executes
    accepted grasps in pybullet on the given pile. Stops on Ctrl-C / SIGTERM. Authenticated
    frames: add ?secoc_key=KEYFILE to --link (the laptop uses the same key; see `loggrasp link-key`).

    Example: loggrasp crane-sim --link zenoh://127.0.0.1:7447/crane1 --pile scans/s3/truth/pile.json
    """
    import signal
    import threading

    import field.controller
    from field.errors import FieldError
    from field.executor import PybulletTrialExecutor
    from synth.errors import SynthError

    if no_journal and journal:
        fail("give --journal PATH or --no-journal, not both")
    journal = None if no_journal else (journal or str(field.controller.default_journal_path(link)))
    try:
        executor = PybulletTrialExecutor(pile, trial=trial)
        base_tm = _parse_triple(base, "--base") if base else default_crane_base(executor.pile)
        config = crane_config(base_tm, max_reach, max_pile_age, journal)
    except (FieldError, SynthError, ValueError) as exc:
        fail(str(exc))
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    typer.echo(f"crane controller twin serving {link} (base E {base_tm[0]:.3f} N {base_tm[1]:.3f}); "
               f"journal {journal or 'OFF (ids forgotten on restart)'}; Ctrl-C stops")
    try:
        final = field.controller.run_controller(link, executor, stop, config)
    except (FieldError, ValueError) as exc:
        fail(str(exc))
    typer.echo(f"stopped in state {final.state.name}")


@app.command("link-key")
def link_key_command(path: str = typer.Argument(..., help="Key file to create (mode 0600; never overwritten).")) -> None:
    """Create a pre-shared key for authenticated crane-link frames (SecOC style).

    Give the same file to both ends, e.g. --link 'can://socketcan/can0?secoc_key=PATH' on the
    laptop and on the crane (crane-sim). The key is never printed.

    Example: loggrasp link-key ~/.config/loggrasp/crane1.key
    """
    from field.errors import KeyFileError
    from field.link.secoc import generate_key_file

    try:
        written = generate_key_file(path)
    except KeyFileError as exc:
        fail(str(exc))
    typer.echo(f"wrote a new key to {written} (mode 0600); copy it to the crane over a secure channel")


def with_secoc_key(link: str, key: Path) -> str:
    """``link`` with ``secoc_key=KEY`` added to its query."""
    return f"{link}{'&' if '?' in link else '?'}secoc_key={key}"


def default_crane_base(pile) -> tuple[float, float, float]:
    """A crane base 5 m south (site frame) of the pile centre, at ground height."""
    import numpy as np

    from synth.geodesy import pile_to_site, site_to_tm

    c = np.mean([log.centre_m for log in pile.logs], axis=0)
    site = pile_to_site(pile.georef, np.array([c[0], c[1], float(pile.terrain.height_at(c[0], c[1]))]))
    e, n, h = site_to_tm(pile.georef, site + np.array([0.0, -5.0, 0.0]))
    return float(np.ravel(e)[0]), float(np.ravel(n)[0]), float(np.ravel(h)[0])


def crane_config(base_tm, max_reach: float, max_pile_age: float, journal: str | None = None):
    from field.controller import ControllerConfig, ReachEnvelope

    return ControllerConfig(reach=ReachEnvelope(base_easting_m=base_tm[0], base_northing_m=base_tm[1],
                                                base_height_m=base_tm[2], max_reach_m=max_reach),
                            max_pile_age_s=max_pile_age, journal_path=journal)


def _trial_options(objective, model, allow_float, max_pile_age, base, max_reach, capacity, views=1, view_spread=0.0):
    from field.trial import TrialOptions

    return TrialOptions(objective=objective, model=model, allow_float=allow_float, max_pile_age_s=max_pile_age,
                        crane_base_tm=_parse_triple(base, "--base") if base else None, max_reach_m=max_reach,
                        lift_capacity_kg=capacity, views=views, view_spread_k=view_spread)


def _show_plan(prepared) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title="plan (best grasp per target subset)")
    for col in ("rank", "targets", "q", "u", "b", "width m"):
        table.add_column(col, justify="right")
    for i, g in enumerate(prepared.plan.grasps[:5]):
        table.add_row(str(i + 1), ",".join(map(str, g.targets)), f"{g.quality:.3f}", f"{g.graspability:.3f}",
                      f"{g.balance:.3f}", f"{g.grasp.width_m:.2f}")
    console.print(table)
    for line in prepared.summary_lines():
        console.print("  " + line)
    console.print("  pictures and GeoJSON go to the record's plan/ folder: plan.png, grasp_map.png, pile.geojson")


@app.command("trial")
def trial_command(
    scan: str = typer.Option(..., "--scan", help="Scan folder (stereo pair folders + scan_pose.json)."),
    gnss: str = typer.Option(..., "--gnss", help="RTK endpoint survey CSV."),
    link: str = typer.Option(..., "--link", help="Crane link URL: can://..., zenoh://..., twin://..."),
    record: str = typer.Option(..., "--record", help="Trial record folder to create."),
    objective: str = typer.Option("f3", "--objective"),
    model: str = typer.Option(None, "--model", help="Checkpoint; default: the shipped model."),
    views: int = typer.Option(1, "--views", help="Dihedral views the planner averages: 1, 2, 4 or 8 (slower, steadier)."),
    view_spread: float = typer.Option(0.0, "--view-spread", help="Lower U by K x its spread over the views (needs --views > 1)."),
    yes: bool = typer.Option(False, "--yes", help="Do not ask for confirmation before sending."),
    allow_float: bool = typer.Option(False, "--allow-float", help="Accept RTK float endpoints."),
    max_pile_age: float = typer.Option(DEFAULT_MAX_PILE_AGE_S, "--max-pile-age", help="Refuse pile data older than this [s]."),
    base: str = typer.Option(None, "--base", help="Crane base E,N,H (SWEREF 99 TM) for the reach check."),
    max_reach: float = typer.Option(10.0, "--max-reach", help="[m]"),
    capacity: float = typer.Option(1500.0, "--capacity", help="Lift capacity [kg]."),
) -> None:
    """Field trial: reconstruct, plan, show, confirm, send, wait for the outcome, record everything.

    Example: loggrasp trial --scan s3/scan --gnss s3/gnss.csv --link can://virtual/ch0 --record trials/t1
    """
    from field.errors import FieldError
    from field.trial import TrialAborted, run_trial_record

    def confirm(prepared) -> bool:
        _show_plan(prepared)
        return yes or typer.confirm("send this grasp to the crane?", default=False)

    try:
        opts = _trial_options(objective, model, allow_float, max_pile_age, base, max_reach, capacity, views,
                              view_spread)
        rec = run_trial_record(scan, gnss, link, record, opts, confirm=confirm, progress=typer.echo)
    except TrialAborted as exc:
        fail(f"{exc} (record: {record})", code=3)
    except (FieldError, ValueError) as exc:
        fail(str(exc))
    typer.echo(f"final state: {rec['final_state']}  outcome: {rec.get('outcome')}  record: {record}")
    if rec["final_state"] != "SUCCESS":
        raise typer.Exit(4)


@app.command("replay")
def replay_command(
    record: str = typer.Argument(..., help="A trial record folder."),
    out: str = typer.Option(None, "--out", help="Work folder for the re-run (default: a temp folder)."),
    link: str = typer.Option(None, "--link", help="Re-send the recorded command to this (twin) link."),
    realtime: bool = typer.Option(False, "--realtime", help="Replay the recorded CAN traffic with its original timing."),
) -> None:
    """Re-run reconstruction and planning from a trial record; say whether the command is bit-identical.

    Example: loggrasp replay trials/t1 --link twin://?executor=fixed
    """
    import json
    import tempfile
    from pathlib import Path

    from field.errors import FieldError
    from field.trial import TrialAborted, read_record, replay_record

    work = out or tempfile.mkdtemp(prefix="loggrasp-replay-")
    try:
        result = replay_record(record, work, progress=typer.echo)
    except (TrialAborted, FieldError) as exc:
        fail(str(exc))
    typer.echo(json.dumps(result, indent=1))
    if realtime:
        blf = Path(record) / "link" / "traffic.blf"
        if not blf.exists():
            fail(f"{record} has no CAN recording (link/traffic.blf): --realtime needs a CAN trial")
        from field.link.can_backend import replay as replay_can

        n = sum(1 for _ in replay_can(blf, realtime=True))
        typer.echo(f"replayed {n} recorded frames with their original timing")
    if link:
        from field.link import GraspCommand, open_link
        from field.link.base import LinkConfig
        from field.link.safety import SafetyConfig

        from field.errors import CommandRejected, LinkError

        rec = read_record(record)
        fields = dict(rec["command"])
        try:
            # the recorded plan is old by design: the laptop-side age check is lifted for a replay;
            # the controller keeps its own (a real crane refuses it: use a twin with crane_max_pile_age_s)
            with open_link(link, LinkConfig(safety=SafetyConfig(max_pile_age_s=1e12))) as lk:
                cmd = GraspCommand(command_id=lk.new_command_id(), **fields)
                lk.send_grasp(cmd, timeout_s=2.0)
                res = lk.wait_outcome(cmd.command_id, timeout_s=120.0)
        except CommandRejected as exc:
            fail(f"the controller rejected the re-sent command: {exc}. Recorded data is old; a twin "
                 "accepts it with e.g. twin://?executor=pybullet&pile=PILE.json&crane_base=E,N,H&crane_max_pile_age_s=1e9")
        except LinkError as exc:
            fail(f"re-sending failed: {exc}")
        typer.echo(f"re-sent as command {cmd.command_id}: {res.outcome_class.name}, {res.logs_grasped} logs")
    if not result["identical"]:
        raise typer.Exit(5)


DEMO_DATA = Path(__file__).resolve().parent / "demo_data"


@app.command("demo")
def demo(
    out: str = typer.Option("out/demo", "--out", help="Output folder (trial record, pictures)."),
    link: str = typer.Option("can://virtual/loggrasp-demo", "--link", help="Link to the in-process crane twin."),
    model: str = typer.Option(None, "--model", help="Checkpoint; default: the shipped model."),
) -> None:
    """The main job on the embedded default: a bundled recorded scan (stereo pair + RTK endpoints)
    is reconstructed, planned on, sent as a SWEREF 99 TM grasp over simulated CAN to the crane
    controller twin, executed in pybullet on the true pile, and recorded.
    """
    import shutil
    import threading
    import time as _time

    from field.controller import run_controller
    from field.executor import PybulletTrialExecutor
    from field.trial import TrialAborted, run_trial_record
    from synth.pile import read_pile

    t0 = _time.perf_counter()
    data = DEMO_DATA
    truth = read_pile(data / "truth" / "pile.json")
    base = default_crane_base(truth)
    # the bundled scan was recorded earlier: its staleness limit is set past its age, and said so
    from field.trial import captured_time

    age = _time.time() - captured_time(data / "scan", data / "gnss.csv")
    max_age = age + 3600.0
    typer.echo(f"bundled scan recorded {age / 86400:.1f} days ago: staleness limit raised to {max_age:.0f} s for the demo")
    out_dir = Path(out)
    record = out_dir / "trial"
    if record.exists():
        shutil.rmtree(record)
    from field.link.secoc import generate_key_file

    key = out_dir / "link.key"
    if not key.exists():
        generate_key_file(key)
    link = with_secoc_key(link, key)
    typer.echo(f"authenticated frames on (SecOC-style MACs, key {key}); crane journal {out_dir / 'crane-journal.jsonl'}")
    stop, ready = threading.Event(), threading.Event()
    config = crane_config(base, 10.0, max_age, str(out_dir / "crane-journal.jsonl"))
    crane = threading.Thread(target=run_controller, daemon=True, name="crane-twin",
                             args=(link, PybulletTrialExecutor(truth), stop, config), kwargs={"ready_event": ready})
    crane.start()
    if not ready.wait(20):
        fail("the crane controller twin did not start")
    try:
        opts = _trial_options("f3", model, False, max_age, f"{base[0]},{base[1]},{base[2]}", 10.0, 1500.0)

        def show(prepared) -> bool:
            _show_plan(prepared)
            return True

        rec = run_trial_record(data / "scan", data / "gnss.csv", link, record, opts, confirm=show, progress=typer.echo)
    except TrialAborted as exc:
        fail(str(exc), code=3)
    finally:
        stop.set()
        crane.join(10)
    typer.echo(f"crane twin: {rec['final_state']}, outcome {rec.get('outcome')}")
    typer.echo(f"record: {record} (plan pictures in {record / 'plan'}); whole chain {_time.perf_counter() - t0:.1f} s")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
