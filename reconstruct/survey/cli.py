"""``loggrasp survey``: raw receiver logs + time windows, or a field app's survey export -> a checked
survey CSV; and the ``--gnss``/``--gnss-windows`` pair that ``reconstruct`` and ``trial`` share.
Errors are raised and printed once by ``field.cli.run``."""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Literal

import typer

from synth.common.cli import CliError, Output, check_input, check_output_file, option

SURVEY_FORMAT = "loggrasp.survey-report"
GNSS_HELP = ("RTK endpoint survey CSV (see README), or raw receiver logs (u-blox .ubx, NMEA, mixed; repeat --gnss "
             "for several) with --gnss-windows.")
GNSS_WINDOWS_HELP = "Time-window file of the raw --gnss logs (log_id,end,t_start_utc,t_end_utc; see README)."
POINT_TABLE = ["log", "end", "epochs", "fix", "h acc m", "v acc m", "scatter h m", "scatter v m", "time UTC"]


def gnss_source(gnss: list[Path], windows: Path | None, date_utc: dt.date | None = None):
    """``--gnss`` (one survey CSV, or raw logs) and ``--gnss-windows`` -> a path or a
    :class:`~reconstruct.survey.windows.RawGnss`; a :class:`CliError` naming the flag otherwise."""
    from reconstruct.survey.windows import RawGnss

    for g in gnss:
        check_input(g, "--gnss", "file")
    if windows is None:
        if len(gnss) != 1 or gnss[0].suffix.lower() != ".csv":
            raise CliError(f"--gnss {' '.join(map(str, gnss))}: raw receiver logs need their time windows "
                           "(--gnss-windows FILE); a survey CSV ends in .csv")
        return gnss[0]
    check_input(windows, "--gnss-windows", "file")
    csvs = [g for g in gnss if g.suffix.lower() == ".csv"]
    if csvs:
        raise CliError(f"--gnss {csvs[0]} is a survey CSV: --gnss-windows goes with raw receiver logs only")
    return RawGnss(tuple(gnss), windows, date_utc)


def parse_date(text: str | None, flag: str = "--date") -> dt.date | None:
    if text is None:
        return None
    try:
        return dt.date.fromisoformat(text)
    except ValueError as exc:
        raise CliError(f"{flag} must be a date YYYY-MM-DD, got {text!r}") from exc


