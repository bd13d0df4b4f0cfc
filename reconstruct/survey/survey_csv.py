"""The survey CSV (``loggrasp.gnss-csv``): its reader, as loggrasp writes it and as field apps
export it, and its writer. The format is described in :mod:`reconstruct.survey.gnss`.

Field-app exports are read as they come:

* the separator is found from the header row (``,``, ``;`` or a tab); with ``;`` or a tab,
  numbers may use a decimal comma (``64,1000123``), as European spreadsheets write them;
* other column names are mapped onto ours by a :class:`ColumnMap` (``--columns`` on the command
  line: ``id=Point,easting=E,northing=N,height=H,fix=Solution``, or a file of ``ours = theirs``
  lines). With a map, columns it does not name are ignored, the accuracies may be absent, and
  without an ``end`` column the end is the point name's last letter (``log3a``, ``log3-b``);
* fix words of field apps (``FIX``, ``Fixed``, ``RTK float``, ``DGPS``, ``Autonomous``, a GGA
  quality number...) are read as our fixes (:data:`FIX_WORDS`).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from reconstruct.errors import GnssError, GnssFormatError
from reconstruct.survey.points import (FIXES, GnssPoint, GnssSurvey, check_survey, read_lines, time_field)
from synth.common.files import atomic_write_bytes
from synth.geometry import geodesy

GNSS_CSV_FORMAT = "loggrasp.gnss-csv"
GNSS_CSV_VERSION = "1.0"

GEO_COLS = ("lat_deg", "lon_deg")
TM_COLS = ("easting_m", "northing_m")
REQUIRED = ("log_id", "end", "h_ell_m", "fix", "h_acc_m", "v_acc_m")
OPTIONAL = ("time_utc", "n_epochs", "spread_h_m", "spread_v_m")
COLUMNS = (*REQUIRED[:2], *GEO_COLS, *TM_COLS, *REQUIRED[2:], *OPTIONAL)
CRS_ALLOWED = (geodesy.EPSG_SWEREF99, geodesy.EPSG_SWEREF99_TM)

#: short names a column map may use for our columns
COLUMN_ALIASES = {"id": "log_id", "point": "log_id", "name": "log_id", "lat": "lat_deg", "lon": "lon_deg",
                  "easting": "easting_m", "northing": "northing_m", "height": "h_ell_m", "h_ell": "h_ell_m",
                  "h_acc": "h_acc_m", "v_acc": "v_acc_m", "time": "time_utc", "epochs": "n_epochs"}

#: a field app's fix word (lower case) -> our fix; GGA quality numbers too
FIX_WORDS = {**{f: f for f in FIXES},
             "fix": "rtk_fixed", "fixed": "rtk_fixed", "rtk fix": "rtk_fixed", "rtk fixed": "rtk_fixed",
             "rtk_fix": "rtk_fixed", "rtk": "rtk_fixed", "4": "rtk_fixed",
             "float": "rtk_float", "rtk float": "rtk_float", "5": "rtk_float",
             "dgps": "dgnss", "dgnss": "dgnss", "differential": "dgnss", "2": "dgnss",
             "single": "single", "autonomous": "single", "standalone": "single", "gps": "single", "1": "single",
             "none": "none", "no fix": "none", "invalid": "none", "0": "none"}

_POINT_END = re.compile(r"^(?P<log>.*?)[\s_.-]?(?P<end>[abAB])$")


@dataclass(frozen=True)
class ColumnMap:
    """How a field app's columns map onto ours: ``pairs`` of (our column, the file's column)."""

    pairs: tuple[tuple[str, str], ...]
    source: str = "--columns"  # where the map came from, for messages

    def __post_init__(self) -> None:
        ours = [o for o, _ in self.pairs]
        unknown = sorted(set(ours) - set(COLUMNS))
        if unknown:
            raise ValueError(f"{self.source}: unknown column name(s) {unknown}; ours are "
                             f"{', '.join(COLUMNS)} (or {', '.join(COLUMN_ALIASES)})")
        if len(set(ours)) != len(ours):
            raise ValueError(f"{self.source}: a column is mapped twice")
        if not self.pairs:
            raise ValueError(f"{self.source}: an empty column map")

    def rename(self) -> dict[str, str]:
        """The file's column -> ours."""
        return {theirs: ours for ours, theirs in self.pairs}


