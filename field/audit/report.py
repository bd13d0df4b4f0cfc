"""What ``loggrasp audit verify`` says about a journal or a trial record, and the one entry point.

:func:`verify` reads a controller journal (a file) or a trial record (a folder with
``record.json``) and returns an :class:`AuditReport`: ``ok`` (the chain verifies; its head hash,
entry count and notes), ``broken`` (the first entry that does not verify, and what differs) or
``unchained`` (written before hash chains: nothing to verify, which is not the same as broken).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

REPORT_FORMAT = "loggrasp.audit"
REPORT_VERSION = "1.0"


@dataclass
class AuditReport:
    """The verdict on one file or folder."""

    path: str
    kind: str  # "controller journal" | "trial record"
    status: str = "ok"  # "ok" | "broken" | "unchained"
    entries: int = 0  # chained lines that verify, genesis included
    head: str | None = None  # hash of the last verified line
    broken_at: int | None = None  # index of the first entry that does not verify (0: the genesis)
    entry: str = ""  # that entry, named for people (index, line, command id or file)
    problem: str = ""  # what differs there
    notes: list[str] = field(default_factory=list)  # things that verify but a reviewer should know

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def unchained(self, why: str) -> "AuditReport":
        self.status, self.problem = "unchained", why
        return self

    def broken(self, check: Any, entry: str) -> "AuditReport":
        """Broken where ``check`` (a :class:`~field.audit.chain.ChainCheck`) stopped."""
        self.status, self.broken_at, self.entry, self.problem = "broken", check.broken_at, entry, check.problem
        self.entries, self.head = len(check.entries), check.head
        return self

    def broken_entry(self, index: int | None, entry: str, problem: str) -> "AuditReport":
        self.status, self.broken_at, self.entry, self.problem = "broken", index, entry, problem
        return self

    def verified(self, check: Any) -> None:
        """The counts of a chain that verified (``check``: a ChainCheck); a torn tail noted."""
        self.entries, self.head = len(check.entries), check.head
        if check.torn_tail:
            self.notes.append(f"a torn last line after entry {len(check.entries) - 1} (a writer stopped mid-append); "
                              "everything before it verifies")

    def expect_head(self, head: str | None) -> None:
        """Broken unless the chain ends at ``head`` (a hash kept outside the file): catches a
        rollback or a clean cut of the last entries, which a chain alone cannot."""
        if head is None or not self.ok or (self.head or "").startswith(head.lower()):
            return
        self.broken_entry(self.entries - 1, f"entry {self.entries - 1} (the last)",
                          f"the chain ends at head {str(self.head)[:12]}…, not at the expected --head {head[:12]}… "
                          "(entries were cut off or the chain was rewritten)")

    def line(self) -> str:
        """One line for people."""
        if self.status == "unchained":
            return f"{self.path}: {self.kind} without a hash chain: {self.problem}"
        if self.status == "broken":
            return f"{self.path}: {self.kind} hash chain broken at {self.entry}: {self.problem}"
        notes = "".join(f"; note: {n}" for n in self.notes)
        return (f"{self.path}: {self.kind} OK: {self.entries} chained entries (genesis included) verify, "
                f"head sha256 {self.head}{notes}")

    def to_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, **asdict(self)}


def verify(path: str | Path, head: str | None = None) -> AuditReport:
    """Check the journal file or trial record folder at ``path`` (``head``: the hash its chain
    must end at). Raises :class:`~field.audit.chain.AuditError` when it is neither, or unreadable."""
    from field.audit.chain import AuditError

    path = Path(path)
    if path.is_dir():
        from field.audit.record import verify_record

        report = verify_record(path)
    else:
        from field.audit.journal import verify_journal

        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise AuditError(f"cannot read {path}: {exc.strerror or exc}") from exc
        report = verify_journal(path, raw)
    report.expect_head(head)
    return report
