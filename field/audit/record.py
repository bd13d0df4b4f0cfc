"""A trial record's hash chain (``RECORD/audit.jsonl``): its writer and its check.

Each time :mod:`field.trial` writes ``record.json`` (every step of a trial), :meth:`RecordSeal.write`
first appends to the chain one entry per file of the record folder that is new or changed since
the last step (``{"kind": "file", "path", "sha256", "bytes"}``; ``"removed"`` for one that is
gone), then one entry for the new ``record.json`` (``{"kind": "record", "sha256", "state"}``), and
only then replaces ``record.json`` atomically. ``record.json`` names its own entry (``audit``:
``{"chain", "entry", "prev"}``), so:

- an edited byte in any chained file, in ``record.json`` or in the chain is caught, naming the
  entry; a deleted, inserted or reordered chain entry breaks the next entry's ``prev``;
- a cut tail is caught because ``record.json`` names an entry past the chain's end (or, the
  record entry kept and files cut, a file that is in the folder but not in the chain);
- a crash mid-append leaves a torn last line and ``record.json`` at the previous step: it verifies,
  with a note (file entries past ``record.json``'s entry are an unfinished step);
- what it cannot catch alone: a rollback of the whole folder to an earlier step (the chain cut
  back AND ``record.json`` and the later files replaced by their earlier bytes). For that, keep
  the head hash the verification prints somewhere else and pass it as ``--head``.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Any

from field.audit.chain import AuditError, ChainCheck, ChainFile, check_lines
from field.audit.report import AuditReport
from synth.common.formats import VersionedJson

AUDIT_FILE = "audit.jsonl"
CHAIN_FORMAT = "loggrasp.audit-chain"
CHAIN_VERSION = "1.0"
RECORD_FILE = "record.json"
RECORD_FORMAT = "loggrasp.trial-record"  # the same name field.trial writes
_NOT_SEALED_AS_FILES = (AUDIT_FILE, RECORD_FILE)  # the chain itself, and record.json (its own entries)
CHAIN = VersionedJson(CHAIN_FORMAT, CHAIN_VERSION, "trial record audit chain", AuditError,
                      fix="upgrade loggrasp to verify it")
RECORD = VersionedJson(RECORD_FORMAT, "1.3", "trial record", AuditError, fix="upgrade loggrasp to verify it")


def _files(folder: Path) -> dict[str, Path]:
    """The record folder's files by path relative to it (posix), the chain and record.json aside."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_file() and rel not in _NOT_SEALED_AS_FILES:
            out[rel] = p
    return out


def _sha256(path: Path) -> str:
    from synth.common.files import sha256_file

    return sha256_file(path)


class RecordSeal:
    """The hash chain of one trial record while the trial writes it (one per trial)."""

    def __init__(self) -> None:
        self._sealed: dict[str, str] = {}  # file -> the sha256 last chained
        self._chain: ChainFile | None = None
        self._entries = 0  # lines in the chain, genesis included

    def _append(self, entry: dict[str, Any]) -> None:
        self._chain.append(entry)
        self._entries += 1

    def _changed_files(self, folder: Path) -> list[dict[str, Any]]:
        files = _files(folder)
        out = []
        for rel, path in files.items():
            sha = _sha256(path)
            if self._sealed.get(rel) != sha:
                out.append({"kind": "file", "path": rel, "sha256": sha, "bytes": path.stat().st_size})
                self._sealed[rel] = sha
        for rel in sorted(set(self._sealed) - set(files)):
            out.append({"kind": "removed", "path": rel})
            del self._sealed[rel]
        return out

    def write(self, folder: Path, record: dict[str, Any]) -> None:
        """Chain the folder's changed files and the new ``record.json``, then write it atomically.
        ``record`` gets its ``audit`` field (the entry that seals it)."""
        from synth.common.files import atomic_write_bytes

        if self._chain is None:
            self._chain = ChainFile.create(folder / AUDIT_FILE, CHAIN.document(
                {"what": "trial record", "created_utc_s": time.time()}))
            self._entries = 1
        self._chain.path = folder / AUDIT_FILE  # the folder may have been renamed into place
        for entry in self._changed_files(folder):
            self._append(entry)
        record["audit"] = {"chain": AUDIT_FILE, "entry": self._entries, "prev": self._chain.head}
        data = json.dumps(record, indent=1).encode()
        self._append({"kind": "record", "path": RECORD_FILE, "sha256": hashlib.sha256(data).hexdigest(),
                      "state": record.get("final_state")})
        atomic_write_bytes(folder / RECORD_FILE, data)


# --- checking ---------------------------------------------------------------------------------


def _name(i: int, e: dict[str, Any] | None) -> str:
    if e is None:
        return f"entry {i}"
    what = e.get("path") or ("genesis" if i == 0 else e.get("kind", "?"))
    state = f", state {e['state']}" if e.get("state") else ""
    return f"entry {i} ({e.get('kind', 'genesis')} {what}{state})" if i else "entry 0 (genesis)"