def parse_columns(text: str, source: str = "--columns") -> ColumnMap:
    """``id=Point,easting=E,...`` -> a :class:`ColumnMap` (our names or their aliases on the left)."""
    pairs = []
    for part in text.split(","):
        if not part.strip():
            continue
        if "=" not in part:
            raise ValueError(f"{source}: {part.strip()!r} is not OURS=THEIRS (e.g. id=Point,easting=E)")
        ours, theirs = (s.strip() for s in part.split("=", 1))
        pairs.append((COLUMN_ALIASES.get(ours.lower(), ours.lower()), theirs))
    return ColumnMap(tuple(pairs), source)


def read_column_map(path: str | Path) -> ColumnMap:
    """A column-map file: one ``ours = theirs`` line per column (``#`` comments); a column name of
    the file may hold commas and spaces here."""
    path = Path(path)
    pairs = []
    for lineno, line in read_lines(path):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if "=" not in s:
            raise GnssFormatError(f"{path}:{lineno}: {s!r} is not 'ours = theirs' (e.g. easting = Easting [m])")
        ours, theirs = (v.strip() for v in s.split("=", 1))
        pairs.append((COLUMN_ALIASES.get(ours.lower(), ours.lower()), theirs))
    try:
        return ColumnMap(tuple(pairs), str(path))
    except ValueError as exc:
        raise GnssFormatError(str(exc)) from exc


def column_map(spec: str) -> ColumnMap:
    """``--columns``: ``OURS=THEIRS,...`` inline, or the path of a column-map file."""
    if "=" in spec:
        try:
            return parse_columns(spec)
        except ValueError as exc:
            raise GnssFormatError(str(exc)) from exc
    return read_column_map(spec)


# -- reader ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Table:
    """A CSV file's meaningful ``#`` lines, header and rows, and how its numbers are written."""

    meta: dict[str, tuple[str, int]]
    header: list[str]
    header_line: int
    rows: list[tuple[int, list[str]]]
    decimal_comma: bool


def _read_table(path: Path) -> _Table:
    meta: dict[str, tuple[str, int]] = {}
    header: list[str] | None = None
    header_line, delimiter = 0, ","
    rows: list[tuple[int, list[str]]] = []
    for lineno, line in read_lines(path):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s[1:].strip()
            if ":" in body:
                k, v = body.split(":", 1)
                meta[k.strip().lower()] = (v.strip(), lineno)
            continue
        if header is None:
            delimiter = max((";", "\t", ","), key=line.count)
            header, header_line = [f.strip() for f in next(csv.reader([line], delimiter=delimiter))], lineno
        else:
            rows.append((lineno, next(csv.reader([line], delimiter=delimiter))))
    if header is None:
        raise GnssFormatError(f"{path}: no header row (expected e.g. log_id,end,lat_deg,lon_deg,...)")
    return _Table(meta, header, header_line, rows, decimal_comma=delimiter != ",")


def read_gnss_csv(path: str | Path, *, allow_float: bool = False, max_distance_m: float = 50.0,
                  area: Any = None, require_both_ends: bool = True, columns: ColumnMap | None = None) -> GnssSurvey:
    """Read and check a survey CSV (format in :mod:`reconstruct.survey.gnss`); ``columns`` maps a
    field app's column names onto ours (see the module docstring).

    Raises :class:`GnssFileError` (missing/unreadable), :class:`GnssFormatError`,
    :class:`GnssQualityError`, :class:`GnssOutlierError`."""
    path = Path(path)
    table = _read_table(path)
    _check_version(path, table.meta)
    header = _rename(path, table, columns)
    cols = _check_header(path, table.header_line, header, mapped=columns is not None)
    projected = TM_COLS[0] in cols
    crs = _check_crs(path, table.meta, projected)
    points = []
    for lineno, fields in table.rows:
        where = f"{path}:{lineno}"
        if len(fields) != len(header):
            raise GnssFormatError(
                f"{where}: {len(fields)} fields, the header has {len(header)} ({','.join(table.header)})")
        rec = {name: v.strip() for name, v in zip(header, fields) if name}
        if table.decimal_comma:
            rec = {k: (v if k in ("log_id", "end", "fix", "time_utc") else v.replace(",", ".")) for k, v in rec.items()}
        points.append(_point(rec, where, projected))
    survey = GnssSurvey(points=tuple(points), source=f"{path} ({crs})")
    return check_survey(survey, allow_float=allow_float, max_distance_m=max_distance_m, area=area,
                        require_both_ends=require_both_ends)


