"""RTK GNSS surveys of log end points: reading, checking, simulating and writing them.

An operator walks the pile with an RTK rover and measures both end centres of each log. The
result arrives in one of two shapes:

1. **A survey CSV** (what a controller app exports, and what :func:`write_gnss_csv` writes).
2. **Raw receiver logs** (u-blox UBX, NMEA, or both mixed with RTCM3 and configuration traffic, as
   a serial logger or u-center records them) plus a **time-window sidecar** saying which log end
   the rover stood on when.

This module is the package's front door: it re-exports the parts, which live by concern in
:mod:`~reconstruct.survey.points` (data model, checks), :mod:`~reconstruct.survey.survey_csv`
(the CSV reader, field-app exports, writer), :mod:`~reconstruct.survey.stream` (raw stream
framing; :mod:`~reconstruct.survey.ubx`, :mod:`~reconstruct.survey.nmea`) and
:mod:`~reconstruct.survey.windows` (time windows, averaging); the twin's simulated surveys are here.

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
Read by :func:`read_raw_gnss` / :func:`survey_from_logs` (``loggrasp survey``): every file is framed
as a byte stream whatever its suffix (:mod:`reconstruct.survey.stream`: UBX NAV-PVT joined with
NAV-HPPOSLLH, or NAV-HPPOSLLH alone; NMEA GGA/GNS with GST accuracies and RMC/ZDA dates; RTCM3,
polls, ACKs and unknown messages skipped and counted). A file that is not a receiver log, or holds
no position epoch, is refused.

Time-window sidecar (``loggrasp.gnss-windows``): a CSV with header
``log_id,end,t_start_utc,t_end_utc`` (ISO 8601 times, UTC; "#" comments allowed); see
:mod:`reconstruct.survey.windows`. Every epoch in ``[t_start, t_end]`` is averaged into that log
end; the point's ``fix`` is the WORST fix among those epochs, its accuracy the median of theirs,
and the scatter is reported as ``spread_h_m``/``spread_v_m``.

Field-app exports (``;`` separators with decimal commas, other column names mapped by a
:class:`ColumnMap`) are read too: :mod:`reconstruct.survey.survey_csv`.

Checks (all readers, :func:`check_survey`): every point lies in Sweden (swapped lat/lon is named
as such), every log has exactly one ``a`` and one ``b`` end, only ``rtk_fixed`` points unless
``allow_float=True`` (which admits ``rtk_float``; ``dgnss``/``single``/``none`` are never
accepted: metre-level positions are useless for logs), and no point lies more than
``max_distance_m`` (default 50 m) horizontally from the median of all points or, when ``area`` is
given, from the scanned area's origin. Errors name the file, the line and the log id.

The site frame and heights follow :mod:`synth.geometry.geodesy` (ellipsoidal heights, ENU at an origin).
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from reconstruct.errors import GnssError, GnssFormatError
from reconstruct.survey.points import (ENDS, FIXES, GnssPoint, GnssSurvey, check_survey, iso_utc, parse_time,
                                       read_lines)
from reconstruct.survey.stream import Epoch, ReceiverLog, StreamConfig, read_receiver_log
from reconstruct.survey.survey_csv import (GNSS_CSV_FORMAT, GNSS_CSV_VERSION, ColumnMap, column_map, parse_columns,
                                           read_column_map, read_gnss_csv, survey_csv_bytes, write_gnss_csv)
from reconstruct.survey.windows import (RawGnss, RawSurvey, TimeWindow, read_raw_gnss, read_time_windows,
                                        survey_from_logs)
from synth.geometry import geodesy
from synth.scene.pile import PileSpec

__all__ = ["ENDS", "FIXES", "GNSS_CSV_FORMAT", "GNSS_CSV_VERSION", "ColumnMap", "Epoch", "GnssPoint", "GnssSurvey",
           "RawGnss", "RawSurvey", "ReceiverLog", "StreamConfig", "TimeWindow", "check_survey", "column_map",
           "parse_columns", "pile_endpoints_site", "read_column_map", "read_gnss", "read_gnss_csv", "read_lines",
           "read_nmea_epochs", "read_raw_gnss", "read_receiver_log", "read_time_windows", "read_ubx_epochs",
           "simulate_survey", "survey_csv_bytes", "survey_from_logs", "write_gnss_csv"]


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
    t0 = parse_time(t0_utc, "t0_utc")
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
            time_utc=iso_utc(t0 + dt.timedelta(seconds=k * seconds_per_point)),
            source=f"simulated point {k}",
        ))
    return GnssSurvey(points=tuple(points), source="simulated survey")


def read_nmea_epochs(path: str | Path, date_utc: dt.date | None = None) -> tuple[list[Epoch], list[str]]:
    """Epochs and warnings of one raw log (NMEA, or any stream :func:`read_receiver_log` reads)."""
    log = read_receiver_log(path, date_utc)
    return log.epochs, log.warnings


def read_ubx_epochs(path: str | Path) -> tuple[list[Epoch], list[str]]:
    """Epochs and warnings of one raw log (UBX, or any stream :func:`read_receiver_log` reads)."""
    log = read_receiver_log(path)
    return log.epochs, log.warnings


def read_gnss(source: str | Path | RawGnss, **kwargs: Any) -> GnssSurvey:
    """A checked survey from a survey CSV (:func:`read_gnss_csv`) or from raw logs and their time
    windows (a :class:`RawGnss`, :func:`read_raw_gnss`); ``kwargs`` are the checks' options."""
    if isinstance(source, RawGnss):
        return read_raw_gnss(source.logs, source.windows, date_utc=source.date_utc, **kwargs)
    path = Path(source)
    if path.suffix.lower() != ".csv":
        raise GnssFormatError(
            f"{path}: not a survey CSV; raw receiver logs need their time-window file (--gnss-windows FILE)"
        )
    return read_gnss_csv(path, **kwargs)
