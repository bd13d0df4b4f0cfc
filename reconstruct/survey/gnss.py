"""RTK GNSS surveys of log end points: reading, checking, simulating and writing them.

An operator walks the pile with an RTK rover and measures both end centres of each log. The
result arrives in one of two shapes:

1. **A survey CSV** (what a controller app exports, and what :func:`write_gnss_csv` writes).
2. **Raw receiver logs** (NMEA GGA or u-blox UBX) plus a **time-window sidecar** saying which
   log end the rover stood on when.

Survey CSV format (``loggrasp.gnss-csv``, version 1.0)
------------------------------------------------------
UTF-8 text, comma-separated, one header row, one row per log end. Lines starting with ``#`` are
comments; two of them are meaningful (key and value separated by a colon, case-insensitive)::

    # format: loggrasp.gnss-csv 1.0      (written by loggrasp; optional in hand-made files;
                                          a newer MAJOR version is refused)
    # crs: EPSG:4619                     (EPSG:4619 SWEREF 99 lat/lon, or EPSG:3006 SWEREF 99 TM;
                                          any other CRS is refused)

Columns (header names exactly as below, any order)::

    log_id      text, the log's name (e.g. "log3"); every log has exactly one "a" and one "b" row
    end         "a" or "b" (which end of the log; "a" is the butt when known)
    lat_deg     SWEREF 99 latitude [deg]   } geographic form (crs EPSG:4619, the default), or
    lon_deg     SWEREF 99 longitude [deg]  }
    easting_m   SWEREF 99 TM easting [m]   } projected form (crs EPSG:3006, the default when
    northing_m  SWEREF 99 TM northing [m]  } these columns are used) — never both forms
    h_ell_m     ellipsoidal height above GRS80 [m] (NOT a height above sea level)
    fix         rtk_fixed | rtk_float | dgnss | single | none
    h_acc_m     receiver's horizontal accuracy estimate, 1 sigma [m]; empty = unknown
    v_acc_m     receiver's vertical accuracy estimate, 1 sigma [m]; empty = unknown
    time_utc    optional, ISO 8601 UTC time of the measurement (e.g. 2026-05-14T09:30:05Z)
    n_epochs    optional, number of receiver epochs averaged into the point (default 1)
    spread_h_m  optional, horizontal RMS scatter of those epochs about their mean [m]
    spread_v_m  optional, vertical RMS scatter of those epochs [m]

Example::

    # format: loggrasp.gnss-csv 1.0
    # crs: EPSG:4619
    log_id,end,lat_deg,lon_deg,h_ell_m,fix,h_acc_m,v_acc_m,time_utc
    log0,a,64.1000123456,20.0000456789,251.2345,rtk_fixed,0.0140,0.0210,2026-05-14T09:30:05Z
    log0,b,64.1000345678,20.0000987654,251.3012,rtk_fixed,0.0150,0.0230,2026-05-14T09:30:41Z

Raw receiver logs
-----------------
* **NMEA** (text; ``.nmea``, ``.txt``, ``.log``), parsed with pynmea2: GGA gives position,
  quality (4 = RTK fixed, 5 = RTK float, 2 = DGNSS, 1 = single, 0 = none) and time of day; the
  ellipsoidal height is ``altitude + geoid separation``. GST (same time stamp), when present,
  gives the accuracies (sqrt(sd_lat² + sd_lon²) and sd_alt). RMC gives the date; a log without
  RMC needs ``date_utc``. Sentences failing their checksum are skipped and reported in
  ``GnssSurvey.warnings``.
* **UBX** (binary; ``.ubx``), parsed with pyubx2: NAV-PVT gives time, fix (``carrSoln`` 2 =
  fixed, 1 = float) and a position; NAV-HPPOSLLH with the same ``iTOW`` replaces the position
  with its high-precision one and gives ``hAcc``/``vAcc`` (mm in the message).

Time-window sidecar (``loggrasp.gnss-windows``): a CSV with header
``log_id,end,t_start_utc,t_end_utc`` (ISO 8601 times, UTC; "#" comments allowed). Every epoch
in ``[t_start, t_end]`` is averaged into that log end; the point's ``fix`` is the WORST fix among
those epochs, its accuracy the median of theirs, and the scatter is reported as
``spread_h_m``/``spread_v_m``.

Checks (all readers, :func:`check_survey`): every point lies in Sweden (swapped lat/lon is named
as such), every log has exactly one ``a`` and one ``b`` end, only ``rtk_fixed`` points unless
``allow_float=True`` (which admits ``rtk_float``; ``dgnss``/``single``/``none`` are never
accepted: metre-level positions are useless for logs), and no point lies more than
``max_distance_m`` (default 50 m) horizontally from the median of all points or, when ``area`` is
given, from the scanned area's origin. Errors name the file, the line and the log id.

The site frame and heights follow :mod:`synth.geometry.geodesy` (ellipsoidal heights, ENU at an origin).
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from reconstruct.errors import (
    GnssError,
    GnssFileError,
    GnssFormatError,
    GnssOutlierError,
    GnssQualityError,
)
from synth.geometry import geodesy
from synth.common.files import atomic_write_bytes
from synth.scene.pile import Georeference, PileSpec

GNSS_CSV_FORMAT = "loggrasp.gnss-csv"
GNSS_CSV_VERSION = "1.0"

FIXES = ("rtk_fixed", "rtk_float", "dgnss", "single", "none")  # best to worst
ENDS = ("a", "b")
_GEO_COLS = ("lat_deg", "lon_deg")
_TM_COLS = ("easting_m", "northing_m")
_REQUIRED = ("log_id", "end", "h_ell_m", "fix", "h_acc_m", "v_acc_m")
_OPTIONAL = ("time_utc", "n_epochs", "spread_h_m", "spread_v_m")
_CRS_ALLOWED = (geodesy.EPSG_SWEREF99, geodesy.EPSG_SWEREF99_TM)

_GGA_QUALITY = {4: "rtk_fixed", 5: "rtk_float", 2: "dgnss", 1: "single", 0: "none"}


@dataclass(frozen=True)
class GnssPoint:
    """One measured log end (float64 coordinates)."""

    log_id: str
    end: str  # "a" or "b"
    lat_deg: float  # SWEREF 99 [deg]
    lon_deg: float  # SWEREF 99 [deg]
    h_ell_m: float  # ellipsoidal height, GRS80 [m]
    fix: str  # one of FIXES
    h_acc_m: float = math.nan  # horizontal accuracy estimate, 1 sigma [m]; NaN = unknown
    v_acc_m: float = math.nan  # vertical accuracy estimate, 1 sigma [m]; NaN = unknown
    time_utc: str = ""  # ISO 8601 UTC; "" = unknown
    n_epochs: int = 1  # receiver epochs averaged into this point [-]
    spread_h_m: float = 0.0  # horizontal RMS scatter of the averaged epochs [m]
    spread_v_m: float = 0.0  # vertical RMS scatter of the averaged epochs [m]
    source: str = ""  # where it came from ("file:line"), for messages

    def __post_init__(self) -> None:
        if self.end not in ENDS:
            raise ValueError(f"{self.where}: end must be 'a' or 'b', got {self.end!r}")
        if self.fix not in FIXES:
            raise ValueError(f"{self.where}: fix must be one of {', '.join(FIXES)}, got {self.fix!r}")
        for name in ("lat_deg", "lon_deg", "h_ell_m"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ValueError(f"{self.where}: {name} must be finite, got {v}")
        for name in ("h_acc_m", "v_acc_m"):
            v = getattr(self, name)
            if not (math.isnan(v) or 0.0 <= v < 1e4):
                raise ValueError(f"{self.where}: {name} must be >= 0 m (or unknown), got {v}")
        if self.n_epochs < 1:
            raise ValueError(f"{self.where}: n_epochs must be >= 1, got {self.n_epochs}")

    @property
    def where(self) -> str:
        loc = f"{self.source}: " if self.source else ""
        return f"{loc}log {self.log_id!r} end {self.end!r}"


@dataclass(frozen=True)
class GnssSurvey:
    """A checked set of log end points. ``warnings`` lists things a person should know (skipped
    corrupt sentences, float points admitted...)."""

    points: tuple[GnssPoint, ...]
    source: str = ""
    warnings: tuple[str, ...] = ()

    @property
    def log_ids(self) -> list[str]:
        """Log ids in order of first appearance."""
        return list(dict.fromkeys(p.log_id for p in self.points))

    def point(self, log_id: str, end: str) -> GnssPoint:
        for p in self.points:
            if p.log_id == log_id and p.end == end:
                return p
        raise KeyError(f"no point for log {log_id!r} end {end!r}")

    def geodetic(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lat [deg], lon [deg], h [m]) arrays of all points, in ``points`` order."""
        a = np.array([[p.lat_deg, p.lon_deg, p.h_ell_m] for p in self.points], dtype=np.float64)
        return a[:, 0], a[:, 1], a[:, 2]

    def default_origin(self) -> tuple[float, float, float]:
        """The site origin used when none is given: the mean of all points (lat, lon, h).

        A plain mean of degrees is exact to far below a millimetre over a pile's extent."""
        lat, lon, h = self.geodetic()
        return float(np.mean(lat)), float(np.mean(lon)), float(np.mean(h))

    def points_site(self, origin: Any = None) -> np.ndarray:
        """All points in the site ENU frame at ``origin`` (default :meth:`default_origin`),
        shape (n, 3) [m]."""
        origin = self.default_origin() if origin is None else origin
        lat, lon, h = self.geodetic()
        return geodesy.geodetic_to_site(origin, lat, lon, h)

    def endpoints_site(self, origin: Any = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """``{log_id: (end_a, end_b)}`` in the site ENU frame [m] (float64 (3,) arrays).

        ``origin``: a :class:`~synth.scene.pile.Georeference` or (lat_deg, lon_deg, h_m); default
        :meth:`default_origin`."""
        site = self.points_site(origin)
        out: dict[str, dict[str, np.ndarray]] = {}
        for p, xyz in zip(self.points, site):
            out.setdefault(p.log_id, {})[p.end] = xyz
        missing = [k for k, v in out.items() if set(v) != set(ENDS)]
        if missing:
            raise GnssFormatError(f"logs {missing} lack an 'a' or 'b' end; run check_survey first")
        return {k: (v["a"], v["b"]) for k, v in out.items()}

    def ends_site(self, origin: Any = None) -> dict[str, tuple[np.ndarray | None, np.ndarray | None]]:
        """``{log_id: (end_a, end_b)}`` in the site ENU frame [m], ``None`` for an end not measured
        (:func:`check_survey` with ``require_both_ends=False``)."""
        site = self.points_site(origin)
        out: dict[str, list] = {}
        for p, xyz in zip(self.points, site):
            out.setdefault(p.log_id, [None, None])[ENDS.index(p.end)] = xyz
        return {k: (v[0], v[1]) for k, v in out.items()}

    def endpoints_pile(self, georef: Georeference) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """``{log_id: (end_a, end_b)}`` in the pile frame of ``georef`` [m] (through its site
        frame and ``T_site_pile``) — ready for :meth:`synth.scene.pile.LogSpec.from_endpoints`."""
        site = self.endpoints_site(georef)
        return {k: tuple(geodesy.site_to_pile(georef, np.stack(v))) for k, v in site.items()}

    def georeference(self, origin: Any = None) -> Georeference:
        """A :class:`Georeference` at ``origin`` (default: the mean point) with the pile frame
        equal to the site frame (identity ``T_site_pile``)."""
        lat, lon, h = geodesy.origin_of(self.default_origin() if origin is None else origin)
        return Georeference(origin_lat_deg=lat, origin_lon_deg=lon, origin_h_m=h)


# -- checks ---------------------------------------------------------------------------------
def check_survey(survey: GnssSurvey, *, allow_float: bool = False, max_distance_m: float = 50.0,
                 area: Any = None, require_both_ends: bool = True) -> GnssSurvey:
    """Check a survey (see the module docstring); return it, with a warning added when float
    points were admitted. ``area``: the scanned area's origin (a Georeference or (lat, lon, h)).
    ``require_both_ends=False`` admits logs with one end measured (a warning names them): the
    reconstruction places the other end from the scan.
    Raises :class:`GnssFormatError`, :class:`GnssQualityError` or :class:`GnssOutlierError`."""
    if not max_distance_m > 0:
        raise ValueError(f"max_distance_m must be > 0 m, got {max_distance_m}")
    pts = survey.points
    if not pts:
        raise GnssFormatError(f"{survey.source or 'survey'}: no points")
    for p in pts:
        try:
            geodesy.check_geodetic(p.lat_deg, p.lon_deg, p.where)
            geodesy.check_height(p.h_ell_m, p.where)
        except geodesy.CoordinateError as exc:
            raise GnssFormatError(str(exc)) from exc
    # ends: exactly one a and one b per log
    seen: dict[tuple[str, str], GnssPoint] = {}
    for p in pts:
        key = (p.log_id, p.end)
        if key in seen:
            raise GnssFormatError(
                f"log {p.log_id!r} end {p.end!r} is measured twice ({seen[key].source or '?'} and "
                f"{p.source or '?'}); delete one or fix its log id / end"
            )
        seen[key] = p
    one_ended = []
    for log_id in survey.log_ids:
        for end in ENDS:
            if (log_id, end) not in seen:
                other = seen[(log_id, "b" if end == "a" else "a")]
                if not require_both_ends:
                    one_ended.append(f"{log_id} (no end {end})")
                    continue
                raise GnssFormatError(
                    f"log {log_id!r} has no end {end!r} (only {other.where}); measure the other "
                    "end or remove the log from the survey"
                )
    # fix quality
    accepted = ("rtk_fixed", "rtk_float") if allow_float else ("rtk_fixed",)
    bad = [p for p in pts if p.fix not in accepted]
    if bad:
        listing = "; ".join(f"{p.where} is {p.fix}" for p in bad[:8])
        more = f" (and {len(bad) - 8} more)" if len(bad) > 8 else ""
        hint = ("re-measure them with an RTK fixed solution"
                + ("" if allow_float else ", or accept RTK float points explicitly with --allow-float "
                   "(the scan then places every float end it sees)"))
        raise GnssQualityError(f"{len(bad)} point(s) are not {' / '.join(accepted)}: {listing}{more}; {hint}")
    warnings = list(survey.warnings)
    if one_ended:
        warnings.append(f"{len(one_ended)} log(s) with one end measured: {', '.join(one_ended)}; the other end "
                        "comes from the scan")
    n_float = sum(p.fix == "rtk_float" for p in pts)
    if n_float:
        warnings.append(f"{n_float} RTK float point(s) admitted (decimetre-level accuracy)")
    # distances
    lat, lon, h = survey.geodetic()
    med = (float(np.median(lat)), float(np.median(lon)), float(np.median(h)))
    _check_distances(pts, geodesy.geodetic_to_site(med, lat, lon, h), max_distance_m,
                     "the median of all points")
    if area is not None:
        _check_distances(pts, geodesy.geodetic_to_site(area, lat, lon, h), max_distance_m,
                         "the scanned area's origin")
    return replace(survey, warnings=tuple(warnings))


def _check_distances(pts: Sequence[GnssPoint], site: np.ndarray, limit: float, what: str) -> None:
    d = np.hypot(site[:, 0], site[:, 1])
    far = np.flatnonzero(d > limit)
    if far.size:
        i = int(far[np.argmax(d[far])])
        raise GnssOutlierError(
            f"{pts[i].where} lies {d[i]:.1f} m from {what} (limit {limit:g} m); "
            f"{far.size} point(s) too far. Check its log id and coordinates, or raise max_distance_m"
        )


# -- CSV reader -----------------------------------------------------------------------------
def read_gnss_csv(path: str | Path, *, allow_float: bool = False, max_distance_m: float = 50.0,
                  area: Any = None, require_both_ends: bool = True) -> GnssSurvey:
    """Read and check a survey CSV (format in the module docstring).

    Raises :class:`GnssFileError` (missing/unreadable), :class:`GnssFormatError`,
    :class:`GnssQualityError`, :class:`GnssOutlierError`."""
    path = Path(path)
    lines = _read_lines(path)
    meta: dict[str, tuple[str, int]] = {}
    header: list[str] | None = None
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    for lineno, line in lines:
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s[1:].strip()
            if ":" in body:
                k, v = body.split(":", 1)
                meta[k.strip().lower()] = (v.strip(), lineno)
            continue
        fields = next(csv.reader([line]))
        if header is None:
            header, header_line = [f.strip() for f in fields], lineno
        else:
            rows.append((lineno, fields))
    if header is None:
        raise GnssFormatError(f"{path}: no header row (expected e.g. log_id,end,lat_deg,lon_deg,...)")
    _check_version(path, meta)
    cols = _check_header(path, header_line, header)
    projected = _TM_COLS[0] in cols
    crs = _check_crs(path, meta, projected)
    points = []
    for lineno, fields in rows:
        where = f"{path}:{lineno}"
        if len(fields) != len(header):
            raise GnssFormatError(
                f"{where}: {len(fields)} fields, the header has {len(header)} ({','.join(header)})"
            )
        rec = {name: v.strip() for name, v in zip(header, fields)}
        log_id = rec["log_id"]
        if not log_id:
            raise GnssFormatError(f"{where}: empty log_id")
        try:
            if projected:
                e = _num(rec, "easting_m", where)
                n = _num(rec, "northing_m", where)
                try:
                    geodesy.check_sweref_tm(e, n, f"{where} (log {log_id!r})")
                except geodesy.CoordinateError as exc:
                    raise GnssFormatError(str(exc)) from exc
                lat_a, lon_a = geodesy.tm_to_geodetic(e, n, check=False)
                lat, lon = float(lat_a), float(lon_a)
            else:
                lat = _num(rec, "lat_deg", where)
                lon = _num(rec, "lon_deg", where)
            point = GnssPoint(
                log_id=log_id, end=rec["end"].lower(), lat_deg=lat, lon_deg=lon,
                h_ell_m=_num(rec, "h_ell_m", where), fix=rec["fix"].lower(),
                h_acc_m=_num(rec, "h_acc_m", where, allow_empty=True),
                v_acc_m=_num(rec, "v_acc_m", where, allow_empty=True),
                time_utc=_time_field(rec.get("time_utc", ""), where),
                n_epochs=int(_num(rec, "n_epochs", where, default=1.0)),
                spread_h_m=_num(rec, "spread_h_m", where, default=0.0),
                spread_v_m=_num(rec, "spread_v_m", where, default=0.0),
                source=where,
            )
        except GnssError:
            raise
        except ValueError as exc:  # GnssPoint's checks: the message names file, line and log
            raise GnssFormatError(str(exc)) from exc
        points.append(point)
    survey = GnssSurvey(points=tuple(points), source=f"{path} ({crs})")
    return check_survey(survey, allow_float=allow_float, max_distance_m=max_distance_m, area=area,
                        require_both_ends=require_both_ends)


def _read_lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError as exc:
        raise GnssFileError(f"GNSS file {path} does not exist; check the path") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise GnssFileError(f"cannot read GNSS file {path}: {exc}") from exc
    return list(enumerate(text.splitlines(), start=1))


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


def _check_header(path: Path, lineno: int, header: list[str]) -> set[str]:
    cols = set(header)
    where = f"{path}:{lineno}"
    if len(cols) != len(header):
        raise GnssFormatError(f"{where}: repeated column names in header {header}")
    has_geo = any(c in cols for c in _GEO_COLS)
    has_tm = any(c in cols for c in _TM_COLS)
    if has_geo and has_tm:
        raise GnssFormatError(f"{where}: give lat_deg/lon_deg OR easting_m/northing_m, not both")
    if not (has_geo or has_tm):
        raise GnssFormatError(f"{where}: no coordinate columns (lat_deg,lon_deg or easting_m,northing_m)")
    need = set(_REQUIRED) | set(_TM_COLS if has_tm else _GEO_COLS)
    missing = [c for c in need if c not in cols]
    if missing:
        raise GnssFormatError(f"{where}: header lacks column(s) {sorted(missing)}")
    unknown = cols - need - set(_OPTIONAL)
    if unknown:
        raise GnssFormatError(
            f"{where}: unknown column(s) {sorted(unknown)}; allowed: "
            f"{', '.join(sorted(need | set(_OPTIONAL)))}"
        )
    return cols


def _check_crs(path: Path, meta: dict[str, tuple[str, int]], projected: bool) -> str:
    expected = geodesy.EPSG_SWEREF99_TM if projected else geodesy.EPSG_SWEREF99
    if "crs" not in meta:
        return expected
    value, lineno = meta["crs"]
    crs = value.upper().replace(" ", "")
    if crs not in _CRS_ALLOWED:
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


def _parse_time(raw: str, where: str) -> dt.datetime:
    try:
        t = dt.datetime.fromisoformat(raw.strip())
    except ValueError as exc:
        raise GnssFormatError(f"{where}: time {raw!r} is not ISO 8601 (e.g. 2026-05-14T09:30:05Z)") from exc
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.timezone.utc)
    return t.astimezone(dt.timezone.utc)


