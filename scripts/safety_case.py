"""Write docs/safety-case.md from a test run: the IEC 61784-3 transmission errors × the two crane
links (CAN, Zenoh), the abort paths, the key handling and what the link does not guarantee.

Usage: .venv/bin/python scripts/safety_case.py [--out docs/safety-case.md] [-- PYTEST_ARGS...]
(``make safety-case``). It runs the tests in tests/field that carry the ``safety_case`` marker
and writes the page from their markers and outcomes (the result of this run, per test). A test
is evidence through its marker::

    @pytest.mark.safety_case(error="corruption", link="can", measure="E2E CRC", reaction="rejected CRC")
    @pytest.mark.safety_case(abort="laptop heartbeat lost", link="can", reaction="grasp ABORTED")
    @pytest.mark.safety_case(keys="key file mode 0600", reaction="refused otherwise")
    @pytest.mark.safety_case(gap="CAN without keys: integrity, not origin", reaction="forged outcome believed")

``link`` is ``can``, ``zenoh`` or ``both`` (a codec-level test, the same frames on both links).
Work that is not in this tree yet is listed in :data:`PENDING` and shown as *pending*; a matrix
cell with neither a test nor a pending entry makes the script exit 1. Exit code: pytest's,
else 1 for a missing cell.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ERRORS = {  # IEC 61784-3's transmission errors, as the standard's "black channel" names them
    "corruption": "a frame's bits changed on the way",
    "unintended repetition": "an old frame sent again (a copy, a replay)",
    "incorrect sequence": "frames arrive in another order than sent",
    "loss": "a frame (or a whole stream: heartbeats, a peer) never arrives",
    "unacceptable delay": "a frame arrives too late to be acted on",
    "insertion": "a frame no legitimate sender sent",
    "masquerade": "a frame that poses as coming from a legitimate sender",
    "addressing": "a frame delivered to, or read as meant for, the wrong receiver or kind",
}
LINKS = {"can": "CAN", "zenoh": "Zenoh"}
SECTIONS = ("abort", "keys", "gap")
#: evidence that waits on work not in this tree: (key, value, link, what it will prove, waits on)
PENDING: list[tuple[str, str, str, str, str]] = []


@dataclass
class Evidence:
    """One marker of one test (a test may carry several)."""

    nodeid: str
    kind: str  # "error" | "abort" | "keys" | "gap"
    topic: str  # the error name, abort path, key rule or gap
    link: str  # "can" | "zenoh" | "both"
    measure: str
    reaction: str
    outcome: str = "not run"

    @classmethod
    def from_mark(cls, nodeid: str, kw: dict) -> "Evidence":
        kinds = [k for k in ("error", *SECTIONS) if k in kw]
        if len(kinds) != 1:
            raise ValueError(f"{nodeid}: safety_case marker needs exactly one of error=, abort=, keys=, gap=; got {kw}")
        kind = kinds[0]
        if kind == "error" and kw["error"] not in ERRORS:
            raise ValueError(f"{nodeid}: safety_case error={kw['error']!r} is not one of {sorted(ERRORS)}")
        link = kw.get("link", "both")
        if link not in (*LINKS, "both"):
            raise ValueError(f"{nodeid}: safety_case link={link!r}: use can, zenoh or both")
        if not kw.get("reaction") or (kind == "error" and not kw.get("measure")):
            raise ValueError(f"{nodeid}: safety_case marker needs reaction= (and measure= for an error)")
        return cls(nodeid, kind, kw[kind], link, kw.get("measure", ""), kw["reaction"])

    def on(self, link: str) -> bool:
        return self.link in (link, "both")


@dataclass
class SafetyCase:
    """The pytest plugin: collects the markers of the selected tests and each test's outcome."""

    evidence: list[Evidence] = field(default_factory=list)
    outcomes: dict[str, str] = field(default_factory=dict)

    def pytest_collection_finish(self, session) -> None:
        for item in session.items:
            for mark in item.iter_markers("safety_case"):
                self.evidence.append(Evidence.from_mark(item.nodeid, mark.kwargs))

    def pytest_runtest_logreport(self, report) -> None:
        now = "failed" if report.failed else "skipped" if report.skipped else "passed"
        if report.when == "call" or now != "passed":
            worst = ("failed", "skipped", "passed")  # a test's outcome: its worst phase
            before = self.outcomes.get(report.nodeid)
            if before is None or worst.index(now) < worst.index(before):
                self.outcomes[report.nodeid] = now

    def finished(self) -> list[Evidence]:
        for e in self.evidence:
            e.outcome = self.outcomes.get(e.nodeid, "not run")
        return self.evidence


# --- the page -----------------------------------------------------------------------------------


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _mark(outcome: str) -> str:
    return {"passed": "passed", "failed": "**FAILED**", "skipped": "skipped", "not run": "not run"}[outcome]


def _pending(kind: str, topic: str, link: str | None = None) -> list[tuple]:
    return [p for p in PENDING if p[0] == kind and p[1] == topic and (link is None or p[2] in (link, "both"))]