def _parse_line(raw: bytes, i: int) -> dict[str, Any] | None:
    try:
        obj = json.loads(raw.split(b"\n")[i].decode("utf-8"))
        return obj if isinstance(obj, dict) else None
    except (IndexError, UnicodeDecodeError, ValueError):
        return None


def _check_record_entry(report: AuditReport, entries: list[dict], claimed: Any, record_raw: bytes) -> bool:
    """record.json against the chain's last record entry (``claimed``: the entry record.json
    names, for the diagnosis); False when it does not match (the report says why)."""
    records = [i for i, e in enumerate(entries) if e.get("kind") == "record"]
    last = records[-1] if records else None
    sha = hashlib.sha256(record_raw).hexdigest()
    if last is not None and entries[last].get("sha256") == sha:
        if len(entries) > last + 1:
            report.notes.append(f"{len(entries) - last - 1} file entries after record.json's entry {last}: a step "
                                "that did not finish (the trial stopped while writing)")
        return True
    if isinstance(claimed, int) and claimed >= len(entries):
        report.broken_entry(len(entries), f"entry {claimed} (record {RECORD_FILE})",
                            f"record.json was sealed as entry {claimed} but the chain ends at entry "
                            f"{len(entries) - 1}: its tail was cut off")
    elif any(entries[i].get("sha256") == sha for i in records):
        report.broken_entry(last, _name(last, entries[last]),
                            f"the chain seals a later {RECORD_FILE} than the folder's: record.json was rolled back, or "
                            "the writer stopped between appending this entry and replacing record.json")
    else:
        report.broken_entry(last, _name(last, entries[last]) if last is not None else RECORD_FILE,
                            f"{RECORD_FILE} differs from the sha256 sealed in this entry (edited)")
    return False


def _check_files(report: AuditReport, folder: Path, entries: list[dict]) -> None:
    """The folder's files against the last entry of each in the chain; the first difference."""
    sealed: dict[str, tuple[int, str | None]] = {}
    for i, e in enumerate(entries):
        if e.get("kind") == "file":
            sealed[e["path"]] = (i, e["sha256"])
        elif e.get("kind") == "removed":
            sealed[e["path"]] = (i, None)
    files = _files(folder)
    problems: list[tuple[float, str, str]] = []
    for rel, (i, sha) in sealed.items():
        if sha is None and rel in files:
            problems.append((i, _name(i, entries[i]), "the file was removed at this entry but is in the folder"))
        elif sha is not None and rel not in files:
            problems.append((i, _name(i, entries[i]), "the file is missing from the folder"))
        elif sha is not None and _sha256(files[rel]) != sha:
            problems.append((i, _name(i, entries[i]), "the file differs from the sha256 sealed in this entry (edited)"))
    for rel in sorted(set(files) - set(sealed)):
        problems.append((float("inf"), rel, "the file is not in the chain (added after sealing, or the chain's tail "
                                            "was cut off)"))
    if problems:
        i, name, problem = min(problems, key=lambda p: p[0])
        report.broken_entry(None if i == float("inf") else int(i), name, problem)
    report.notes.insert(0, f"{sum(1 for s in sealed.values() if s[1] is not None)} files sealed")


def _read(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise AuditError(f"cannot read {path}: {exc.strerror or exc}") from exc


def _parse_record(raw: bytes, path: Path, strict: bool) -> dict[str, Any] | None:
    """record.json as a dict when it is a trial record of a version this code reads; else None
    (``strict``: :class:`AuditError`, for a folder whose record.json no chain seals)."""
    try:
        return RECORD.check(json.loads(raw), path)
    except ValueError as exc:
        if strict:
            raise AuditError(f"{path} is not valid JSON ({exc}): not a trial record this code can check") from exc
    except AuditError:
        if strict:
            raise
    return None


def verify_record(folder: Path) -> AuditReport:
    """The check of a trial record folder: its chain, record.json and every file against it."""
    record_raw = _read(folder / RECORD_FILE)
    if record_raw is None:
        raise AuditError(f"{folder} is not a trial record (no {RECORD_FILE}); give a record folder or a journal file")
    chain_raw = _read(folder / AUDIT_FILE)
    rec = _parse_record(record_raw, folder / RECORD_FILE, strict=chain_raw is None)
    report = AuditReport(str(folder), "trial record")
    if chain_raw is None:
        if "audit" not in rec:
            return report.unchained(f"record format_version {rec['format_version']} predates hash chains (1.3)")
        return report.broken_entry(None, AUDIT_FILE, f"the chain file is missing (record.json names entry "
                                   f"{(rec.get('audit') or {}).get('entry')} of it)")
    check: ChainCheck = check_lines(chain_raw)
    if not check.ok:
        return report.broken(check, _name(check.broken_at, _parse_line(chain_raw, check.broken_at)))
    CHAIN.check(check.entries[0], folder / AUDIT_FILE)
    report.verified(check)
    claimed = (rec or {}).get("audit", {}).get("entry") if isinstance((rec or {}).get("audit"), dict) else None
    if not _check_record_entry(report, check.entries, claimed, record_raw):
        return report
    _check_files(report, folder, check.entries)
    if report.ok:
        report.notes.insert(1, f"record.json state {rec.get('final_state')}")
    return report
