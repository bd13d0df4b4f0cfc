"""Tamper-evident records (issue 39): the controller journal and trial records, hash-chained, and
``loggrasp audit verify`` naming the first broken entry."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from field.audit.chain import ChainFile, check_lines
from field.audit.report import verify
from field.cli import run
from field.controller import ControllerJournal
from field.errors import ControllerError
from field.link.messages import Outcome, OutcomeClass, RejectReason
from field.trial import TrialOptions
from field.trial_record import _TrialRecord


def _journal(path: Path, n: int = 4, keep: int = 10_000) -> ControllerJournal:
    j = ControllerJournal(path, keep=keep, fsync=False)
    for cid in range(1, n + 1):
        j.record_accepted(cid, f"d{cid}")
        j.record_outcome(Outcome(cid, OutcomeClass.SUCCESS, 2, 990))
    j.record_rejected(n + 1, RejectReason.STALE, "dx")
    return j


def _line_of(raw: bytes, pos: int) -> int:
    return raw[:pos].count(b"\n")


def _each_byte_edited(raw: bytes):
    for pos in range(len(raw)):
        new = b"0" if raw[pos:pos + 1] != b"0" else b"1"
        yield pos, raw[:pos] + new + raw[pos + 1:]


# -- the controller journal ----------------------------------------------------------------------------
def test_a_clean_journal_verifies(tmp_path):
    p = tmp_path / "j.jsonl"
    _journal(p)
    r = verify(p)
    assert r.status == "ok" and r.entries == 1 + 9 and r.head == json.loads(p.read_bytes().splitlines()[-1])["hash"]


def test_every_edited_byte_of_a_journal_is_caught_at_its_entry(tmp_path):
    p = tmp_path / "j.jsonl"
    _journal(p, n=2)
    raw = p.read_bytes()
    for pos, edited in _each_byte_edited(raw):
        p.write_bytes(edited)
        r = verify(p)
        assert r.status == "broken" and r.broken_at == _line_of(raw, pos), (pos, r.line())
        assert f"entry {r.broken_at} (line {r.broken_at + 1}" in r.line()


def test_a_deleted_or_reordered_journal_entry_is_named(tmp_path):
    p = tmp_path / "j.jsonl"
    _journal(p)
    lines = p.read_bytes().splitlines(keepends=True)
    p.write_bytes(b"".join(lines[:3] + lines[4:]))  # entry 3 deleted
    r = verify(p)
    assert r.status == "broken" and r.broken_at == 3 and "deleted, inserted or reordered" in r.problem
    p.write_bytes(b"".join(lines[:2] + [lines[3], lines[2]] + lines[4:]))  # entries 2 and 3 swapped
    assert verify(p).broken_at == 2


def test_a_cut_journal_tail_is_caught_only_against_a_kept_head(tmp_path):
    """A clean cut of the last entries leaves a shorter, valid chain: only the head kept
    elsewhere (--head) tells; the verification prints that head."""
    p = tmp_path / "j.jsonl"
    _journal(p)
    head = verify(p).head
    lines = p.read_bytes().splitlines(keepends=True)
    p.write_bytes(b"".join(lines[:-1]))
    assert verify(p).status == "ok"
    r = verify(p, head=head[:16])
    assert r.status == "broken" and "cut off" in r.problem
    assert verify(tmp_path / "j.jsonl", head=verify(p).head).status == "ok"


def test_a_crash_mid_append_keeps_the_chain_and_the_controller_goes_on(tmp_path):
    p = tmp_path / "j.jsonl"
    _journal(p)
    whole = p.read_bytes()
    with open(p, "ab") as f:
        f.write(b'{"command_id":9,"hash":"ab')  # the controller died mid-line
    r = verify(p)
    assert r.status == "ok" and r.entries == 10 and "torn last line" in r.line()
    j = ControllerJournal(p, fsync=False)  # restarted: the torn line cut off, then appended to
    assert p.read_bytes() == whole
    j.record_accepted(9, "d9")
    assert verify(p).status == "ok" and verify(p).entries == 11


def test_an_unchained_journal_says_so_and_is_chained_when_opened(tmp_path):
    p = tmp_path / "j.jsonl"
    p.write_text(json.dumps({"format": "loggrasp.controller_journal", "version": "2.0"}) + "\n"
                 + json.dumps({"command_id": 5, "status": "rejected", "reason": "BUSY", "digest": None}) + "\n")
    r = verify(p)
    assert r.status == "unchained" and "predates hash chains" in r.line() and "broken" not in r.line()
    assert set(ControllerJournal(p, fsync=False).recover()[0]) == {5}
    assert verify(p).status == "ok"


def test_a_compacted_journal_continues_its_chain(tmp_path):
    p = tmp_path / "j.jsonl"
    _journal(p, n=4, keep=2)  # 10 lines > 2 * keep: compacted on the next load
    old_head = verify(p).head
    ControllerJournal(p, keep=2, fsync=False)
    r = verify(p)
    assert r.status == "ok" and r.entries == 3 and json.loads(p.read_bytes().splitlines()[0])["prev"] == old_head


def test_a_controller_does_not_start_on_a_tampered_journal(tmp_path):
    p = tmp_path / "j.jsonl"
    _journal(p)
    p.write_bytes(p.read_bytes().replace(b'"reason":"STALE"', b'"reason":"BUSY"'))
    with pytest.raises(ControllerError, match="hash chain broken at entry 9"):
        ControllerJournal(p, fsync=False)


# -- trial records ---------------------------------------------------------------------------------------
def _record(tmp_path: Path) -> Path:
    """A trial record written by the trial's own writer: staged, published, three steps."""
    final, tmp = tmp_path / "rec", tmp_path / ".rec.tmp"
    tmp.mkdir()
    rec = _TrialRecord(final, tmp, "twin://", TrialOptions())
    (tmp / "inputs").mkdir()
    (tmp / "inputs" / "gnss.csv").write_text("e,n,h\n1,2,3\n")
    rec.write(final_state="AWAITING CONFIRMATION")
    rec.publish()
    (final / "plan").mkdir()
    (final / "plan" / "plan.json").write_text('{"rank": 1}')
    rec.write(final_state="SENDING")
    (final / "link").mkdir()
    (final / "link" / "traffic.blf").write_bytes(bytes(range(40)))
    rec.write(final_state="SUCCESS", outcome={"class": "SUCCESS"})
    return final