def _rename(path: Path, table: _Table, columns: ColumnMap | None) -> list[str]:
    """The header in our names ("" for a column a map leaves out that is not one of ours)."""
    if columns is None:
        return table.header
    rename = columns.rename()
    missing = [theirs for theirs in rename if theirs not in table.header]
    if missing:
        raise GnssFormatError(f"{path}:{table.header_line}: no column(s) {missing} named by {columns.source}; "
                              f"the header has {', '.join(table.header)}")
    return [rename.get(h, h if h in COLUMNS else "") for h in table.header]


def _point(rec: dict[str, str], where: str, projected: bool) -> GnssPoint:
    log_id, end = _log_and_end(rec, where)
    try:
        if projected:
            e, n = _num(rec, "easting_m", where), _num(rec, "northing_m", where)
            try:
                geodesy.check_sweref_tm(e, n, f"{where} (log {log_id!r})")
            except geodesy.CoordinateError as exc:
                raise GnssFormatError(str(exc)) from exc
            lat_a, lon_a = geodesy.tm_to_geodetic(e, n, check=False)
            lat, lon = float(lat_a), float(lon_a)
        else:
            lat, lon = _num(rec, "lat_deg", where), _num(rec, "lon_deg", where)
        fix_word = rec["fix"].strip().lower()
        return GnssPoint(
            log_id=log_id, end=end, lat_deg=lat, lon_deg=lon, h_ell_m=_num(rec, "h_ell_m", where),
            fix=FIX_WORDS.get(fix_word, fix_word),
            h_acc_m=_num(rec, "h_acc_m", where, allow_empty=True),
            v_acc_m=_num(rec, "v_acc_m", where, allow_empty=True),
            time_utc=time_field(rec.get("time_utc", ""), where),
            n_epochs=int(_num(rec, "n_epochs", where, default=1.0)),
            spread_h_m=_num(rec, "spread_h_m", where, default=0.0),
            spread_v_m=_num(rec, "spread_v_m", where, default=0.0),
            source=where,
        )
    except GnssError:
        raise
    except ValueError as exc:  # GnssPoint's checks: the message names file, line and log
        raise GnssFormatError(str(exc)) from exc


def _log_and_end(rec: dict[str, str], where: str) -> tuple[str, str]:
    """The log id and end; without an ``end`` column, the point name's last letter (``log3a``)."""
    log_id = rec["log_id"]
    if not log_id:
        raise GnssFormatError(f"{where}: empty log_id")
    if "end" in rec:
        return log_id, rec["end"].lower()
    m = _POINT_END.match(log_id)
    if not m or not m.group("log"):
        raise GnssFormatError(f"{where}: point {log_id!r} names no end; name points like log3a / log3b or map an "
                              "end column (end=COLUMN)")
    return m.group("log"), m.group("end").lower()


def _check_version(path: Path, meta: dict[str, tuple[str, int]]) -> None:
    if "format" not in meta:
        return
    value, lineno = meta["format"]
    parts = value.split()
    if len(parts) != 2 or parts[0] != GNSS_CSV_FORMAT:
        raise GnssFormatError(f"{path}:{lineno}: format {value!r} is not {GNSS_CSV_FORMAT} <version>")
    if parts[1].split(".")[0] != GNSS_CSV_VERSION.split(".")[0]:
        raise GnssFormatError(
            f"{path}:{lineno}: {GNSS_CSV_FORMAT} version {parts[1]} is not supported (this loggrasp "
            f"reads {GNSS_CSV_VERSION.split('.')[0]}.x); upgrade loggrasp or re-export the survey"
        )


def _check_header(path: Path, lineno: int, header: list[str], mapped: bool = False) -> set[str]:
    named = [c for c in header if c]
    cols = set(named)
    where = f"{path}:{lineno}"
    if len(cols) != len(named):
        raise GnssFormatError(f"{where}: repeated column names in header {header}")
    has_geo = any(c in cols for c in GEO_COLS)
    has_tm = any(c in cols for c in TM_COLS)
    if has_geo and has_tm:
        raise GnssFormatError(f"{where}: give lat_deg/lon_deg OR easting_m/northing_m, not both")
    if not (has_geo or has_tm):
        raise GnssFormatError(f"{where}: no coordinate columns (lat_deg,lon_deg or easting_m,northing_m); a field "
                              "app's export names them its own way: map them with --columns (see README)")
    need = set(REQUIRED) | set(TM_COLS if has_tm else GEO_COLS)
    if mapped:  # a field app's export: the end may be in the point name, the accuracies unknown
        need -= {"end", "h_acc_m", "v_acc_m"}
    missing = [c for c in need if c not in cols]
    if missing:
        raise GnssFormatError(f"{where}: header lacks column(s) {sorted(missing)}"
                              + ("; map them with --columns (see README)" if not mapped else ""))
    unknown = cols - need - set(OPTIONAL) - ({"end", "h_acc_m", "v_acc_m"} if mapped else set())
    if unknown:
        raise GnssFormatError(
            f"{where}: unknown column(s) {sorted(unknown)}; allowed: "
            f"{', '.join(sorted(need | set(OPTIONAL)))} (map other names with --columns)"
        )
    return cols