def _summary(ev: list[Evidence], error: str, link: str) -> tuple[str, bool]:
    """A matrix cell: (text, missing)."""
    here = [e for e in ev if e.kind == "error" and e.topic == error and e.on(link)]
    pending = _pending("error", error, link)
    failed = sum(e.outcome == "failed" for e in here)
    passed = sum(e.outcome == "passed" for e in here)
    if not here:
        return ("pending" if pending else "**MISSING**"), not pending
    text = f"**{failed} FAILED** of {len(here)}" if failed else f"{passed}/{len(here)} tests pass"
    return text + (f" + {len(pending)} pending" if pending else ""), False


def _matrix(ev: list[Evidence]) -> tuple[list[str], list[str]]:
    lines = ["| transmission error | " + " | ".join(LINKS.values()) + " |", "|---|" + "---|" * len(LINKS)]
    missing = []
    for error, meaning in ERRORS.items():
        cells = []
        for link in LINKS:
            text, gap = _summary(ev, error, link)
            cells.append(text)
            if gap:
                missing.append(f"{error} on {LINKS[link]}")
        lines.append(f"| [{error}](#{error.replace(' ', '-')}) — {meaning} | " + " | ".join(cells) + " |")
    return lines, missing


def _link_name(link: str) -> str:
    return "CAN + Zenoh (transport-independent)" if link == "both" else LINKS[link]


def _cells(ev: list[Evidence]) -> list[str]:
    out = []
    for error, meaning in ERRORS.items():
        out += [f"### {error}", "", f"{meaning[0].upper() + meaning[1:]}.", "",
                "| link | measure that detects it | safe reaction | test | last run |", "|---|---|---|---|---|"]
        for link in (*LINKS, "both"):
            for e in (e for e in ev if e.kind == "error" and e.topic == error and e.link == link):
                out.append(f"| {_link_name(link)} | {_cell(e.measure)} | {_cell(e.reaction)} | `{e.nodeid}` | "
                           f"{_mark(e.outcome)} |")
            for p in (p for p in PENDING if p[:2] == ("error", error) and p[2] == link):
                out.append(f"| {_link_name(link)} | — | {_cell(p[3])} | waits on {_cell(p[4])} | pending |")
        out.append("")
    return out


def _section(ev: list[Evidence], kind: str, head: str) -> list[str]:
    out = [f"| {head} | link | safe reaction / what the test shows | test | last run |", "|---|---|---|---|---|"]
    for e in (e for e in ev if e.kind == kind):
        out.append(f"| {_cell(e.topic)} | {_link_name(e.link)} | {_cell(e.reaction)} | `{e.nodeid}` | "
                   f"{_mark(e.outcome)} |")
    for p in (p for p in PENDING if p[0] == kind):
        out.append(f"| {_cell(p[1])} | {_link_name(p[2])} | {_cell(p[3])} | waits on {_cell(p[4])} | pending |")
    return out


KEY_TEXT = """Authenticated frames are SecOC style: an 8-byte time-based freshness value and an HMAC-SHA256
truncated to 8 bytes over the frame id, the frame and the freshness value (`field/link/secoc.py`).
One pre-shared key per crane (`loggrasp link-key KEYFILE`: 32 random bytes, hex, mode 0600, never
overwritten, never printed), given to both ends with `?secoc_key=KEYFILE`; a link without a key is
refused unless the operator opts out explicitly (`--insecure-link` / `insecure=1`, said in the
confirmation and kept in the record). A key file readable by group or others is refused. Each
direction (laptop → crane, crane → laptop) MACs with its own key derived from the file's, and a
key file may hold several `KEY_ID HEX` lines: the key id travels in the freshness value, so keys
rotate without downtime. More than `max_mac_failures` frames failing their MAC or key id within
`mac_failure_window_s` put the controller in FAULT (commands refused, a running grasp aborted). Receivers drop a bad MAC, a replay (a freshness value seen before)
and a frame more than 2 s off their clock; an e-stop frame stops the crane even when its MAC fails
(fail-safe). A MAC cannot tell the crane from a laptop (the laptop, which verifies crane frames, could
compute them), so every crane → laptop frame is also signed with Ed25519 by a key only the crane holds
(`field/link/signing.py`; `loggrasp link-key --crane-signing CRANE` writes CRANE, mode 0600, for the
crane's `signing_key=`, and CRANE.pub for the laptops' `crane_key=`): a laptop's key file cannot make
crane frames. On Zenoh the signature follows the frame in its payload; on CAN FD it follows in a
signature frame of its own identifier, and the laptop acts on a crane frame only once its signature
frame verifies (a frame left unsigned for `signature_wait_s` is dropped: a lost frame). A failed
signature is an authentication failure, dropped and counted like a failed MAC. On Zenoh, sessions also authenticate (user/password or mutual TLS) and an
access-control policy gives the crane, operators and observers their roles
(`field/link/zenoh_acl.json5`)."""