def test_a_clean_trial_record_verifies(tmp_path):
    d = _record(tmp_path)
    r = verify(d)
    kinds = [json.loads(x)["kind"] for x in (d / "audit.jsonl").read_text().splitlines()[1:]]
    assert kinds == ["file", "record", "file", "record", "file", "record"]
    assert r.status == "ok" and "3 files sealed" in r.line() and "state SUCCESS" in r.line()
    assert json.loads((d / "record.json").read_text())["audit"]["entry"] == 6


@pytest.mark.parametrize("name", ["audit.jsonl", "record.json", "plan/plan.json", "link/traffic.blf"])
def test_every_edited_byte_of_a_trial_record_is_caught(tmp_path, name):
    d = _record(tmp_path)
    target = d / name
    raw = target.read_bytes()
    for pos, edited in _each_byte_edited(raw):
        target.write_bytes(edited)
        r = verify(d)
        assert r.status == "broken", (name, pos)
        if name == "audit.jsonl":
            assert r.broken_at == _line_of(raw, pos), (pos, r.line())
        elif name == "record.json":
            assert r.broken_at == 6 and "record.json differs" in r.problem
        else:
            assert name in r.entry and "differs from the sha256 sealed" in r.problem
    target.write_bytes(raw)
    assert verify(d).status == "ok"


def test_trial_record_entries_deleted_reordered_cut_or_files_added(tmp_path):
    d = _record(tmp_path)
    chain = d / "audit.jsonl"
    lines = chain.read_bytes().splitlines(keepends=True)
    chain.write_bytes(b"".join(lines[:2] + lines[3:]))
    assert verify(d).broken_at == 2
    chain.write_bytes(b"".join(lines[:3] + [lines[4], lines[3]] + lines[5:]))
    assert verify(d).broken_at == 3
    chain.write_bytes(b"".join(lines[:-1]))  # the tail cut: record.json names an entry past the end
    r = verify(d)
    assert r.status == "broken" and "entry 6" in r.entry and "tail was cut off" in r.problem
    chain.write_bytes(b"".join(lines))
    (d / "plan" / "extra.png").write_bytes(b"x")
    r = verify(d)
    assert r.status == "broken" and r.entry == "plan/extra.png" and "not in the chain" in r.problem
    (d / "plan" / "extra.png").unlink()
    (d / "plan" / "plan.json").unlink()
    assert "missing" in verify(d).problem


