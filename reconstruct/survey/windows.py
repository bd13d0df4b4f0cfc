"""Raw receiver logs + the operator's time windows -> a checked survey.

The time-window sidecar (``loggrasp.gnss-windows`` 1.0) is a CSV with header
``log_id,end,t_start_utc,t_end_utc`` (ISO 8601 times, UTC; ``#`` comments allowed, and an optional
``# format: loggrasp.gnss-windows 1.0`` line: a newer major version is refused); each row says
that the rover stood on that log end between those times. Every epoch of the logs in
``[t_start, t_end]`` is averaged into that end: the point's fix is the WORST fix among those
epochs, its accuracy the median of theirs, and their scatter about the mean is reported
(``spread_h_m``/``spread_v_m``). A window that holds no epoch of any log is an error naming the
window and the logs' time span; so is a log with a window for one end only (unless one-ended logs
are allowed), and windows that overlap.
"""

from __future__ import annotations

import csv
import datetime as dt
import math
import statistics
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reconstruct.errors import GnssFormatError, GnssQualityError
from reconstruct.survey.points import (ENDS, FIXES, GnssPoint, GnssSurvey, check_survey, iso_utc, parse_time,
                                       read_lines)
from reconstruct.survey.stream import Epoch, ReceiverLog, StreamConfig, read_receiver_log
from synth.geometry import geodesy

WINDOWS_HEADER = ["log_id", "end", "t_start_utc", "t_end_utc"]
WINDOWS_FORMAT, WINDOWS_VERSION = "loggrasp.gnss-windows", "1.0"  # an optional "# format: ..." line


@dataclass(frozen=True)
class TimeWindow:
    """One row of the time-window sidecar."""

    log_id: str
    end: str
    t_start: dt.datetime
    t_end: dt.datetime
    source: str = ""


@dataclass(frozen=True)
class RawGnss:
    """Raw receiver logs and their time-window file: a survey still to be averaged."""

    logs: tuple[Path, ...]
    windows: Path
    date_utc: dt.date | None = None  # the date of NMEA epochs when the logs give none

    def __post_init__(self) -> None:
        if not self.logs:
            raise ValueError("give at least one receiver log")

    def __str__(self) -> str:
        return f"{', '.join(map(str, self.logs))} (windows {self.windows})"


@dataclass(frozen=True)
class RawSurvey:
    """A survey averaged from raw logs, with what was read from each log."""

    survey: GnssSurvey
    logs: tuple[ReceiverLog, ...]
    windows: tuple[TimeWindow, ...]


def read_time_windows(path: str | Path, require_both_ends: bool = True) -> list[TimeWindow]:
    """Read the time-window sidecar ``log_id,end,t_start_utc,t_end_utc`` (see the module docstring)."""
    path = Path(path)
    header = None
    windows = []
    for lineno, line in read_lines(path):
        s = line.strip()
        where = f"{path}:{lineno}"
        if s.startswith("#"):
            _check_version(where, s)
        if not s or s.startswith("#"):
            continue
        fields = [f.strip() for f in next(csv.reader([line]))]
        if header is None:
            header = fields
            if header != WINDOWS_HEADER:
                raise GnssFormatError(f"{where}: header must be {','.join(WINDOWS_HEADER)}, got {line!r}")
            continue
        if len(fields) != 4:
            raise GnssFormatError(f"{where}: expected 4 fields ({','.join(WINDOWS_HEADER)}), got {len(fields)}")
        log_id, end, t0, t1 = fields
        if not log_id:
            raise GnssFormatError(f"{where}: empty log_id")
        if end.lower() not in ENDS:
            raise GnssFormatError(f"{where} (log {log_id!r}): end must be 'a' or 'b', got {end!r}")
        a, b = parse_time(t0, where), parse_time(t1, where)
        if not b > a:
            raise GnssFormatError(f"{where} (log {log_id!r}): t_end_utc must be after t_start_utc")
        windows.append(TimeWindow(log_id, end.lower(), a, b, where))
    if not windows:
        raise GnssFormatError(f"{path}: no time windows" + ("" if header else " (an empty file)"))
    _check_windows(path, windows, require_both_ends)
    return windows


def _check_version(where: str, comment: str) -> None:
    """A ``# format: loggrasp.gnss-windows MAJOR.MINOR`` line: a newer major version is refused."""
    key, _, value = comment[1:].partition(":")
    if key.strip().lower() != "format":
        return
    parts = value.split()
    if len(parts) != 2 or parts[0] != WINDOWS_FORMAT:
        raise GnssFormatError(f"{where}: format {value.strip()!r} is not {WINDOWS_FORMAT} <version>")
    if parts[1].split(".")[0] != WINDOWS_VERSION.split(".")[0]:
        raise GnssFormatError(f"{where}: {WINDOWS_FORMAT} version {parts[1]} is not supported (this loggrasp reads "
                              f"{WINDOWS_VERSION.split('.')[0]}.x); upgrade loggrasp")


