"""``loggrasp audit``: check a controller journal or a trial record for tampering (thin commands)."""

from __future__ import annotations

from pathlib import Path

import typer

from synth.cli import APP_SETTINGS, JSON
from synth.common.cli import CliError, Output, check_input, option

audit_app = typer.Typer(help="Tamper-evident records: check the hash chain of a controller journal or a trial "
                             "record.", **APP_SETTINGS)


@audit_app.command("verify")
def verify_command(
    record: Path = typer.Argument(..., metavar="RECORD",
                                  help="A controller journal file (crane-sim --journal) or a trial record folder."),
    head: str = option("--head", "The sha256 (or a prefix of it) the chain must end at, kept elsewhere from an "
                       "earlier verification: catches entries cut off the end or a rewritten chain.",
                       default=None, metavar="SHA256"),
    as_json: bool = JSON,
) -> None:
    """Verify the hash chain of a journal or trial record: say OK with its head hash, or name the first broken entry.

    Every entry carries the sha256 of the one before it, so an edited byte, a deleted, inserted or
    reordered entry, or (for a trial record) a file changed after it was sealed, is named with
    the entry where the chain first fails. Exit 0: the chain verifies; 2: it is broken, or the
    journal/record predates hash chains (then it says so: nothing to verify is not "broken").

    \b
    Example: loggrasp audit verify out/demo/trial
    Example: loggrasp audit verify ~/.local/state/loggrasp/journal-virtual-crane.jsonl --json
    """
    from field.audit.report import REPORT_FORMAT, REPORT_VERSION, verify

    o = Output(as_json)
    check_input(record, "RECORD")
    if head is not None and (len(head) < 8 or any(c not in "0123456789abcdefABCDEF" for c in head)):
        raise CliError(f"--head {head!r} is not a sha256 in hex (at least 8 digits)")
    report = verify(record, head)
    o.result(REPORT_FORMAT, report.to_dict(), REPORT_VERSION)
    if report.status == "ok":
        o.say(report.line())
        return
    raise CliError(report.line())
