"""A hash-chained JSON-lines file: each line carries the sha256 of the line before it.

Line 0 is the *genesis* (a file's head: its ``format`` and version, and ``prev``: ``None``, or the
head of the chain it continues after a compaction); every later line is an entry. Each line is
the canonical serialisation (:func:`canonical`: sorted keys, no spaces, ASCII) of a JSON object
that holds ``hash`` = sha256 of the canonical serialisation of the same object without ``hash``,
and — every line but the genesis — ``prev`` = the previous line's ``hash``::

    {"format":"loggrasp.x","hash":"9f…","prev":null,"version":"1.0"}
    {"command_id":7,"hash":"41…","prev":"9f…","status":"accepted"}

So an edited byte changes a line's hash (or makes it no longer canonical), and a deleted,
inserted or reordered line breaks the next line's ``prev``. A chain alone cannot tell a clean
cut of its last lines from a shorter history: its owner anchors the head elsewhere (a trial
record's ``record.json`` names its own entry; a head kept outside the file is checked with
``loggrasp audit verify --head``).

Appends are one ``write`` of a whole line, flushed and fsynced; a crash mid-append leaves at most
a *torn* last line without its newline, which :func:`check_lines` reports (the chain before it
verifies) and :meth:`ChainFile.resume` cuts off before appending again.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from field.errors import FieldError

HASH_KEY = "hash"  # the line's own sha256 (hex)
PREV_KEY = "prev"  # the previous line's hash; the genesis: None or the head it continues


class AuditError(FieldError):
    """A record or journal could not be checked (missing, unreadable, not a loggrasp file)."""


def canonical(obj: dict[str, Any]) -> str:
    """The one serialisation that is hashed and written: sorted keys, no spaces, ASCII only."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def entry_hash(obj: dict[str, Any]) -> str:
    """sha256 (hex) of ``obj``'s canonical serialisation without its ``hash`` field."""
    body = {k: v for k, v in obj.items() if k != HASH_KEY}
    return hashlib.sha256(canonical(body).encode("ascii")).hexdigest()


def seal(obj: dict[str, Any], prev: str | None) -> tuple[str, str]:
    """(the line to write, without newline; its hash) of ``obj`` chained after ``prev``; ``obj``'s
    own ``prev`` / ``hash`` fields are replaced."""
    body = {k: v for k, v in obj.items() if k not in (HASH_KEY, PREV_KEY)}
    body[PREV_KEY] = prev
    digest = entry_hash(body)
    return canonical({**body, HASH_KEY: digest}), digest


# --- checking ---------------------------------------------------------------------------------


@dataclass
class ChainCheck:
    """What :func:`check_lines` found: the entries that verify, and the first break if any."""

    entries: list[dict[str, Any]] = field(default_factory=list)  # verified lines; [0] is the genesis
    broken_at: int | None = None  # index of the first line that does not verify
    problem: str = ""  # what differs there, one line
    torn_tail: bool = False  # the file ends in a partial line (a crash mid-append)

    @property
    def ok(self) -> bool:
        return self.broken_at is None

    @property
    def head(self) -> str | None:
        """The last verified line's hash."""
        return self.entries[-1][HASH_KEY] if self.entries else None


def _split(raw: bytes) -> tuple[list[bytes], bytes]:
    """(complete lines, the unterminated tail: b"" when the file ends with a newline)."""
    *lines, tail = raw.split(b"\n")
    return lines, tail


