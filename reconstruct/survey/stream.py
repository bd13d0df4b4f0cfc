"""Raw receiver streams read as they come: one file's u-blox UBX, NMEA and RTCM3 traffic, in any
mix, framed here and turned into receiver epochs (:class:`Epoch`).

A receiver log is a byte stream: what a serial logger or u-center records holds the receiver's
UBX navigation messages, its NMEA sentences, the RTCM3 corrections passing through and the
configuration traffic (polls, ACKs, messages of classes no library knows). The framing is done
here (UBX: sync ``B5 62`` and its Fletcher checksum; RTCM3: preamble ``D3`` and its CRC-24Q;
NMEA: ``$...*hh``), so nothing in the stream can stop the reading; only the messages used are
decoded (UBX NAV-PVT / NAV-HPPOSLLH with pyubx2, NMEA with pynmea2). Everything else is skipped
and counted (:attr:`ReceiverLog.skipped`).

* **UBX**: NAV-PVT gives time, fix (``carrSoln`` 2 = RTK fixed, 1 = float) and a position;
  NAV-HPPOSLLH with the same ``iTOW`` replaces the position with its high-precision one and gives
  ``hAcc``/``vAcc``. NAV-HPPOSLLH *without* a NAV-PVT is used with its own time (``iTOW``, GPS
  time of week, placed in the week of the stream's other times or of ``time_hint``); its fix is
  the NMEA fix of the same second when the stream has one, else judged from ``hAcc``
  (:class:`StreamConfig`), with a warning.
* **NMEA**: GGA and GNS give position and fix (GGA quality 4 = RTK fixed, 5 = float, 2 = DGNSS,
  1 = single; GNS mode letters R, F, D, A), the ellipsoidal height is ``altitude + geoid
  separation``; GST of the same time stamp gives the accuracies; RMC or ZDA the date (else the
  date of the stream's UBX epochs, else ``date_utc``). Where UBX and NMEA give the same epoch, UBX
  is used.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from reconstruct.errors import GnssFileError, GnssFormatError
from reconstruct.survey.points import iso_utc

GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.timezone.utc)
GPS_UTC_LEAP_S = 18  # GPS time - UTC [s], unchanged since 2017-01-01
WEEK_S = 604800  # [s]
MIN_FRAMED_FRACTION = 0.5  # a receiver log: at least this share of its bytes is UBX, NMEA or RTCM3 [-]

GGA_QUALITY = {4: "rtk_fixed", 5: "rtk_float", 2: "dgnss", 1: "single", 0: "none"}
GNS_MODE = (("R", "rtk_fixed"), ("F", "rtk_float"), ("D", "dgnss"), ("P", "dgnss"), ("A", "single"))

_CANDIDATE = re.compile(rb"\xb5\x62|\xd3|\$")
_NMEA = re.compile(rb"\$[A-Z][A-Z0-9]{2,9},[\x20-\x7e]*?\*[0-9A-Fa-f]{2}")


@dataclass(frozen=True)
class StreamConfig:
    """How to judge the fix of a NAV-HPPOSLLH epoch that has no NAV-PVT (nor an NMEA fix) beside it."""

    lone_hp_fixed_max_h_acc_m: float = 0.03  # hAcc at or under this: taken as RTK fixed [m]
    lone_hp_float_max_h_acc_m: float = 0.5  # hAcc at or under this: RTK float; over it: single [m]

    def __post_init__(self) -> None:
        if not 0 < self.lone_hp_fixed_max_h_acc_m <= self.lone_hp_float_max_h_acc_m:
            raise ValueError("need 0 < lone_hp_fixed_max_h_acc_m <= lone_hp_float_max_h_acc_m")


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


@dataclass
class ReceiverLog:
    """One raw log, read: its epochs (time order), what was used and skipped, and warnings."""

    path: Path
    n_bytes: int = 0
    epochs: list[Epoch] = field(default_factory=list)
    used: Counter = field(default_factory=Counter)  # message kind -> count, e.g. "UBX NAV-PVT"
    skipped: Counter = field(default_factory=Counter)  # e.g. "UBX ACK-ACK", "RTCM3 1077", "NMEA GSV"
    junk_bytes: int = 0
    warnings: list[str] = field(default_factory=list)

    def span(self) -> tuple[dt.datetime, dt.datetime] | None:
        """First and last epoch time, or None."""
        return (self.epochs[0].t_utc, self.epochs[-1].t_utc) if self.epochs else None

    def summary(self) -> dict[str, Any]:
        """What was read, as JSON-ready numbers."""
        span = self.span()
        return {"path": str(self.path), "bytes": self.n_bytes, "epochs": len(self.epochs),
                "first_utc": iso_utc(span[0]) if span else None, "last_utc": iso_utc(span[1]) if span else None,
                "used": dict(sorted(self.used.items())), "skipped": dict(sorted(self.skipped.items())),
                "junk_bytes": self.junk_bytes}

    def describe(self) -> str:
        """One line: epochs, span, used and skipped messages."""
        span = self.span()
        when = f" {iso_utc(span[0])} to {iso_utc(span[1])}" if span else ""
        used = ", ".join(f"{n} {k}" for k, n in sorted(self.used.items()))
        kinds: Counter = Counter()
        for k, n in self.skipped.items():
            kinds[k.split()[0]] += n
        skipped = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items()))
        return (f"{self.path}: {len(self.epochs)} epochs{when} ({used or 'nothing used'})"
                + (f"; skipped {skipped}" if skipped else "")
                + (f"; {self.junk_bytes} bytes not in any frame" if self.junk_bytes else ""))


# -- framing --------------------------------------------------------------------------------
def _crc24q_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        c = i << 16
        for _ in range(8):
            c <<= 1
            if c & 0x1000000:
                c ^= 0x1864CFB
        table.append(c & 0xFFFFFF)
    return tuple(table)


_CRC24Q = _crc24q_table()


def crc24q(data: bytes) -> int:
    """RTCM3's CRC-24Q of ``data``."""
    crc = 0
    for b in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ _CRC24Q[(crc >> 16) ^ b]
    return crc


