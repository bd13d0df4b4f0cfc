"""The measures each ``make bench`` section gives, read from the section's own Markdown tables.

A section (bench/run.py, bench/bench_*.py) prints tables for people; :func:`measures_of_section`
picks the headline figures out of them by column name and row, checks each against its target and
returns :class:`~experiments.bench_page.Measure` rows for docs/benchmarks.md. A figure that is not
in the section's output (a table changed shape) is a :class:`BenchPageError` naming the measure.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable

from experiments.bench_page import BenchPageError, Measure


@dataclass(frozen=True)
class Spec:
    """What a measure is: where it goes on the page and its target."""

    area: str
    measure: str
    target: str = ""


SPECS: dict[str, Spec] = {
    "simulator.settle_4": Spec("Simulator", "4-log pile settled (generate + drop + settle + validate), wall median",
                               "< 2 s"),
    "simulator.settle_4_obstacles": Spec("Simulator", "4-log pile with 3 obstacles settled, wall median", "< 2 s"),
    "simulator.render_128": Spec("Simulator", "orthographic render at 128 px (7 logs, 3 obstacles), wall median",
                                 "< 0.1 s"),
    "simulator.stereo_pair_egl": Spec("Simulator", "stereo pair 1280x720 (EGL renderer, warm), wall median"),
    "simulator.stereo_depth_err": Spec("Simulator", "SGBM depth error on log pixels (1280x720, 50°, 3 m), median"),
    "trials.fast_rate": Spec("Grasp trials", "trials per second per core, fast preset (4-log piles)", "≥ 2"),
    "trials.agreement": Spec("Grasp trials", "same outcome class as the careful preset, fast preset", "≥ 95 %"),
    "trials.dataset_projection": Spec("Grasp trials", "paper-scale data set (604 piles, ~70,700 trials), "
                                                      "projected wall on 2 cores"),
    "trials.robust_1cm": Spec("Grasp trials", "grasps that succeeded, moved by 1 cm / 1° (the crane off): success",
                              "≥ 95 %"),
    "trials.robust_3cm": Spec("Grasp trials", "grasps that succeeded, moved by 3 cm / 3°: success", "≥ 85 %"),
    "planner.plan_7": Spec("Planner", "plan a 7-log pile (127 subsets), shipped width, wall median", "≤ 0.5 s"),
    "planner.plan_12": Spec("Planner", "plan a 12-log pile with pre-selection (127 of 4095 subsets), wall median",
                            "≤ 1 s"),
    "planner.train_small": Spec("Planner", "training throughput, shipped width (1.94 M), bf16, 2 threads"),
    "planner.views8_7": Spec("Planner", "plan a 7-log pile with 8 averaged views, wall median"),
    "reconstruction.single_pair": Spec("Reconstruction", "single-pair scan (3 logs) reconstructed, wall median",
                                       "< 10 s"),
    "reconstruction.end_point": Spec("Reconstruction", "end point error, 3 twin piles (15 logs), median"),
    "reconstruction.diameter": Spec("Reconstruction", "mean-diameter error, 3 twin piles (15 logs), median",
                                    "≤ 1 cm"),
    "reconstruction.iou": Spec("Reconstruction", "log mask IoU (128 px), 3 twin piles, median", "≥ 0.9"),
    "reconstruction.unposed_end_point": Spec("Reconstruction", "unposed scans (SfM + GNSS): end point error, median"),
    "reconstruction.unposed_wall": Spec("Reconstruction", "unposed scan (4 pairs) reconstructed, wall median"),
    "link.can_virtual": Spec("Crane link", "command → ack, can-virtual, E2E frames, rejected command: p50 / p99"),
    "link.can_virtual_secoc": Spec("Crane link", "command → ack, can-virtual, authenticated frames, crane answers "
                                                 "signed (Ed25519), rejected command: p50 / p99", "p99 ≤ 5 ms"),
    "link.zenoh": Spec("Crane link", "command → ack, Zenoh on 127.0.0.1, E2E frames, rejected command: p50 / p99"),
    "link.zenoh_secoc_accept": Spec("Crane link", "command → ack, Zenoh, authenticated frames, crane answers signed, "
                                                  "executed command: p50 / p99"),
    "link.frame_auth_cost": Spec("Crane link", "per-frame cost (an Ack), median: HMAC-SHA256/64 verify / "
                                               "AES-128-CMAC / Ed25519 sign / Ed25519 verify"),
    "demo.wall": Spec("End to end", "`loggrasp demo`, process start to exit", "< 30 s"),
}


def tables(md: str) -> list[list[dict[str, str]]]:
    """Every Markdown table in ``md``: a list of rows, each a dict column name -> cell text."""
    out, lines, i = [], md.splitlines(), 0
    while i + 1 < len(lines):
        if lines[i].startswith("|") and re.match(r"^\|(\s*:?-+:?\s*\|)+\s*$", lines[i + 1]):
            head = [c.strip() for c in lines[i].strip().strip("|").split("|")]
            rows, i = [], i + 2
            while i < len(lines) and lines[i].startswith("|"):
                cells = [c.strip() for c in lines[i].strip().strip("|").split("|")]
                rows.append(dict(zip(head, cells)))
                i += 1
            out.append(rows)
        else:
            i += 1
    return out


def cell(md: str, column: str, **where: str) -> str:
    """The ``column`` cell of the first row (of any table) whose cells equal ``where``'s values
    (keys with ``_`` for spaces); :class:`BenchPageError` when there is none."""
    want = {k.replace("_", " "): v for k, v in where.items()}
    for table in tables(md):
        for row in table:
            if column in row and all(row.get(k) == v for k, v in want.items()):
                return row[column]
    raise BenchPageError(f"no table row with {want} and a column {column!r}")


def number(text: str) -> float:
    m = re.search(r"-?[0-9]+(?:\.[0-9]+)?", text)
    if m is None:
        raise BenchPageError(f"no number in {text!r}")
    return float(m.group(0))


def _yes(ok: bool) -> str:
    return "yes" if ok else "no"


def _piles(md: str) -> dict[str, tuple[str, str]]:
    out = {}
    for key, obstacles in (("simulator.settle_4", "0"), ("simulator.settle_4_obstacles", "3")):
        v = number(cell(md, "wall s (median)", logs="4", obstacles=obstacles))
        out[key] = (f"{v:.2f} s", _yes(v < 2.0))
    return out


def _render(md: str) -> dict[str, tuple[str, str]]:
    v = number(cell(md, "one render wall s (median)", size_px="128"))
    return {"simulator.render_128": (f"{v:.4f} s", _yes(v < 0.1))}


def _stereo(md: str) -> dict[str, tuple[str, str]]:
    pair = number(cell(md, "pair, warm renderer (median)", renderer="egl"))
    err = cell(md, "median", renderer="egl", image="1280x720", HFOV="50°")
    return {"simulator.stereo_pair_egl": (f"{pair:.3f} s", ""), "simulator.stereo_depth_err": (err, "")}


def _trials(md: str) -> dict[str, tuple[str, str]]:
    rate = number(cell(md, "trials/s per core", preset="fast"))
    agree = re.search(r"outcome agreement fast vs careful: \*\*([0-9]+/[0-9]+) = ([0-9.]+) %\*\*", md)
    proj = re.search(r"\*\*([0-9.]+ h) on 2 cores\*\*", md)
    if agree is None or proj is None:
        raise BenchPageError("no 'outcome agreement fast vs careful' line or no projected wall time")
    pct = float(agree.group(2))
    return {"trials.fast_rate": (f"{rate:.2f} trials/s", _yes(rate >= 2.0)),
            "trials.agreement": (f"{pct:.1f} % ({agree.group(1)})", _yes(pct >= 95.0)),
            "trials.dataset_projection": (proj.group(1), "")}


def _planner(md: str) -> dict[str, tuple[str, str]]:
    p7 = number(cell(md, "wall s", model="small", mask_injection="input", logs="7"))
    p12 = number(cell(md, "wall s", model="small", mask_injection="input", logs="12"))
    train = number(cell(md, "samples/s", model="small", mode="bf16+CL"))
    views = number(cell(md, "wall s", views="8", logs="7"))
    return {"planner.plan_7": (f"{p7:.2f} s", _yes(p7 <= 0.5)), "planner.plan_12": (f"{p12:.2f} s", _yes(p12 <= 1.0)),
            "planner.train_small": (f"{train:.1f} samples/s", ""), "planner.views8_7": (f"{views:.2f} s", "")}


def _reconstruct(md: str) -> dict[str, tuple[str, str]]:
    single = re.search(r"Single pair \(3 logs of 1\.2 m\), [0-9]+ runs: wall median ([0-9.]+) s", md)
    if single is None:
        raise BenchPageError("no 'Single pair (3 logs of 1.2 m), N runs: wall median' line")
    end = number(cell(md, "median", measure="end point error [m]"))
    dia = number(cell(md, "median", measure="abs mean-diameter error [m]"))
    iou = number(cell(md, "median", measure="log mask IoU (128 px)"))
    wall = float(single.group(1))
    return {"reconstruction.single_pair": (f"{wall:.1f} s", _yes(wall < 10.0)),
            "reconstruction.end_point": (f"{end * 100:.1f} cm", ""),
            "reconstruction.diameter": (f"{dia * 1000:.1f} mm", _yes(dia <= 0.01)),
            "reconstruction.iou": (f"{iou:.3f}", _yes(iou >= 0.9))}


def _unposed(md: str) -> dict[str, tuple[str, str]]:
    end = number(cell(md, "unposed median", measure="end point error [m]"))
    wall = number(cell(md, "unposed median", measure="reconstruct() wall [s]"))
    n = cell(md, "n (posed/unposed)", measure="end point error [m]")
    return {"reconstruction.unposed_end_point": (f"{end * 100:.1f} cm (logs posed/unposed {n})", ""),
            "reconstruction.unposed_wall": (f"{wall:.1f} s", "")}


def _link(md: str) -> dict[str, tuple[str, str]]:
    def p(backend: str, frames: str, mode: str) -> str:
        kw = {"backend": backend, "frames": frames, "mode": mode}
        return f"{number(cell(md, 'p50 ms', **kw)):.2f} / {number(cell(md, 'p99 ms', **kw)):.2f} ms"

    demo = cell(md, "wall s", command="`loggrasp demo`")
    result = cell(md, "result", command="`loggrasp demo`")
    wall = number(demo)
    signed = "authenticated (SecOC) + signed answers (Ed25519)"
    keyed = {"backend": "can-virtual", "frames": signed, "mode": "reject"}
    cost = [number(cell(md, "median µs", operation_on_one_Ack_frame=what)) for what in (
        "HMAC-SHA256/64: verify (MAC only)", "AES-128-CMAC/64 over the same bytes", "Ed25519: sign (crane)",
        "Ed25519: verify (laptop)")]
    return {"link.can_virtual": (p("can-virtual", "E2E only", "reject"), ""),
            "link.can_virtual_secoc": (p(**keyed), _yes(number(cell(md, "p99 ms", **keyed)) <= 5.0)),
            "link.zenoh": (p("zenoh", "E2E only", "reject"), ""),
            "link.zenoh_secoc_accept": (p("zenoh", signed, "accept"), ""),
            "link.frame_auth_cost": (" / ".join(f"{c:.1f}" for c in cost) + " µs", ""),
            "demo.wall": (f"{wall:.1f} s" + ("" if result == "ok" else f" ({result})"),
                          _yes(wall < 30.0 and result == "ok"))}


def _twin_robustness(md: str) -> dict[str, tuple[str, str]]:
    out = {}
    for key, level, target in (("trials.robust_1cm", "1 cm / 1°", 95.0), ("trials.robust_3cm", "3 cm / 3°", 85.0)):
        text = cell(md, "success", moved_by=level)
        out[key] = (text, _yes(number(text) >= target))
    return out


#: section name (bench/run.py) -> reader of its figures
SECTION_READERS: dict[str, Callable[[str], dict[str, tuple[str, str]]]] = {
    "piles": _piles, "render": _render, "stereo": _stereo, "trials": _trials, "planner": _planner,
    "reconstruct": _reconstruct, "unposed": _unposed, "link": _link, "twin robustness": _twin_robustness,
}


@dataclass(frozen=True)
class Run:
    """The facts of one ``make bench`` run that every measure it gives carries."""

    date: str  # UTC
    machine: str
    load: str  # 1-minute load average at the start
    command: str
    commit: str
    details: str  # the run's heading in the history file


def measures_of_section(section: str, md: str, run: Run) -> list[Measure]:
    """The measures section ``section`` gave in its Markdown ``md``, carrying ``run``'s facts."""
    reader = SECTION_READERS.get(section)
    if reader is None:
        return []
    try:
        figures = reader(md)
    except BenchPageError as exc:
        raise BenchPageError(f"section {section!r}: a measure is not in its output ({exc}); its table changed "
                             f"shape: update experiments/bench_measures.py") from exc
    return [Measure(key=key, area=SPECS[key].area, measure=SPECS[key].measure, value=value,
                    target=SPECS[key].target, met=met if SPECS[key].target else "", date=run.date,
                    machine=run.machine, load=run.load, command=run.command, commit=run.commit, details=run.details)
            for key, (value, met) in figures.items()]