def test_a_trial_record_without_its_chain_file_is_broken_and_an_old_one_unchained(tmp_path):
    d = _record(tmp_path)
    (d / "audit.jsonl").unlink()
    assert verify(d).status == "broken"
    rec = json.loads((d / "record.json").read_text())
    del rec["audit"]
    rec["format_version"] = "1.1"
    (d / "record.json").write_text(json.dumps(rec))
    r = verify(d)
    assert r.status == "unchained" and "1.1 predates hash chains" in r.line()


def test_a_rollback_of_record_json_is_caught(tmp_path):
    """record.json replaced by an earlier step's bytes: the chain seals a later record.json."""
    final, tmp = tmp_path / "rec", tmp_path / ".rec.tmp"
    tmp.mkdir()
    rec = _TrialRecord(final, tmp, "twin://", TrialOptions())
    rec.write(final_state="SENDING")
    sending = (tmp / "record.json").read_bytes()
    rec.write(final_state="COLLISION")
    (tmp / "record.json").write_bytes(sending)
    r = verify(tmp)
    assert r.status == "broken" and "later record.json" in r.problem and "COLLISION" in r.entry


def test_a_crash_between_steps_leaves_a_verifiable_record(tmp_path):
    """Files chained for a step whose record.json was never written, and a torn line: a note."""
    d = _record(tmp_path)
    chain = ChainFile.resume(d / "audit.jsonl", fsync=False)
    chain.append({"kind": "file", "path": "link/traffic.blf", "sha256": "0" * 64, "bytes": 1})
    with open(d / "audit.jsonl", "ab") as f:
        f.write(b'{"kind":"rec')
    r = verify(d)
    assert r.status == "broken" and "traffic.blf" in r.entry  # the file is not what the unfinished step sealed
    assert check_lines((d / "audit.jsonl").read_bytes()).torn_tail


# -- the command ------------------------------------------------------------------------------------------
def test_audit_verify_command(tmp_path, capsys):
    d = _record(tmp_path)
    assert run(["audit", "verify", str(d)]) == 0
    assert "trial record OK" in capsys.readouterr().out
    assert run(["audit", "verify", str(d), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["format"] == "loggrasp.audit" and doc["format_version"] == "1.0" and doc["status"] == "ok"
    (d / "plan" / "plan.json").write_text('{"rank": 2}')
    assert run(["audit", "verify", str(d)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "entry 3 (file plan/plan.json" in err[0]
    assert run(["audit", "verify", str(d), "--json"]) == 2
    assert json.loads(capsys.readouterr().out)["status"] == "broken"
    assert run(["audit", "verify", str(d), "--head", "xyz"]) == 2
    assert "--head" in capsys.readouterr().err
    assert run(["audit", "verify", str(tmp_path / "nope")]) == 2
    assert "RECORD" in capsys.readouterr().err


def test_a_line_whose_bytes_are_not_canonical_is_caught(tmp_path):
    """A space added inside a line leaves its content (and hash) the same: the bytes must still be
    the one canonical serialisation."""
    p = tmp_path / "j.jsonl"
    _journal(p)
    p.write_bytes(p.read_bytes().replace(b'"status":"accepted"', b'"status": "accepted"', 1))
    r = verify(p)
    assert r.status == "broken" and r.broken_at == 1 and "canonical" in r.problem


def test_not_a_record_or_journal_is_a_one_line_error(tmp_path, capsys):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "record.json").write_text('{"format": "loggrasp.plan", "format_version": "1.0"}')
    (tmp_path / "f.json").write_text('{"format": "loggrasp.plan"}\n')
    for target, words in ((tmp_path / "d", "not a loggrasp trial record"), (tmp_path / "f.json", "not a controller "
                                                                                                  "journal")):
        assert run(["audit", "verify", str(target)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err