def ubx_checksum(body: bytes) -> bytes:
    """UBX's 8-bit Fletcher checksum of class, id, length and payload."""
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


def _frame_at(data: bytes, i: int) -> tuple[str, int] | None:
    """(kind, end) of a valid frame starting at ``i``, or None."""
    n = len(data)
    if data[i] == 0xB5 and i + 8 <= n and data[i + 1] == 0x62:
        end = i + 8 + int.from_bytes(data[i + 4:i + 6], "little")
        if end <= n and ubx_checksum(data[i + 2:end - 2]) == data[end - 2:end]:
            return "ubx", end
    elif data[i] == 0xD3 and i + 6 <= n and not data[i + 1] & 0xFC:
        end = i + 6 + (((data[i + 1] & 0x03) << 8) | data[i + 2])
        if end <= n and crc24q(data[i:end - 3]) == int.from_bytes(data[end - 3:end], "big"):
            return "rtcm3", end
    elif data[i] == 0x24:
        m = _NMEA.match(data, i)
        if m:
            return "nmea", m.end()
    return None


def frames(data: bytes) -> Iterator[tuple[str, int, bytes]]:
    """``(kind, offset, bytes)`` of every UBX, RTCM3 and NMEA frame in ``data``, in order; bytes
    between frames come as ``("junk", offset, bytes)`` (line ends between NMEA sentences are not
    junk and are not reported)."""
    i, n, junk_from = 0, len(data), 0
    while i < n:
        found = _frame_at(data, i)
        if found is None:
            m = _CANDIDATE.search(data, i + 1)
            i = m.start() if m else n
            continue
        kind, end = found
        gap = data[junk_from:i].strip(b"\r\n")
        if gap:
            yield "junk", junk_from, gap
        yield kind, i, data[i:end]
        i = junk_from = end
    gap = data[junk_from:].strip(b"\r\n")
    if gap:
        yield "junk", junk_from, gap


