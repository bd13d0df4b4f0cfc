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

import typer

from field.audit.cli import audit_app
from field.cli.crane_sim import crane_sim
from field.cli.options import TWIN_PARAMETERS
from field.cli.trial import demo, replay_command, trial_command
from field.link.cli import link_key_command
from planner.cli import eval_command, plan_command, train_command
from planner.cli.learn import round_command, train_ranker_command
from reconstruct.cli import compare_command, reconstruct_command, scan_command
from reconstruct.survey.cli import survey_command
from synth.cli import APP_SETTINGS
from synth.cli import app as synth_app
from synth.common.cli import (EXIT_CODES, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_LINK, CliError,
                              flag_of_path, to_flags)

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
app.command("round")(round_command)
app.command("train-ranker")(train_ranker_command)
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



app.command("crane-sim")(crane_sim)
app.command("trial", epilog=TWIN_PARAMETERS)(trial_command)
app.command("replay", epilog=TWIN_PARAMETERS)(replay_command)
app.command("demo")(demo)


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

