"""NMEA sentences of a receiver stream -> epochs: GGA or GNS (position, fix), GST (accuracies),
RMC or ZDA (the date); other sentences counted and skipped. See :mod:`reconstruct.survey.stream`."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path
from typing import Any

from reconstruct.errors import GnssFormatError
from reconstruct.survey.stream import GGA_QUALITY, GNS_MODE, Epoch, ReceiverLog

_DATED = ("RMC", "ZDA")
_POSITION = ("GGA", "GNS")


class NmeaEpochs:
    """Collects a stream's NMEA sentences (:meth:`add`) and makes its epochs (:meth:`epochs`)."""

    def __init__(self, path: Path, log: ReceiverLog) -> None:
        self.path, self.log = path, log
        self.positions: list[tuple[int, Any, dt.date | None]] = []  # (line, GGA/GNS, the date then)
        self.gst: dict[dt.time, tuple[float, float]] = {}
        self.date: dt.date | None = None
        self.first_date: dt.date | None = None
        self.bad = 0

    def add(self, sentence: str, line: int) -> None:
        """One framed sentence (``$...*hh``) on line ``line`` of the file."""
        import pynmea2

        try:
            msg = pynmea2.parse(sentence, check=True)
        except pynmea2.ParseError:
            self.bad += 1
            self.log.skipped["NMEA bad checksum or syntax"] += 1
            return
        kind = getattr(msg, "sentence_type", "") or "proprietary"
        if kind in _DATED:
            self._date(msg, kind)
        elif kind == "GST" and msg.timestamp is not None:
            try:
                self.gst[msg.timestamp] = (math.hypot(float(msg.std_dev_latitude), float(msg.std_dev_longitude)),
                                           float(msg.std_dev_altitude))
            except (TypeError, ValueError):
                pass
        elif kind in _POSITION:
            self.positions.append((line, msg, self.date))
        else:
            self.log.skipped[f"NMEA {kind}"] += 1
            return
        self.log.used[f"NMEA {kind}"] += 1

    def _date(self, msg: Any, kind: str) -> None:
        try:
            d = msg.datestamp if kind == "RMC" else dt.date(int(msg.year), int(msg.month), int(msg.day))
        except (TypeError, ValueError, AttributeError):
            d = None
        if d is not None:
            self.date = d
            self.first_date = self.first_date or d

    def epochs(self, date_utc: dt.date | None) -> list[Epoch]:
        """The position sentences as epochs (a GNS at the time of a GGA is dropped); a no-fix
        sentence is a no-fix epoch, which still counts against its time window. ``date_utc``:
        the date when the stream gives none."""
        if self.bad:
            self.log.warnings.append(f"{self.path}: {self.bad} NMEA sentence(s) failed to parse or their checksum; "
                                     "skipped")
        gga_times = {m.timestamp for _, m, _ in self.positions if m.sentence_type == "GGA"}
        out = []
        for line, msg, d in self.positions:
            if msg.timestamp is None or (msg.sentence_type == "GNS" and msg.timestamp in gga_times):
                continue
            epoch = self._epoch(f"{self.path}:{line}", msg, d or self.first_date or date_utc)
            if epoch is not None:
                out.append(epoch)
        return out

    def _epoch(self, where: str, msg: Any, d: dt.date | None) -> Epoch | None:
        fix = _fix(msg)
        if d is None:
            if fix == "none":
                return None
            raise GnssFormatError(f"{where}: the NMEA log has no date (no RMC or ZDA sentence); pass the date "
                                  "(--date YYYY-MM-DD) or enable RMC output on the receiver")
        t = dt.datetime.combine(d, msg.timestamp)
        t = t.replace(tzinfo=dt.timezone.utc) if t.tzinfo is None else t.astimezone(dt.timezone.utc)
        if fix == "none" or not msg.lat:
            return Epoch(t, math.nan, math.nan, math.nan, "none", source=where)
        try:
            h_ell = float(msg.altitude) + float(msg.geo_sep)
        except (TypeError, ValueError) as exc:
            raise GnssFormatError(f"{where}: {msg.sentence_type} without altitude/geoid separation: {msg}") from exc
        hs, vs = self.gst.get(msg.timestamp, (math.nan, math.nan))
        return Epoch(t, float(msg.latitude), float(msg.longitude), h_ell, fix, hs, vs, where)


def _fix(msg: Any) -> str:
    if msg.sentence_type == "GGA":
        try:
            return GGA_QUALITY.get(int(msg.gps_qual), "none")
        except (TypeError, ValueError):
            return "none"
    mode = str(msg.mode_indicator or "").upper()
    return next((fix for letter, fix in GNS_MODE if letter in mode), "none")