# -- reading --------------------------------------------------------------------------------
def read_receiver_log(path: str | Path, date_utc: dt.date | None = None, time_hint: dt.datetime | None = None,
                      config: StreamConfig = StreamConfig()) -> ReceiverLog:
    """Read one raw receiver log (see the module docstring). ``date_utc``: the date of NMEA epochs
    when the stream says none; ``time_hint``: a time near the log (the first time window), to place
    lone NAV-HPPOSLLH epochs in their GPS week when the stream has no dated epoch.

    Raises :class:`GnssFileError` (missing or unreadable) or :class:`GnssFormatError` (not a
    receiver log, or one without position epochs)."""
    from reconstruct.survey.nmea import NmeaEpochs
    from reconstruct.survey.ubx import UbxEpochs

    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError as exc:
        raise GnssFileError(f"receiver log {path} does not exist; check the path") from exc
    except OSError as exc:
        raise GnssFileError(f"cannot read receiver log {path}: {exc}") from exc
    log = ReceiverLog(path=path, n_bytes=len(data))
    ubx, nmea = UbxEpochs(path, log), NmeaEpochs(path, log)
    line, line_at = 1, 0
    for kind, offset, raw in frames(data):
        if kind == "junk":
            log.junk_bytes += len(raw)
        elif kind == "rtcm3":
            log.skipped[f"RTCM3 {(raw[3] << 4) | (raw[4] >> 4) if len(raw) > 7 else '?'}"] += 1
        elif kind == "ubx":
            ubx.add(raw, offset)
        else:
            line += data.count(b"\n", line_at, offset)
            line_at = offset
            nmea.add(raw.decode("ascii"), line)
    _check_receiver_log(log, data)
    nmea_epochs = nmea.epochs(date_utc or ubx.first_date())
    ubx_epochs = ubx.epochs(time_hint or (nmea_epochs[0].t_utc if nmea_epochs else None)
                            or (dt.datetime.combine(date_utc, dt.time(12), dt.timezone.utc) if date_utc else None),
                            nmea_epochs, config)
    log.epochs = merge_epochs(ubx_epochs, nmea_epochs, log)
    if not log.epochs:
        raise GnssFormatError(f"{path}: no position epochs in the log ({log.describe().split(': ', 1)[1]}); "
                              "enable NAV-PVT (and NAV-HPPOSLLH) or GGA output on the receiver")
    return log


def _check_receiver_log(log: ReceiverLog, data: bytes) -> None:
    if not data:
        raise GnssFormatError(f"{log.path} is empty; give the rover's receiver log (.ubx or NMEA)")
    framed = log.n_bytes - log.junk_bytes
    if not (log.used or log.skipped) or framed < MIN_FRAMED_FRACTION * log.n_bytes:
        raise GnssFormatError(
            f"{log.path} is not a receiver log: {100.0 * framed / log.n_bytes:.0f} % of its {log.n_bytes} bytes "
            "are UBX, NMEA or RTCM3 frames; give the rover's raw log (u-blox .ubx, NMEA text)")


def merge_epochs(ubx: list[Epoch], nmea: list[Epoch], log: ReceiverLog) -> list[Epoch]:
    """UBX epochs, and the NMEA epochs at times UBX does not cover (10 ms), in time order."""
    covered = {round(e.t_utc.timestamp(), 2) for e in ubx}
    extra = [e for e in nmea if round(e.t_utc.timestamp(), 2) not in covered]
    if len(extra) < len(nmea):
        log.warnings.append(f"{log.path}: {len(nmea) - len(extra)} NMEA epoch(s) repeat UBX epochs; the UBX ones used")
    return sorted([*ubx, *extra], key=lambda e: e.t_utc)


def gps_tow_to_utc(itow_ms: int, near: dt.datetime) -> dt.datetime:
    """The UTC time of GPS time of week ``itow_ms`` [ms] in the GPS week that puts it nearest ``near``."""
    gps_s = (near - GPS_EPOCH).total_seconds() + GPS_UTC_LEAP_S
    week = math.floor(gps_s / WEEK_S)
    best = min((week - 1, week, week + 1), key=lambda w: abs(w * WEEK_S + itow_ms / 1000.0 - gps_s))
    return GPS_EPOCH + dt.timedelta(seconds=best * WEEK_S - GPS_UTC_LEAP_S, milliseconds=itow_ms)