GAPS = [
    "**CAN without keys has integrity, not origin**: E2E CRCs and counters catch corruption, loss, "
    "repetition and reordering, but any node on the bus can forge a valid frame. Authentication is on "
    "by default; an operator who opts out (`--insecure-link`) runs without origin.",
    "**Laptop → crane frames are MAC'd with a shared key**: the crane's answers are signed, but a command "
    "is only MAC'd, so whoever holds any copy of the SecOC key file (another laptop, or the crane's own "
    "disk) can make laptop frames, commands included. The crane's signing key is the crane's identity: "
    "whoever steals it can make crane answers.",
    "**On CAN a crane answer is two frames** (the data frame, then its 64-byte signature frame): twice the "
    "crane's frames on the bus, and an answer whose signature frame is lost or more than "
    "`signature_wait_s` (0.25 s) late is dropped - a lost frame, which the link survives but which costs "
    "a status query.",
    "**Frames carry no crane identity**: addressing between cranes rests on separate buses, one Zenoh key "
    "expression per crane and one key per crane. Two cranes sharing a key and a bus or router would accept "
    "each other's commands.",
    "**CAN has no source addresses**: two laptops on one bus are detected and reported, but the controller "
    "cannot tell whose command it got. One laptop per crane.",
    "**Freshness needs synchronised clocks** (laptop and crane within the 2 s SecOC window and the 2 s "
    "plan-timestamp skew): GNSS time on a real crane.",
    "**A revocation that gets no answer** leaves the state UNKNOWN: the operator is told to watch the "
    "crane, not that the command did not run.",
    "**An e-stop over the link is not a safety function** in the machinery-directive sense: the physical "
    "e-stop circuit on the crane remains the primary one.",
    "**Zenoh roles are only as good as the credentials**: a stolen operator password is an operator.",
    "**The records are tamper-evident, not tamper-proof**: `loggrasp audit verify` catches an edited, "
    "deleted or reordered entry, but a rewritten whole chain (or a record rolled back to an earlier step) "
    "is caught only against a head hash kept elsewhere (`--head`).",
]


def _commit() -> str:
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
        return sha + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def render(ev: list[Evidence], when: str, commit: str) -> tuple[str, list[str]]:
    """(the page, the matrix cells with neither a test nor a pending entry)."""
    matrix, missing = _matrix(ev)
    counts = {k: sum(e.outcome == k for e in {e.nodeid: e for e in ev}.values())
              for k in ("passed", "failed", "skipped", "not run")}
    lines = [
        "# Safety case: the crane link's transmission errors",
        "",
        f"Generated by `make safety-case` (`scripts/safety_case.py`) from a test run on {when} at commit "
        f"{commit}: {len({e.nodeid for e in ev})} tests, {counts['passed']} passed, {counts['failed']} failed, "
        f"{counts['skipped']} skipped, {counts['not run']} not run; {len(PENDING)} items pending. Do not edit: "
        "the markers on the tests (`@pytest.mark.safety_case`) and this script are the source.",
        "",
        "IEC 61784-3 (\"black channel\") names eight transmission errors a safety protocol must detect "
        "whatever the channel under it does. For each error and each link: the measure that detects it, "
        "the test that proves it (pytest node id), the safe reaction, and the test's result in the run "
        "that wrote this page. *pending*: evidence that waits on work not merged yet.",
        "",
        "## The matrix",
        "",
        *matrix,
        "",
        "## Each cell",
        "",
        *_cells(ev),
        "## Abort paths",
        "",
        "How a running grasp ends early, and what proves each path.",
        "",
        *_section(ev, "abort", "abort path"),
        "",
        "## Key handling",
        "",
        KEY_TEXT,
        "",
        *_section(ev, "keys", "rule"),
        "",
        "## What the link does NOT guarantee",
        "",
        *[f"- {g}" for g in GAPS],
        "",
        "A test below passes while the gap is still there (it shows the gap, so closing it fails the test).",
        "",
        *_section(ev, "gap", "gap shown by a test"),
        "",
        "## Regenerate",
        "",
        "`make safety-case` (or `PYTHONPATH=. .venv/bin/python scripts/safety_case.py`: the tests folder has no packages of its own, so the repository root goes first on the path), about four minutes on 2 cores (the soak at 8,000 commands on CAN and 2,000 on Zenoh included; the default suite runs 4,000 on CAN).",
        "",
    ]
    return "\n".join(lines), missing


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "safety-case.md", help="the page to write")
    ap.add_argument("pytest_args", nargs="*", help="more pytest arguments (after --)")
    args = ap.parse_args(argv)
    plugin = SafetyCase()
    # the soak at the sizes this page states (the default suite runs 4,000 on CAN)
    os.environ.setdefault("LOGGRASP_SOAK_CAN_N", "8000")
    os.environ.setdefault("LOGGRASP_SOAK_ZENOH_N", "2000")
    code = pytest.main(["-q", "-p", "no:cacheprovider", "-m", "safety_case", str(ROOT / "tests" / "field"),
                        *args.pytest_args], plugins=[plugin])
    from synth.common.files import atomic_write_text

    page, missing = render(plugin.finished(), time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), _commit())
    atomic_write_text(args.out, page)
    print(f"wrote {args.out}", file=sys.stderr)
    if missing:
        print(f"error: no test and nothing pending for {', '.join(missing)}", file=sys.stderr)
        return int(code) or 1
    return int(code)


if __name__ == "__main__":
    sys.exit(main())
