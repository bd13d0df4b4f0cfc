"""The controller journal's hash chain: its writer's two hooks and its check.

:class:`field.controller.ControllerJournal` (format ``loggrasp.controller_journal`` 2.1) writes
its lines through :class:`~field.audit.chain.ChainFile`: the head line is the genesis, each
command-id line an entry. A compaction (or the rewrite of an unchained 2.0 / 1.x journal)
writes a new file whose genesis ``prev`` is the old file's head, so the chain continues.
"""

from __future__ import annotations

import json
import secrets
import time
from pathlib import Path
from typing import Any

from field.audit.chain import AuditError, ChainFile, check_lines
from field.audit.report import AuditReport
from field.errors import ControllerError

JOURNAL_FORMAT = "loggrasp.controller_journal"  # the same name field.controller writes
HASH_FIELD = b'"hash"'  # in every line of a chained journal, in none of an older one


def _unchained_version(raw: bytes) -> str | None:
    """The version of a journal written before hash chains (no line has a hash field, and its
    head says 2.0 or 1.x); None when the file is, or claims to be, chained."""
    if HASH_FIELD in raw:
        return None
    try:
        version = str(json.loads(raw.split(b"\n", 1)[0].decode("utf-8")).get("version", ""))
    except (UnicodeDecodeError, ValueError, AttributeError):
        return None  # not even a head: the chain check names entry 0
    return version if version.split(".")[:2] in (["2", "0"], ["2"]) or version.split(".")[0] == "1" else None


def chained_journal(path: Path, fsync: bool) -> ChainFile | None:
    """The chain writer of a journal just loaded; None when it predates chains (the caller
    rewrites it chained). A chain that does not verify raises :class:`ControllerError`: the ids
    it remembers cannot be trusted, so the controller does not start on it."""
    try:
        if _unchained_version(path.read_bytes()) is not None:
            return None
        return ChainFile.resume(path, fsync)
    except (AuditError, OSError) as exc:
        raise ControllerError(f"controller journal {exc}") from exc


def rewrite_journal(path: Path, head: dict[str, Any], items: list[dict[str, Any]], previous: ChainFile | None,
                    fsync: bool) -> ChainFile:
    """Write the journal anew (atomically), chained on from ``previous``'s head when there was one.
    The genesis gets a random chain id and its time, so no two journals share a genesis hash."""
    head = {**head, "chain_id": secrets.token_hex(8), "created_utc_s": time.time()}
    return ChainFile.create(path, head, items, continues=previous.head if previous is not None else None,
                            fsync=fsync)


def _entry_name(raw_line: bytes | None, index: int) -> str:
    """``entry I (line L, command_id C)``: the command id when the line still parses."""
    cid = None
    if raw_line is not None:
        try:
            cid = json.loads(raw_line.decode("utf-8")).get("command_id")
        except (UnicodeDecodeError, ValueError, AttributeError):
            pass
    return f"entry {index} (line {index + 1}" + (f", command_id {cid})" if cid is not None else ")")


def verify_journal(path: Path, raw: bytes) -> AuditReport:
    """The check of a controller journal's bytes: chained from its genesis, or why not."""
    report = AuditReport(str(path), "controller journal")
    if HASH_FIELD not in raw and f'"{JOURNAL_FORMAT}"'.encode() not in raw.split(b"\n", 1)[0]:
        raise AuditError(f"{path} is not a controller journal; give a journal file (crane-sim --journal) or a trial "
                         "record folder")
    version = _unchained_version(raw)
    if version is not None:
        return report.unchained(f"journal version {version} predates hash chains (2.1); a controller of this "
                                "version rewrites it chained when it next opens it")
    check = check_lines(raw)
    if not check.ok:
        lines = raw.split(b"\n")
        line = lines[check.broken_at] if check.broken_at < len(lines) else None
        return report.broken(check, _entry_name(line, check.broken_at))
    genesis = check.entries[0]
    if genesis.get("format") != JOURNAL_FORMAT:
        raise AuditError(f"{path}: not a controller journal (format {genesis.get('format')!r})")
    report.verified(check)
    if genesis.get("prev") is not None:
        report.notes.append(f"continues an earlier chain (compacted) whose head was {genesis['prev'][:12]}…")
    return report