def _check_crs(path: Path, meta: dict[str, tuple[str, int]], projected: bool) -> str:
    expected = geodesy.EPSG_SWEREF99_TM if projected else geodesy.EPSG_SWEREF99
    if "crs" not in meta:
        return expected
    value, lineno = meta["crs"]
    crs = value.upper().replace(" ", "")
    if crs not in CRS_ALLOWED:
        raise GnssFormatError(
            f"{path}:{lineno}: CRS {value!r} is not supported; a survey must be in SWEREF 99 "
            f"({geodesy.EPSG_SWEREF99}, lat/lon) or SWEREF 99 TM ({geodesy.EPSG_SWEREF99_TM}, "
            "easting/northing) — set the rover to SWEREF 99 (RTK through SWEPOS delivers it)"
        )
    if crs != expected:
        raise GnssFormatError(
            f"{path}:{lineno}: CRS {crs} does not match the coordinate columns "
            f"({'easting_m/northing_m' if projected else 'lat_deg/lon_deg'} need {expected})"
        )
    return crs


def _num(rec: Mapping[str, str], name: str, where: str, allow_empty: bool = False,
         default: float | None = None) -> float:
    raw = rec.get(name, "")
    if raw == "":
        if default is not None:
            return default
        if allow_empty:
            return math.nan
        raise GnssFormatError(f"{where}: {name} is empty")
    try:
        v = float(raw)
    except ValueError as exc:
        raise GnssFormatError(f"{where}: {name} {raw!r} is not a number") from exc
    if not math.isfinite(v) and not (allow_empty and math.isnan(v)):
        raise GnssFormatError(f"{where}: {name} must be finite, got {raw!r}")
    return v


# -- writer ---------------------------------------------------------------------------------
def survey_csv_bytes(survey: GnssSurvey, crs: str = geodesy.EPSG_SWEREF99) -> bytes:
    """``survey`` as survey CSV text, in SWEREF 99 lat/lon (``EPSG:4619``, 1e-10 deg ≈ 0.01 mm)
    or SWEREF 99 TM (``EPSG:3006``, 0.1 mm)."""
    if crs not in CRS_ALLOWED:
        raise ValueError(f"crs must be one of {CRS_ALLOWED}, got {crs!r}")
    projected = crs == geodesy.EPSG_SWEREF99_TM
    buf = io.StringIO()
    buf.write(f"# format: {GNSS_CSV_FORMAT} {GNSS_CSV_VERSION}\n")
    buf.write(f"# crs: {crs}\n")
    buf.write("# heights: ellipsoidal (GRS80) [m]; accuracies 1 sigma [m]\n")
    w = csv.writer(buf, lineterminator="\n")
    coord_cols = list(TM_COLS if projected else GEO_COLS)
    w.writerow(["log_id", "end", *coord_cols, "h_ell_m", "fix", "h_acc_m", "v_acc_m", *OPTIONAL])
    lat, lon, _ = survey.geodetic()
    if projected:
        e, n = geodesy.geodetic_to_tm(lat, lon)
        coords = [(f"{a:.4f}", f"{b:.4f}") for a, b in zip(e, n)]
    else:
        coords = [(f"{a:.10f}", f"{b:.10f}") for a, b in zip(lat, lon)]

    def acc(v: float) -> str:
        return "" if math.isnan(v) else f"{v:.4f}"

    for p, c in zip(survey.points, coords):
        w.writerow([p.log_id, p.end, *c, f"{p.h_ell_m:.4f}", p.fix, acc(p.h_acc_m), acc(p.v_acc_m),
                    p.time_utc, p.n_epochs, f"{p.spread_h_m:.4f}", f"{p.spread_v_m:.4f}"])
    return buf.getvalue().encode("utf-8")


def write_gnss_csv(survey: GnssSurvey, path: str | Path, crs: str = geodesy.EPSG_SWEREF99) -> Path:
    """Write ``survey`` as a survey CSV (atomically; see :func:`survey_csv_bytes`). Returns the path."""
    path = Path(path)
    atomic_write_bytes(path, survey_csv_bytes(survey, crs))
    return path
