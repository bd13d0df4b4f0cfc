"""docs/benchmarks.md as a page a user reads: the current figure of every measure on top, the runs
that made them in docs/benchmarks-history.md.

The current figures live in a small versioned file, ``docs/results/benchmarks.json`` (format
``loggrasp.benchmarks``): one :class:`Measure` per measure, with the date, machine, load and command
of the run that gave its figure. ``make bench`` (bench/run.py) runs its sections; the figures a
section measured replace their measures' entries (:func:`measures_of_section` reads them from the
section's own tables, :mod:`experiments.bench_measures`), the section's Markdown is appended, dated,
to the history file, and the page is rendered again from the file. So a partial run (``--only``)
or a measure that only a slow command gives (the 200-scan survey bench, the real test) keeps its
last figure with its own date and command: nothing has to be rerun to rewrite the page.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

from synth.common.files import atomic_write_bytes
from synth.common.formats import VersionedJson


class BenchPageError(ValueError):
    """A benchmark results file or page that cannot be read or made."""


#: what "met?" may say: the target is met, missed, not decided by the run's uncertainty, or there is none
MET_VALUES = ("yes", "no", "unresolved", "")


@dataclass(frozen=True)
class Measure:
    """The current figure of one measure and the run it comes from."""

    key: str  # stable id, "<area>.<name>", e.g. "simulator.render_128"
    area: str  # the page's group, e.g. "Simulator"
    measure: str  # what is measured (the unit is in the value)
    value: str  # the figure as the page shows it, unit included: "0.016 s"
    target: str = ""  # "< 0.1 s"; "" = no target set
    met: str = ""  # one of MET_VALUES
    date: str = ""  # UTC: "2026-11-22 06:28" (or a span)
    machine: str = ""  # "2-core AMD EPYC"
    load: str = ""  # 1-minute load average when the run started (or a span); "" = not recorded
    command: str = ""  # how to measure it again
    commit: str = ""  # the code measured
    details: str = ""  # the heading of the run in the history file

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            if not isinstance(getattr(self, field.name), str):
                raise ValueError(f"Measure.{field.name} must be text, got {getattr(self, field.name)!r}")
        if not self.key or not self.area or not self.measure or not self.value:
            raise ValueError(f"a measure needs a key, an area, a name and a value: {self!r}")
        if self.met not in MET_VALUES:
            raise ValueError(f"Measure {self.key}: met must be one of {MET_VALUES}, got {self.met!r}")


RESULTS = VersionedJson("loggrasp.benchmarks", "1.0", "benchmark results file", BenchPageError,
                        fix="upgrade loggrasp, or run `make bench` to write the file again",
                        unreadable_fix="restore docs/results/benchmarks.json from git",
                        filename="benchmarks.json")


def read_measures(path: str | Path) -> dict[str, Measure]:
    """The measures of a results file, by key, in the file's order."""
    doc = RESULTS.read(path)
    out: dict[str, Measure] = {}
    names = {f.name for f in dataclasses.fields(Measure)}
    for i, item in enumerate(doc.get("measures", [])):
        if not isinstance(item, dict) or set(item) - names:
            raise BenchPageError(f"{path}: measure {i} is not a measure (unknown fields "
                                 f"{sorted(set(item) - names) if isinstance(item, dict) else item!r})")
        try:
            m = Measure(**item)
        except (TypeError, ValueError) as exc:
            raise BenchPageError(f"{path}: measure {i}: {exc}") from exc
        out[m.key] = m
    return out


def write_measures(path: str | Path, measures: dict[str, Measure]) -> None:
    """Write the results file atomically (every field of every measure, in order)."""
    RESULTS.write(path, {"measures": [dataclasses.asdict(m) for m in measures.values()]}, ensure_ascii=False)


def updated(current: dict[str, Measure], new: Iterable[Measure]) -> dict[str, Measure]:
    """``current`` with ``new`` measures replacing theirs (same place) or appended."""
    out = dict(current)
    for m in new:
        out[m.key] = m
    return out


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def render_page(measures: dict[str, Measure], history: str = "benchmarks-history.md") -> str:
    """The whole page: a table of the current figures per area, then how to read and renew them."""
    lines = [
        "# loggrasp benchmarks",
        "",
        "The current figure of every measure, each with the run it comes from. Every run, with all the "
        f"tables it printed, is in [{history}]({history}) (mostly oldest first); the figures below are kept in "
        "`docs/results/benchmarks.json`, and this page is written from that file by `make bench` "
        "(`.venv/bin/python bench/run.py --out docs/benchmarks.md`): do not edit it by hand.",
        "",
        "Wall times were measured on shared 2-core machines: the load column is the 1-minute load average "
        "when the run started (2 = both cores busy), and wall times grow with it; CPU times do not. "
        "*met?* says `unresolved` where the run's 95 % interval straddles the target.",
    ]
    areas: dict[str, list[Measure]] = {}
    for m in measures.values():
        areas.setdefault(m.area, []).append(m)
    for area, rows in areas.items():
        lines += ["", f"## {area}", "", "| measure | value | target | met? | date (UTC) | machine | load | command |",
                  "|---|---|---|---|---|---|---|---|"]
        for m in rows:
            command = f"`{m.command}`" if m.command else ""
            lines.append("| " + " | ".join(_cell(x) for x in (m.measure, f"**{m.value}**", m.target or "—",
                                                                m.met or "—", m.date, m.machine, m.load or "—",
                                                                command)) + " |")
        sources = sorted({m.details for m in rows if m.details})
        if sources:
            lines += ["", f"Runs ({history}): " + "; ".join(f"“{s}”" for s in sources) + "."]
    lines += [
        "",
        "## Renewing a figure",
        "",
        "`make bench` reruns the quick sections (`--only NAME...` for some of them: piles, render, stereo, "
        "trials, planner, reconstruct, link, unposed), appends their output to the history and replaces "
        "the figures they measured. The rows whose command is another bench (the survey conditions, the "
        "real test, verified planning, training) are renewed by running that command and putting its "
        "figure, date, machine, load and command into `docs/results/benchmarks.json`; then "
        "`.venv/bin/python bench/run.py --page-only` writes this page again.",
        "",
    ]
    return "\n".join(lines)


def history_entry(title: str, run_lines: list[str], parts: list[str]) -> str:
    """One run's block for the history file: a rule, a heading, the run's facts, its sections."""
    return "\n\n---\n\n" + f"# {title}\n\n" + "  \n".join(run_lines) + "\n\n" + "\n\n".join(parts) + "\n"


def append_history(path: Path, entry: str) -> None:
    """Append ``entry`` to the history file (written whole, atomically)."""
    old = path.read_text() if path.exists() else "# loggrasp benchmark runs\n"
    atomic_write_bytes(path, (old.rstrip("\n") + "\n" + entry).encode())


def write_page(path: Path, measures: dict[str, Measure]) -> None:
    history = path.with_name(path.stem + "-history.md").name
    atomic_write_bytes(path, render_page(measures, history).encode())
