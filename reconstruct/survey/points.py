"""The survey's data model: measured log end points (:class:`GnssPoint`), a survey
(:class:`GnssSurvey`) and its checks (:func:`check_survey`), with the time and file helpers every
reader shares. The formats are described in :mod:`reconstruct.survey.gnss`."""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from reconstruct.errors import GnssFileError, GnssFormatError, GnssOutlierError, GnssQualityError
from synth.geometry import geodesy
from synth.scene.pile import Georeference

FIXES = ("rtk_fixed", "rtk_float", "dgnss", "single", "none")  # best to worst
ENDS = ("a", "b")


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


def read_lines(path: Path) -> list[tuple[int, str]]:
    """``(line number, line)`` of a UTF-8 text file (a BOM is dropped); :class:`GnssFileError`
    when it is missing, unreadable or not text."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError as exc:
        raise GnssFileError(f"GNSS file {path} does not exist; check the path") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise GnssFileError(f"cannot read GNSS file {path}: {exc}") from exc
    return list(enumerate(text.splitlines(), start=1))


def parse_time(raw: str, where: str) -> dt.datetime:
    """An ISO 8601 time as an aware UTC datetime (a time without a zone is UTC)."""
    try:
        t = dt.datetime.fromisoformat(raw.strip())
    except ValueError as exc:
        raise GnssFormatError(f"{where}: time {raw!r} is not ISO 8601 (e.g. 2026-05-14T09:30:05Z)") from exc
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.timezone.utc)
    return t.astimezone(dt.timezone.utc)


def time_field(raw: str, where: str) -> str:
    return iso_utc(parse_time(raw, where)) if raw else ""


def iso_utc(t: dt.datetime) -> str:
    """``2026-05-14T09:30:05.000Z``."""
    return t.astimezone(dt.timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")