def _is_torn(tail: bytes) -> bool:
    """A tail a crash mid-append leaves: the start of a line, never a whole JSON value."""
    try:
        json.JSONDecoder().raw_decode(tail.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return True
    return False  # a whole object followed by something: an edit, not a crash


def _check_line(i: int, line: bytes, prev: str | None, genesis_prev_free: bool) -> tuple[dict | None, str]:
    """(the parsed line, "") when line ``i`` verifies after ``prev``; else (None, what differs)."""
    try:
        obj = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        return None, f"not a JSON line ({exc})"
    if not isinstance(obj, dict) or not isinstance(obj.get(HASH_KEY), str):
        return None, "no hash field: not a chained line"
    if obj[HASH_KEY] != entry_hash(obj):
        return None, f"its content does not match its hash {obj[HASH_KEY][:12]}… (the entry was edited)"
    if canonical(obj).encode() != line:
        return None, "its bytes are not the canonical serialisation of its content (the line was edited)"
    if i == 0 and genesis_prev_free:
        return obj, ""
    if obj.get(PREV_KEY) != prev:
        got = str(obj.get(PREV_KEY))[:12]
        return None, (f"its prev {got}… is not the hash {str(prev)[:12]}… of entry {i - 1} (an entry before it was "
                      "deleted, inserted or reordered)")
    return obj, ""


def check_lines(raw: bytes) -> ChainCheck:
    """Verify a chained file's bytes from its genesis; stops at the first line that does not."""
    lines, tail = _split(raw)
    out = ChainCheck()
    prev: str | None = None
    for i, line in enumerate(lines):
        obj, problem = _check_line(i, line, prev, genesis_prev_free=True)
        if obj is None:
            out.broken_at, out.problem = i, problem
            return out
        out.entries.append(obj)
        prev = obj[HASH_KEY]
    if tail:
        if _is_torn(tail):
            out.torn_tail = True
        else:
            out.broken_at, out.problem = len(lines), "the last line has no newline after a whole entry (edited)"
    return out


# --- writing ----------------------------------------------------------------------------------


class ChainFile:
    """The writer of a chained file: :meth:`create` (or :meth:`resume`), then :meth:`append`.

    :meth:`create` writes the whole file atomically (genesis and entries: a new file, or a
    compaction); :meth:`append` adds one line with a single write, flushed (and fsynced)."""

    def __init__(self, path: str | Path, head: str, fsync: bool = True):
        self.path = Path(path)
        self.head = head  # hash of the last line
        self.fsync = fsync

    @classmethod
    def create(cls, path: str | Path, genesis: dict[str, Any], entries: list[dict[str, Any]] = (),
               continues: str | None = None, fsync: bool = True) -> "ChainFile":
        """Write ``genesis`` (its ``prev``: ``continues``) and ``entries`` chained, atomically."""
        from synth.common.files import atomic_write_bytes

        line, head = seal(genesis, continues)
        lines = [line]
        for e in entries:
            line, head = seal(e, head)
            lines.append(line)
        atomic_write_bytes(path, ("\n".join(lines) + "\n").encode("ascii"))
        return cls(path, head, fsync)

    @classmethod
    def resume(cls, path: str | Path, fsync: bool = True) -> "ChainFile":
        """Continue an existing chained file: a torn last line (a crash mid-append) is cut off
        first; a chain that does not verify raises :class:`AuditError` (nothing is appended to it)."""
        path = Path(path)
        raw = path.read_bytes()
        check = check_lines(raw)
        if not check.ok:
            raise AuditError(f"{path}: hash chain broken at entry {check.broken_at}: {check.problem}; "
                             "move the file away (it is evidence) and start a new one")
        if check.torn_tail:
            with open(path, "r+b") as f:
                f.truncate(raw.rfind(b"\n") + 1)
                f.flush()
                os.fsync(f.fileno())
        if check.head is None:
            raise AuditError(f"{path}: an empty chain (no genesis line); move the file away")
        return cls(path, check.head, fsync)

    def append(self, entry: dict[str, Any]) -> str:
        """Chain ``entry`` after the head and append it; returns its hash."""
        line, digest = seal(entry, self.head)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        try:
            data = (line + "\n").encode("ascii")
            if os.write(fd, data) != len(data):
                raise OSError(f"short write appending to {self.path}")
            if self.fsync:
                os.fsync(fd)
        finally:
            os.close(fd)
        self.head = digest
        return digest