def _time_field(raw: str, where: str) -> str:
    return _iso(_parse_time(raw, where)) if raw else ""


def _iso(t: dt.datetime) -> str:
    return t.astimezone(dt.timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


# -- CSV writer -----------------------------------------------------------------------------
def write_gnss_csv(survey: GnssSurvey, path: str | Path, crs: str = geodesy.EPSG_SWEREF99) -> Path:
    """Write ``survey`` as a survey CSV (atomically), in SWEREF 99 lat/lon (``EPSG:4619``,
    1e-10 deg ≈ 0.01 mm) or SWEREF 99 TM (``EPSG:3006``, 0.1 mm). Returns the path."""
    if crs not in _CRS_ALLOWED:
        raise ValueError(f"crs must be one of {_CRS_ALLOWED}, got {crs!r}")
    projected = crs == geodesy.EPSG_SWEREF99_TM
    buf = io.StringIO()
    buf.write(f"# format: {GNSS_CSV_FORMAT} {GNSS_CSV_VERSION}\n")
    buf.write(f"# crs: {crs}\n")
    buf.write("# heights: ellipsoidal (GRS80) [m]; accuracies 1 sigma [m]\n")
    w = csv.writer(buf, lineterminator="\n")
    coord_cols = list(_TM_COLS if projected else _GEO_COLS)
    w.writerow(["log_id", "end", *coord_cols, "h_ell_m", "fix", "h_acc_m", "v_acc_m", *_OPTIONAL])
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
    path = Path(path)
    atomic_write_bytes(path, buf.getvalue().encode("utf-8"))
    return path


# -- simulation (the twin) ------------------------------------------------------------------
def pile_endpoints_site(pile: PileSpec) -> list[tuple[np.ndarray, np.ndarray]]:
    """Both end centres of every log of a georeferenced pile, in the site frame [m]:
    ``[(butt, top), ...]`` in log order (end ``a`` = butt)."""
    if pile.georef is None:
        raise GnssError("the pile has no georeference; cannot place its logs on Earth")
    out = []
    for log in pile.logs:
        butt, top = log.endpoints_m()
        site = geodesy.pile_to_site(pile.georef, np.stack([butt, top]))
        out.append((site[0], site[1]))
    return out


def simulate_survey(
    logs_endpoints_site: Sequence[tuple[Any, Any]] | Mapping[str, tuple[Any, Any]],
    georef: Any,
    rng: np.random.Generator,
    sigma_h_m: float = 0.015,
    sigma_v_m: float = 0.025,
    n_float: int = 0,
    float_sigma_h_m: float = 0.25,
    float_sigma_v_m: float = 0.40,
    t0_utc: str = "2026-05-14T09:00:00Z",
    seconds_per_point: float = 20.0,
    omit: Sequence[str] = (),
) -> GnssSurvey:
    """A survey as an RTK rover would measure the given log ends.

    ``logs_endpoints_site``: ``[(end_a, end_b), ...]`` (ids ``log0``, ``log1``...) or
    ``{log_id: (end_a, end_b)}``, site ENU [m]; ``georef`` gives the site origin. Fixed points get
    Gaussian noise with horizontal RMS ``sigma_h_m`` (``sigma_h_m/√2`` per axis) and vertical
    ``sigma_v_m``; ``n_float`` randomly chosen points are RTK float with the ``float_sigma_*``
    noise (pass ``n_float > 0`` to exercise the float path; the default survey is all fixed so
    that it passes :func:`check_survey` as is). Reported accuracies are the sigmas scaled by a
    random 0.8–1.25 (receivers' estimates are themselves approximate). Times start at ``t0_utc``.
    ``omit``: ids of logs left out of the survey (their points are drawn, then dropped, so the other
    points are the same as without it; ``n_float`` counts the points kept).
    """
    if not (sigma_h_m >= 0 and sigma_v_m >= 0 and float_sigma_h_m >= 0 and float_sigma_v_m >= 0):
        raise ValueError("noise sigmas must be >= 0 m")
    if isinstance(logs_endpoints_site, Mapping):
        items = [(str(k), v) for k, v in logs_endpoints_site.items()]
    else:
        items = [(f"log{i}", v) for i, v in enumerate(logs_endpoints_site)]
    n_pts = 2 * len(items)
    unknown = set(omit) - {k for k, _ in items}
    if unknown:
        raise ValueError(f"omit names logs that are not there: {sorted(unknown)}")
    kept = np.array([items[k // 2][0] not in set(omit) for k in range(n_pts)])
    if not 0 <= n_float <= int(kept.sum()):
        raise ValueError(f"n_float must be in [0, {int(kept.sum())}] (the number of log ends surveyed), got {n_float}")
    truth = np.array([[np.asarray(a, float), np.asarray(b, float)] for _, (a, b) in items]).reshape(-1, 3)
    is_float = np.zeros(n_pts, bool)
    is_float[np.flatnonzero(kept)[rng.choice(int(kept.sum()), size=n_float, replace=False)]] = True
    sh = np.where(is_float, float_sigma_h_m, sigma_h_m)
    sv = np.where(is_float, float_sigma_v_m, sigma_v_m)
    noise = rng.standard_normal((n_pts, 3)) * np.stack([sh / math.sqrt(2), sh / math.sqrt(2), sv], axis=1)
    lat, lon, h = geodesy.site_to_geodetic(georef, truth + noise)
    t0 = _parse_time(t0_utc, "t0_utc")
    acc = rng.uniform(0.8, 1.25, size=(n_pts, 2))  # the same stream as one draw per value, point by point
    points = []
    for k in range(n_pts):
        log_id = items[k // 2][0]
        if not kept[k]:
            continue
        points.append(GnssPoint(
            log_id=log_id, end=ENDS[k % 2], lat_deg=float(lat[k]), lon_deg=float(lon[k]),
            h_ell_m=float(h[k]), fix="rtk_float" if is_float[k] else "rtk_fixed",
            h_acc_m=float(sh[k] * acc[k, 0]), v_acc_m=float(sv[k] * acc[k, 1]),
            time_utc=_iso(t0 + dt.timedelta(seconds=k * seconds_per_point)),
            source=f"simulated point {k}",
        ))
    return GnssSurvey(points=tuple(points), source="simulated survey")


# -- raw receiver logs ----------------------------------------------------------------------
@dataclass(frozen=True)
class Epoch:
    """One receiver solution."""

    t_utc: dt.datetime
    lat_deg: float
    lon_deg: float
    h_ell_m: float
    fix: str
    h_acc_m: float = math.nan
    v_acc_m: float = math.nan
    source: str = ""


@dataclass(frozen=True)
class TimeWindow:
    """One row of the time-window sidecar."""

    log_id: str
    end: str
    t_start: dt.datetime
    t_end: dt.datetime
    source: str = ""


@dataclass
class _RawLog:
    epochs: list[Epoch] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def read_nmea_epochs(path: str | Path, date_utc: dt.date | None = None) -> tuple[list[Epoch], list[str]]:
    """Epochs (GGA with RMC date and GST accuracies) of an NMEA log, and warnings."""
    import pynmea2

    path = Path(path)
    lines = _read_lines(path)
    gga: list[tuple[int, Any, dt.date | None]] = []
    gst: dict[dt.time, tuple[float, float]] = {}
    warnings: list[str] = []
    bad = 0
    date = date_utc
    first_date: dt.date | None = None
    for lineno, line in lines:
        s = line.strip()
        if not s.startswith("$"):
            continue
        try:
            msg = pynmea2.parse(s, check=True)
        except pynmea2.ParseError:
            bad += 1
            continue
        kind = getattr(msg, "sentence_type", "")
        if kind == "RMC" and msg.datestamp is not None:
            date = msg.datestamp
            first_date = first_date or date
        elif kind == "GST" and msg.timestamp is not None:
            try:
                hs = math.hypot(float(msg.std_dev_latitude), float(msg.std_dev_longitude))
                vs = float(msg.std_dev_altitude)
                gst[msg.timestamp] = (hs, vs)
            except (TypeError, ValueError):
                pass
        elif kind == "GGA":
            gga.append((lineno, msg, date))
    if bad:
        warnings.append(f"{path}: {bad} NMEA sentence(s) failed to parse or their checksum; skipped")
    epochs = []
    for lineno, msg, d in gga:
        where = f"{path}:{lineno}"
        d = d or first_date  # GGA before the first RMC of the log: that RMC's date
        if msg.timestamp is None:
            continue
        quality = _int_or(msg.gps_qual, 0)
        fix = _GGA_QUALITY.get(quality, "none")
        if d is not None:
            t = dt.datetime.combine(d, msg.timestamp)
            t = t.replace(tzinfo=dt.timezone.utc) if t.tzinfo is None else t.astimezone(dt.timezone.utc)
        if fix == "none" or not msg.lat:
            if d is not None:  # a no-fix epoch still counts against its time window
                epochs.append(Epoch(t, math.nan, math.nan, math.nan, "none", source=where))
            continue
        if d is None:
            raise GnssFormatError(
                f"{where}: the NMEA log has no date (no RMC sentence before this GGA); pass "
                "date_utc= or enable RMC output on the receiver"
            )
        try:
            h_ell = float(msg.altitude) + float(msg.geo_sep)
        except (TypeError, ValueError) as exc:
            raise GnssFormatError(f"{where}: GGA without altitude/geoid separation: {msg}") from exc
        hs, vs = gst.get(msg.timestamp, (math.nan, math.nan))
        epochs.append(Epoch(t, float(msg.latitude), float(msg.longitude), h_ell, fix, hs, vs, where))
    return epochs, warnings


def read_ubx_epochs(path: str | Path) -> tuple[list[Epoch], list[str]]:
    """Epochs of a u-blox log: NAV-PVT (time, fix) joined on ``iTOW`` with NAV-HPPOSLLH
    (high-precision position and accuracies) when present."""
    from pyubx2 import ERR_RAISE, UBX_PROTOCOL, UBXReader
    from pyubx2.exceptions import UBXParseError, UBXStreamError

    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError as exc:
        raise GnssFileError(f"UBX log {path} does not exist; check the path") from exc
    except OSError as exc:
        raise GnssFileError(f"cannot read UBX log {path}: {exc}") from exc
    pvt: dict[int, Any] = {}
    hp: dict[int, Any] = {}
    order: list[int] = []
    reader = UBXReader(io.BytesIO(data), protfilter=UBX_PROTOCOL, quitonerror=ERR_RAISE)
    n = 0
    try:
        for _raw, msg in reader:
            n += 1
            ident = getattr(msg, "identity", "")
            if ident == "NAV-PVT":
                pvt[msg.iTOW] = msg
                order.append(msg.iTOW)
            elif ident == "NAV-HPPOSLLH" and not getattr(msg, "invalidLlh", 0):
                hp[msg.iTOW] = msg
    except (UBXParseError, UBXStreamError) as exc:
        raise GnssFormatError(f"{path}: corrupt UBX data after message {n}: {exc}") from exc
    warnings = []
    lone_hp = set(hp) - set(pvt)
    if lone_hp:
        warnings.append(f"{path}: {len(lone_hp)} NAV-HPPOSLLH epoch(s) without NAV-PVT (no time/fix); skipped")
    epochs = []
    for k, itow in enumerate(order):
        m = pvt[itow]
        where = f"{path}: NAV-PVT #{k} (iTOW {itow} ms)"
        if not (m.validDate and m.validTime):
            warnings.append(f"{where}: no valid date/time; skipped")
            continue
        t = dt.datetime(m.year, m.month, m.day, m.hour, m.min, m.second, tzinfo=dt.timezone.utc)
        t += dt.timedelta(microseconds=int(m.nano) // 1000)
        if m.carrSoln == 2:
            fix = "rtk_fixed"
        elif m.carrSoln == 1:
            fix = "rtk_float"
        elif m.fixType in (3, 4) and m.gnssFixOk:
            fix = "dgnss" if m.diffSoln else "single"
        else:
            fix = "none"
        src = hp.get(itow, m)
        epochs.append(Epoch(
            t, float(src.lat), float(src.lon), float(src.height) / 1000.0, fix,
            float(src.hAcc) / 1000.0, float(src.vAcc) / 1000.0, where,
        ))
    return epochs, warnings


def read_time_windows(path: str | Path) -> list[TimeWindow]:
    """Read the time-window sidecar ``log_id,end,t_start_utc,t_end_utc``."""
    path = Path(path)
    header = None
    windows = []
    for lineno, line in _read_lines(path):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        fields = [f.strip() for f in next(csv.reader([line]))]
        where = f"{path}:{lineno}"
        if header is None:
            header = fields
            if header != ["log_id", "end", "t_start_utc", "t_end_utc"]:
                raise GnssFormatError(f"{where}: header must be log_id,end,t_start_utc,t_end_utc, got {line!r}")
            continue
        if len(fields) != 4:
            raise GnssFormatError(f"{where}: expected 4 fields (log_id,end,t_start_utc,t_end_utc), got {len(fields)}")
        log_id, end, t0, t1 = fields
        if not log_id:
            raise GnssFormatError(f"{where}: empty log_id")
        if end.lower() not in ENDS:
            raise GnssFormatError(f"{where} (log {log_id!r}): end must be 'a' or 'b', got {end!r}")
        a, b = _parse_time(t0, where), _parse_time(t1, where)
        if not b > a:
            raise GnssFormatError(f"{where} (log {log_id!r}): t_end_utc must be after t_start_utc")
        windows.append(TimeWindow(log_id, end.lower(), a, b, where))
    if header is None:
        raise GnssFormatError(f"{path}: empty time-window file")
    return windows


def read_raw_gnss(
    log_paths: str | Path | Iterable[str | Path],
    windows_path: str | Path,
    *,
    date_utc: dt.date | None = None,
    allow_float: bool = False,
    max_distance_m: float = 50.0,
    area: Any = None,
    min_epochs: int = 1,
) -> GnssSurvey:
    """Average raw receiver epochs (NMEA ``.nmea``/``.txt``/``.log`` or UBX ``.ubx``) over the
    operator's time windows into a checked survey. See the module docstring."""
    if isinstance(log_paths, (str, Path)):
        log_paths = [log_paths]
    epochs: list[Epoch] = []
    warnings: list[str] = []
    for p in map(Path, log_paths):
        suffix = p.suffix.lower()
        if suffix == ".ubx":
            e, w = read_ubx_epochs(p)
        elif suffix in (".nmea", ".txt", ".log"):
            e, w = read_nmea_epochs(p, date_utc)
        else:
            raise GnssFormatError(f"{p}: unknown raw log type {suffix!r}; use .ubx or .nmea/.txt/.log")
        epochs += e
        warnings += w
    windows = read_time_windows(windows_path)
    rank = {f: i for i, f in enumerate(FIXES)}
    points = []
    for w in windows:
        inside = [e for e in epochs if w.t_start <= e.t_utc <= w.t_end]
        if len(inside) < min_epochs:
            raise GnssQualityError(
                f"{w.source} (log {w.log_id!r} end {w.end!r}): {len(inside)} receiver epoch(s) between "
                f"{_iso(w.t_start)} and {_iso(w.t_end)}, need {min_epochs}; check the window times "
                "(UTC!) against the log"
            )
        worst = max(inside, key=lambda e: rank[e.fix]).fix
        if worst == "none":
            n_none = sum(e.fix == "none" for e in inside)
            raise GnssQualityError(
                f"{w.source} (log {w.log_id!r} end {w.end!r}): {n_none} of {len(inside)} epochs have "
                "no position fix; re-measure this end"
            )
        lat = np.array([e.lat_deg for e in inside])
        lon = np.array([e.lon_deg for e in inside])
        h = np.array([e.h_ell_m for e in inside])
        mean = (float(lat.mean()), float(lon.mean()), float(h.mean()))
        if len(inside) > 1:
            enu = geodesy.geodetic_to_site(mean, lat, lon, h, check=False)
            spread_h = float(np.sqrt(np.mean(enu[:, 0] ** 2 + enu[:, 1] ** 2)))
            spread_v = float(np.sqrt(np.mean(enu[:, 2] ** 2)))
        else:
            spread_h = spread_v = 0.0
        h_acc = [e.h_acc_m for e in inside if not math.isnan(e.h_acc_m)]
        v_acc = [e.v_acc_m for e in inside if not math.isnan(e.v_acc_m)]
        try:
            points.append(GnssPoint(
                log_id=w.log_id, end=w.end, lat_deg=mean[0], lon_deg=mean[1], h_ell_m=mean[2],
                fix=worst, h_acc_m=statistics.median(h_acc) if h_acc else math.nan,
                v_acc_m=statistics.median(v_acc) if v_acc else math.nan,
                time_utc=_iso(inside[len(inside) // 2].t_utc), n_epochs=len(inside),
                spread_h_m=spread_h, spread_v_m=spread_v, source=w.source,
            ))
        except ValueError as exc:
            raise GnssFormatError(f"{w.source}: {exc}") from exc
    names = ", ".join(str(p) for p in log_paths)
    survey = GnssSurvey(points=tuple(points), source=f"{names} + {windows_path}", warnings=tuple(warnings))
    return check_survey(survey, allow_float=allow_float, max_distance_m=max_distance_m, area=area)


def read_gnss(path: str | Path, **kwargs: Any) -> GnssSurvey:
    """Read a survey CSV (``.csv``) — a convenience for the CLI; raw logs need
    :func:`read_raw_gnss` and their time-window file."""
    path = Path(path)
    if path.suffix.lower() != ".csv":
        raise GnssFormatError(
            f"{path}: not a survey CSV; raw receiver logs need a time-window file (read_raw_gnss)"
        )
    return read_gnss_csv(path, **kwargs)


def _int_or(v: Any, default: int) -> int:
    try:
        return int(v)
    except (TypeError, ValueError):
        return default