def survey_command(
    inputs: list[Path] = typer.Argument(..., metavar="LOG_OR_CSV...", help="Raw receiver logs (u-blox .ubx, NMEA, "
                                        "mixed captures; several files) with --windows, or one field app's survey CSV."),
    out: Path = option("--out", "Survey CSV to write (loggrasp.gnss-csv), what reconstruct --gnss reads.", default=...,
                       metavar="FILE.csv"),
    windows: Path = option("--windows", "The operator's time-window file for raw logs: log_id,end,t_start_utc,"
                           "t_end_utc (UTC).", default=None, metavar="FILE"),
    columns: str = option("--columns", "A field app's column names, OURS=THEIRS,... (e.g. id=Point,easting=E,"
                          "northing=N,height=H,fix=Solution), or a file of 'ours = theirs' lines.", default=None,
                          metavar="MAP|FILE"),
    date: str = option("--date", "UTC date of NMEA epochs when the log has no RMC/ZDA sentence.", default=None,
                       metavar="YYYY-MM-DD"),
    crs: Literal["EPSG:4619", "EPSG:3006"] = option("--crs", "CRS of the written CSV: EPSG:4619 (SWEREF 99 lat/lon) or "
                                                    "EPSG:3006 (SWEREF 99 TM).", default="EPSG:4619",
                                                    metavar="EPSG:4619|EPSG:3006"),
    allow_float: bool = option("--allow-float", "Accept RTK float ends.", default=False),
    one_end: bool = option("--allow-one-end", "Accept logs with one end measured (reconstruct places the other end "
                           "from the scan); default: both ends of every log.", default=False),
    min_epochs: int = option("--min-epochs", "Receiver epochs each window needs.", default=1, min=1),
    max_distance: float = option("--max-distance", "Farthest a point may lie from the median of all points.",
                                 default=50.0, unit="m", min=0.001, names=["max_distance_m"]),
    as_json: bool = option("--json", f"Print the per-end report as JSON (format {SURVEY_FORMAT}).", default=False),
) -> None:
    """Check a GNSS survey of log ends and write it as the survey CSV: raw receiver logs averaged over the
    operator's time windows, or a field app's export read as it comes (';' and decimal commas, --columns).

    Prints per log end: epochs used, fix, accuracy and scatter; per log file: what was read and skipped
    (RTCM3, polls, ACKs, unknown messages). Nothing is written unless every check passes.

    \b
    Example: loggrasp survey rover.ubx --windows windows.csv --out gnss.csv
    Example: loggrasp survey day1.ubx day1.nmea --windows windows.csv --out gnss.csv --allow-float --json
    Example: loggrasp survey export.csv --columns id=Point,easting=E,northing=N,height=H,fix=Status --out gnss.csv
    """
    from reconstruct.survey.gnss import column_map, read_gnss_csv, survey_from_logs, write_gnss_csv

    o = Output(as_json)
    for p in inputs:
        check_input(p, "LOG_OR_CSV", "file")
    check_output_file(out, "--out", ".csv")
    if any(p.resolve() == out.resolve() for p in [*inputs, *([windows] if windows else [])]):
        raise CliError(f"--out {out} is one of the inputs; choose another --out")
    checks = dict(allow_float=allow_float, max_distance_m=max_distance, require_both_ends=not one_end)
    logs = []
    if windows is None:
        if len(inputs) != 1 or inputs[0].suffix.lower() != ".csv":
            raise CliError("raw receiver logs need the operator's time windows (--windows FILE); a field app's survey "
                           "export is one .csv file")
        survey = read_gnss_csv(inputs[0], columns=column_map(columns) if columns else None, **checks)
    else:
        check_input(windows, "--windows", "file")
        if columns:
            raise CliError("--columns maps a survey CSV's columns; raw receiver logs have none (drop --columns)")
        raw = survey_from_logs(inputs, windows, date_utc=parse_date(date), min_epochs=min_epochs, **checks)
        survey, logs = raw.survey, list(raw.logs)
    write_gnss_csv(survey, out, crs)
    _report(o, survey, logs, out, crs)


def _report(o: Output, survey, logs, out: Path, crs: str) -> None:
    for log in logs:
        o.say(log.describe())
    for w in survey.warnings:
        o.warn(w)
    o.result(SURVEY_FORMAT, {"out": str(out), "crs": crs, "logs": [log.summary() for log in logs],
                             "points": [_point_json(p) for p in survey.points], "warnings": list(survey.warnings)})
    o.table(f"{len(survey.log_ids)} logs, {len(survey.points)} ends -> {out}", POINT_TABLE,
            [_point_row(p) for p in survey.points])


def _point_json(p) -> dict:
    return {"log_id": p.log_id, "end": p.end, "n_epochs": p.n_epochs, "fix": p.fix, "h_acc_m": p.h_acc_m,
            "v_acc_m": p.v_acc_m, "spread_h_m": p.spread_h_m, "spread_v_m": p.spread_v_m, "time_utc": p.time_utc,
            "lat_deg": p.lat_deg, "lon_deg": p.lon_deg, "h_ell_m": p.h_ell_m, "source": p.source}


def _point_row(p) -> list[str]:
    def m(v: float) -> str:
        return "-" if v != v else f"{v:.4f}"

    return [p.log_id, p.end, str(p.n_epochs), p.fix, m(p.h_acc_m), m(p.v_acc_m), m(p.spread_h_m), m(p.spread_v_m),
            p.time_utc or "-"]
