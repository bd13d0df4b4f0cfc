"""docs/benchmarks.md as a page: the current figures on top from docs/results/benchmarks.json, a run
replacing only the figures it measured, every run kept in the history file (tiny inputs, no bench run)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.bench_measures import SECTION_READERS, Run, measures_of_section
from experiments.bench_page import (BenchPageError, Measure, append_history, history_entry, read_measures,
                                    render_page, updated, write_measures, write_page)

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results" / "benchmarks.json"
HISTORY = ROOT / "docs" / "benchmarks-history.md"

RUN = Run(date="2026-12-06 06:00", machine="2-core Intel Xeon", load="1.2", command="make bench", commit="abc1234",
          details="loggrasp benchmarks, 2026-12-06 06:00 UTC")
RENDER_MD = """### Orthographic render (TinyRenderer, 7 logs + 3 obstacles)
Target: under 0.1 s at 128 px.

| size px | one render wall s (median) | CPU s | 3 renders + depth + instance wall s (median) | CPU s |
|---|---|---|---|---|
| 128 | {t128} | 0.0158 | 0.0585 | 0.0468 |
| 256 | 0.0903 | 0.0505 | 0.3061 | 0.1510 |"""
KEPT = Measure(key="survey.failures_default", area="Survey", measure="scans refused, default survey",
               value="0.5 % (1 of 200)", target="≤ 1 %", met="yes", date="2026-12-05 14:40", machine="2-core Intel Xeon",
               load="~6", command="bench_reconstruct.py --survey-scans 200", details="Revision 22")
OLD_RENDER = Measure(key="simulator.render_128", area="Simulator", measure="render", value="0.0161 s",
                     target="< 0.1 s", met="yes", date="2026-11-22 06:28", machine="2-core AMD EPYC", load="4.6",
                     command="make bench", details="the first run")


def test_the_page_is_what_the_generator_makes_of_the_results_file():
    """docs/benchmarks.md is written from the results file, not by hand: regenerate with
    `.venv/bin/python bench/run.py --page-only`."""
    assert (ROOT / "docs" / "benchmarks.md").read_text() == render_page(read_measures(RESULTS))


def test_a_run_replaces_its_figures_keeps_the_others_and_extends_the_history(tmp_path):
    results, page = tmp_path / "benchmarks.json", tmp_path / "benchmarks.md"
    write_measures(results, {m.key: m for m in (OLD_RENDER, KEPT)})
    md = RENDER_MD.format(t128="0.0500")
    new = measures_of_section("render", md, RUN)
    assert [(m.key, m.value, m.met, m.date, m.load) for m in new] == [
        ("simulator.render_128", "0.0500 s", "yes", "2026-12-06 06:00", "1.2")]
    measures = updated(read_measures(results), new)
    write_measures(results, measures)
    write_page(page, read_measures(results))
    text = page.read_text()
    top = text.index("| measure | value | target | met? | date (UTC) | machine | load | command |")
    assert top < text.index("**0.0500 s**") and "0.0161" not in text  # the new figure replaced the old one
    assert "| scans refused, default survey | **0.5 % (1 of 200)** | ≤ 1 % | yes | 2026-12-05 14:40 |" in text
    assert "(benchmarks-history.md)" in text
    history = tmp_path / "benchmarks-history.md"
    history.write_text("# runs\n\nthe old run: 0.0161\n")
    append_history(history, history_entry(RUN.details, ["Machine: x", "Date: y"], [md]))
    old_and_new = history.read_text()
    assert old_and_new.index("0.0161") < old_and_new.index("| 128 | 0.0500 |")  # appended, nothing lost


def test_a_missed_target_says_no():
    (m,) = measures_of_section("render", RENDER_MD.format(t128="0.2000"), RUN)
    assert m.met == "no" and m.value == "0.2000 s"


def test_a_section_whose_table_changed_shape_is_a_clear_error():
    with pytest.raises(BenchPageError, match="section 'render'.*bench_measures.py"):
        measures_of_section("render", RENDER_MD.format(t128="0.05").replace("size px", "pixels"), RUN)


def test_the_results_file_is_versioned_and_checked(tmp_path):
    path = tmp_path / "benchmarks.json"
    write_measures(path, {KEPT.key: KEPT})
    doc = json.loads(path.read_text())
    assert doc["format"] == "loggrasp.benchmarks" and doc["format_version"] == "1.0"
    assert read_measures(path) == {KEPT.key: KEPT}
    path.write_text(json.dumps({**doc, "format_version": "2.0"}))
    with pytest.raises(BenchPageError, match="version '2.0' is not supported"):
        read_measures(path)
    path.write_text(json.dumps({**doc, "measures": [{**doc["measures"][0], "met": "maybe"}]}))
    with pytest.raises(BenchPageError, match="measure 0: .*met must be one of"):
        read_measures(path)


def _block(text: str, heading: str, last: bool) -> str:
    """One section's output in the history: from its heading to its end."""
    start = text.rindex(heading) if last else text.index(heading)
    ends = [text.find(e, start + len(heading)) for e in ("_section time", "\n---\n", "\n# ", "</details>")]
    return text[start:min(e for e in ends if e > 0)]


#: section -> (its heading in the history, take the last run that printed it)
HEADINGS = {
    "piles": ("### Settled piles", True), "render": ("### Orthographic render", True),
    "stereo": ("### Stereo pair render", False), "trials": ("### Grasp trials (fast vs careful", True),
    "planner": ("### Planner (U-Net)", True), "reconstruct": ("### Reconstruction (stereo scan", False),
    "unposed": ("### Unposed scans (pycolmap", False), "link": ("### Crane link", True),
    "twin robustness": ("### Twin robustness", True),
}


def test_every_section_reader_reads_what_its_section_printed_and_the_page_carries_it():
    """The readers on the sections' real output (the history's runs); where the current figure
    came from `bench/run.py`, the results file holds what the reader reads there."""
    assert set(HEADINGS) == set(SECTION_READERS)
    history, current = HISTORY.read_text(), read_measures(RESULTS)
    checked = 0
    for section, (heading, last) in HEADINGS.items():
        for m in measures_of_section(section, _block(history, heading, last), RUN):
            assert m.key in current, m.key
            if "bench/run.py" in current[m.key].command:
                assert m.value == current[m.key].value.split(" (")[0], m.key
                checked += 1
    assert checked >= 10
