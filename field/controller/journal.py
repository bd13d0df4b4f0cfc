"""The controller's journal: every command id it has seen, burned across restarts."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from field.audit.journal import chained_journal, rewrite_journal
from field.errors import ControllerError
from field.link.messages import Outcome, OutcomeClass, RejectReason

log = logging.getLogger(__name__)

JOURNAL_FORMAT = "loggrasp.controller_journal"
JOURNAL_VERSION = "2.1"  # 2.1: hash-chained lines (field/audit/chain.py); 2.0 is read and rewritten chained


def _outcome_doc(out: Outcome) -> dict[str, Any]:
    return {"outcome_class": out.outcome_class.name, "logs_grasped": out.logs_grasped,
            "balance_cos_milli": out.balance_cos_milli}


class ControllerJournal:
    """Persistent memory of every command id seen, and of outcomes (append-only JSON lines).

    First line ``{"format", "version"}``, then one entry per line: ``{"command_id", "status":
    "accepted"|"rejected"|"done", "reason": NAME (rejected), "outcome": {...} (done)}``; a later
    line about an id supersedes an earlier one. Each line is flushed (and fsynced) before the
    controller answers. An id accepted but never finished (controller crashed mid-command) is
    reported ABORTED on load. A version-1 journal (one JSON document) is read and rewritten as
    version 2; a journal with more than ``2 * keep`` lines is compacted to its last ``keep`` ids
    on load (an id older than that is long past any staleness limit). Lines are hash-chained
    (2.1, :mod:`field.audit.chain`; a compaction's head continues the old head); ``loggrasp audit
    verify`` checks the file, and a chain that does not verify is refused on load.
    """

    def __init__(self, path: str | Path, keep: int = 10_000, fsync: bool = True):
        self.path = Path(path)
        self.keep = keep
        self.fsync = fsync
        self.entries: dict[int, dict[str, Any]] = {}
        self._lines = 0
        self._chain = None  # the hash chain's writer (field.audit.chain.ChainFile)
        if self.path.exists():
            self._load()
        if not self.path.exists() or self._lines > 2 * keep:
            self._rewrite()

    def _load(self) -> None:
        try:
            lines = self.path.read_text().splitlines()
            head = json.loads(lines[0]) if lines else {}
        except (OSError, ValueError) as exc:
            raise ControllerError(f"controller journal {self.path} is unreadable ({exc}); move it away") from exc
        if head.get("format") != JOURNAL_FORMAT:
            raise ControllerError(f"{self.path} is not a {JOURNAL_FORMAT} file; move it away or fix --journal")
        major = str(head.get("version", "")).split(".")[0]
        if major == "1":
            for e in head.get("entries", []):
                self._put(e)
            self._lines = 10 ** 9  # rewrite as version 2
            return
        if major != JOURNAL_VERSION.split(".")[0]:
            raise ControllerError(f"{self.path} has journal version {head.get('version')}, this code reads "
                                  f"1.x and {JOURNAL_VERSION.split('.')[0]}.x; update loggrasp")
        self._read_entries(lines[1:])
        self._chain = chained_journal(self.path, self.fsync)  # None: rewrite it chained
        self._lines = self._lines if self._chain is not None else 10 ** 9

    def _read_entries(self, lines: list[str]) -> None:
        for i, line in enumerate(lines):
            try:
                self._put(json.loads(line))
            except (ValueError, KeyError, TypeError) as exc:
                if i == len(lines) - 1:  # a torn last line: the controller died while writing it
                    log.warning("journal %s: ignoring its torn last line", self.path)
                    break
                raise ControllerError(f"controller journal {self.path} line {i + 2} is corrupt ({exc}); "
                                      f"move the file away") from exc
        self._lines = len(lines)

    def _put(self, entry: dict[str, Any]) -> None:
        cid = int(entry["command_id"])
        self.entries.pop(cid, None)  # re-insert: dict order = order of the latest line
        self.entries[cid] = entry

    def _rewrite(self) -> None:
        items = list(self.entries.values())[-self.keep:]
        self.entries = {int(e["command_id"]): e for e in items}
        self._chain = rewrite_journal(self.path, {"format": JOURNAL_FORMAT, "version": JOURNAL_VERSION}, items,
                                      self._chain, self.fsync)
        self._lines = len(items)

    def _append(self, entry: dict[str, Any]) -> None:
        self._put(entry)
        self._chain.append(entry)  # one write of a whole line, fsynced
        self._lines += 1

    def record_accepted(self, command_id: int, digest: str | None = None) -> None:
        self._append({"command_id": command_id, "status": "accepted", "digest": digest})

    def record_rejected(self, command_id: int, reason: RejectReason, digest: str | None = None) -> None:
        self._append({"command_id": command_id, "status": "rejected", "reason": reason.name, "digest": digest})

    def record_outcome(self, outcome: Outcome) -> None:
        digest = self.entries.get(outcome.command_id, {}).get("digest")
        self._append({"command_id": outcome.command_id, "status": "done", "digest": digest,
                      "outcome": _outcome_doc(outcome)})

    def recover(self) -> tuple[dict[int, tuple[str | None, RejectReason]], Outcome | None]:
        """(decision per id seen: (command digest, reason; NONE = accepted), last outcome);
        interrupted commands become ABORTED (and are journaled)."""
        last: Outcome | None = None
        decisions: dict[int, tuple[str | None, RejectReason]] = {}
        for cid, e in list(self.entries.items()):
            reason = RejectReason[e["reason"]] if e["status"] == "rejected" else RejectReason.NONE
            decisions[cid] = (e.get("digest"), reason)
            if e["status"] == "accepted":
                last = Outcome(cid, OutcomeClass.ABORTED, 0, 0)
                self.record_outcome(last)
            elif e["status"] == "done":
                o = e["outcome"]
                last = Outcome(cid, OutcomeClass[o["outcome_class"]], int(o["logs_grasped"]), int(o["balance_cos_milli"]))
        return decisions, last