def _check_windows(path: Path, windows: list[TimeWindow], require_both_ends: bool) -> None:
    """No end twice, both ends of every log (when required), no two windows overlapping."""
    seen: dict[tuple[str, str], TimeWindow] = {}
    for w in windows:
        if (w.log_id, w.end) in seen:
            raise GnssFormatError(f"{w.source}: log {w.log_id!r} end {w.end!r} is measured twice (also "
                                  f"{seen[(w.log_id, w.end)].source}); delete one or fix its log id / end")
        seen[(w.log_id, w.end)] = w
    if require_both_ends:
        for (log_id, end), w in seen.items():
            other = "b" if end == "a" else "a"
            if (log_id, other) not in seen:
                raise GnssFormatError(f"{w.source}: log {log_id!r} has a window for end {end!r} but none for end "
                                      f"{other!r} in {path}; add the other end's window or remove this line")
    ordered = sorted(windows, key=lambda w: w.t_start)
    for a, b in zip(ordered, ordered[1:]):
        if b.t_start <= a.t_end:
            raise GnssFormatError(f"{b.source}: the window of log {b.log_id!r} end {b.end!r} overlaps {a.source} "
                                  f"(log {a.log_id!r} end {a.end!r}); the rover stands on one end at a time")


def average_window(w: TimeWindow, inside: list[Epoch]) -> GnssPoint:
    """The point of window ``w`` from its epochs (at least one): mean position, worst fix, median
    accuracies, RMS scatter."""
    rank = {f: i for i, f in enumerate(FIXES)}
    worst = max(inside, key=lambda e: rank[e.fix]).fix
    if worst == "none":
        n_none = sum(e.fix == "none" for e in inside)
        raise GnssQualityError(f"{w.source} (log {w.log_id!r} end {w.end!r}): {n_none} of {len(inside)} epochs have "
                               "no position fix; re-measure this end")
    lat, lon, h = (np.array([getattr(e, k) for e in inside]) for k in ("lat_deg", "lon_deg", "h_ell_m"))
    mean = (float(lat.mean()), float(lon.mean()), float(h.mean()))
    spread_h = spread_v = 0.0
    if len(inside) > 1:
        enu = geodesy.geodetic_to_site(mean, lat, lon, h, check=False)
        spread_h = float(np.sqrt(np.mean(enu[:, 0] ** 2 + enu[:, 1] ** 2)))
        spread_v = float(np.sqrt(np.mean(enu[:, 2] ** 2)))
    h_acc = [e.h_acc_m for e in inside if not math.isnan(e.h_acc_m)]
    v_acc = [e.v_acc_m for e in inside if not math.isnan(e.v_acc_m)]
    try:
        return GnssPoint(log_id=w.log_id, end=w.end, lat_deg=mean[0], lon_deg=mean[1], h_ell_m=mean[2], fix=worst,
                         h_acc_m=statistics.median(h_acc) if h_acc else math.nan,
                         v_acc_m=statistics.median(v_acc) if v_acc else math.nan,
                         time_utc=iso_utc(inside[len(inside) // 2].t_utc), n_epochs=len(inside),
                         spread_h_m=spread_h, spread_v_m=spread_v, source=w.source)
    except ValueError as exc:
        raise GnssFormatError(f"{w.source}: {exc}") from exc


def _spans(logs: Iterable[ReceiverLog]) -> str:
    return "; ".join(f"{log.path.name} {iso_utc(s[0])} to {iso_utc(s[1])}" for log in logs if (s := log.span()))


def survey_from_logs(
    log_paths: str | Path | Iterable[str | Path],
    windows_path: str | Path,
    *,
    date_utc: dt.date | None = None,
    allow_float: bool = False,
    max_distance_m: float = 50.0,
    area: Any = None,
    min_epochs: int = 1,
    require_both_ends: bool = True,
    config: StreamConfig = StreamConfig(),
) -> RawSurvey:
    """Average raw receiver logs (UBX, NMEA, mixed; see :mod:`reconstruct.survey.stream`) over the
    operator's time windows into a checked survey, with what was read from each log."""
    if min_epochs < 1:
        raise ValueError(f"min_epochs must be >= 1, got {min_epochs}")
    paths = [Path(log_paths)] if isinstance(log_paths, (str, Path)) else [Path(p) for p in log_paths]
    windows = read_time_windows(windows_path, require_both_ends)
    hint = min(w.t_start for w in windows)
    logs = [read_receiver_log(p, date_utc, hint, config) for p in paths]
    epochs = sorted((e for log in logs for e in log.epochs), key=lambda e: e.t_utc)
    points = []
    for w in windows:
        inside = [e for e in epochs if w.t_start <= e.t_utc <= w.t_end]
        if len(inside) < min_epochs:
            raise GnssQualityError(
                f"{w.source} (log {w.log_id!r} end {w.end!r}): {len(inside)} receiver epochs between "
                f"{iso_utc(w.t_start)} and {iso_utc(w.t_end)}, need {min_epochs}; the logs span {_spans(logs)} — "
                "check the window times (UTC!) against the logs")
        points.append(average_window(w, inside))
    warnings = tuple(x for log in logs for x in log.warnings)
    source = f"{', '.join(map(str, paths))} + {windows_path}"
    survey = check_survey(GnssSurvey(points=tuple(points), source=source, warnings=warnings),
                          allow_float=allow_float, max_distance_m=max_distance_m, area=area,
                          require_both_ends=require_both_ends)
    return RawSurvey(survey, tuple(logs), tuple(windows))


def read_raw_gnss(log_paths: str | Path | Iterable[str | Path], windows_path: str | Path, **kwargs: Any) -> GnssSurvey:
    """:func:`survey_from_logs`' survey alone."""
    return survey_from_logs(log_paths, windows_path, **kwargs).survey
