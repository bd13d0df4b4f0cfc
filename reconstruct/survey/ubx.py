"""u-blox UBX frames of a receiver stream -> epochs: NAV-PVT joined with NAV-HPPOSLLH on ``iTOW``,
NAV-HPPOSLLH alone with its own time; every other UBX message (polls, ACKs, configuration,
classes pyubx2 does not know) counted and skipped. See :mod:`reconstruct.survey.stream`."""

from __future__ import annotations

import bisect
import datetime as dt
from pathlib import Path
from typing import Any

from reconstruct.survey.stream import Epoch, ReceiverLog, StreamConfig, gps_tow_to_utc

_NAV_PVT, _NAV_HPPOSLLH = b"\x01\x07", b"\x01\x14"
_USED = {_NAV_PVT: (92, "NAV-PVT"), _NAV_HPPOSLLH: (36, "NAV-HPPOSLLH")}
NMEA_MATCH_S = 0.5  # an NMEA epoch this close to a lone NAV-HPPOSLLH gives it its fix [s]


class UbxEpochs:
    """Collects a stream's UBX frames (:meth:`add`) and makes its epochs (:meth:`epochs`)."""

    def __init__(self, path: Path, log: ReceiverLog) -> None:
        self.path, self.log = path, log
        self.pvt: dict[int, tuple[Any, int]] = {}  # iTOW -> (message, byte offset)
        self.hp: dict[int, tuple[Any, int]] = {}

    def add(self, raw: bytes, offset: int) -> None:
        """One checksum-valid UBX frame at byte ``offset``."""
        from pyubx2 import GET, UBXReader
        from pyubx2.exceptions import UBXMessageError, UBXParseError, UBXTypeError
        from pyubx2.ubxtypes_core import UBX_MSGIDS

        key, length = raw[2:4], len(raw) - 8
        if key not in _USED or length != _USED[key][0]:
            name = UBX_MSGIDS.get(key, f"{raw[2]:02X}-{raw[3]:02X}")
            self.log.skipped[f"UBX {name}{' poll' if length == 0 else ''}"] += 1
            return
        name = _USED[key][1]
        try:
            msg = UBXReader.parse(raw, msgmode=GET)
        except (UBXMessageError, UBXParseError, UBXTypeError) as exc:
            self.log.skipped[f"UBX {name} unreadable"] += 1
            self.log.warnings.append(f"{self.path}: byte {offset}: {name} unreadable ({exc}); skipped")
            return
        if key == _NAV_HPPOSLLH and getattr(msg, "invalidLlh", 0):
            self.log.skipped["UBX NAV-HPPOSLLH invalid"] += 1
            return
        (self.pvt if key == _NAV_PVT else self.hp)[msg.iTOW] = (msg, offset)
        self.log.used[f"UBX {name}"] += 1

    def first_date(self) -> dt.date | None:
        """The date of the first NAV-PVT with a valid date."""
        for m, _ in self.pvt.values():
            if m.validDate:
                return dt.date(m.year, m.month, m.day)
        return None

    def epochs(self, near: dt.datetime | None, nmea: list[Epoch], config: StreamConfig) -> list[Epoch]:
        """NAV-PVT epochs (position from the NAV-HPPOSLLH of the same iTOW), then lone NAV-HPPOSLLH
        epochs placed in time near the first NAV-PVT, else ``near``."""
        out = []
        for itow, (m, offset) in self.pvt.items():
            where = f"{self.path}: NAV-PVT at byte {offset} (iTOW {itow} ms)"
            if not (m.validDate and m.validTime):
                self.log.warnings.append(f"{where}: no valid date/time; skipped")
                continue
            t = dt.datetime(m.year, m.month, m.day, m.hour, m.min, m.second, tzinfo=dt.timezone.utc)
            t += dt.timedelta(microseconds=int(m.nano) // 1000)
            src = self.hp.get(itow, (m, 0))[0]
            out.append(Epoch(t, float(src.lat), float(src.lon), float(src.height) / 1000.0, _pvt_fix(m),
                             float(src.hAcc) / 1000.0, float(src.vAcc) / 1000.0, where))
        lone = [itow for itow in self.hp if itow not in self.pvt]
        if lone:
            anchor = out[0].t_utc if out else near
            out += self._lone(lone, anchor, nmea, config)
        return out

    def _lone(self, itows: list[int], near: dt.datetime | None, nmea: list[Epoch], config: StreamConfig) -> list[Epoch]:
        if near is None:
            self.log.warnings.append(f"{self.path}: {len(itows)} NAV-HPPOSLLH epoch(s) without NAV-PVT and nothing "
                                     "that dates them (no NMEA RMC/ZDA, no time window); skipped — pass a date")
            return []
        by_time = sorted(nmea, key=lambda e: e.t_utc)
        out, judged = [], 0
        for itow in itows:
            m, offset = self.hp[itow]
            t = gps_tow_to_utc(itow, near)
            h_acc = float(m.hAcc) / 1000.0
            fix = _nearest_fix(by_time, t)
            if fix is None:
                judged += 1
                fix = ("rtk_fixed" if h_acc <= config.lone_hp_fixed_max_h_acc_m
                       else "rtk_float" if h_acc <= config.lone_hp_float_max_h_acc_m else "single")
            out.append(Epoch(t, float(m.lat), float(m.lon), float(m.height) / 1000.0, fix, h_acc,
                             float(m.vAcc) / 1000.0, f"{self.path}: NAV-HPPOSLLH at byte {offset} (iTOW {itow} ms)"))
        self.log.warnings.append(
            f"{self.path}: {len(itows)} NAV-HPPOSLLH epoch(s) without NAV-PVT, timed by their iTOW"
            + (f"; the fix of {judged} judged from hAcc (<= {config.lone_hp_fixed_max_h_acc_m:g} m: rtk_fixed, "
               f"<= {config.lone_hp_float_max_h_acc_m:g} m: rtk_float) — enable NAV-PVT for the receiver's own fix"
               if judged else ", their fix from the NMEA epochs of the same time"))
        return out


def _pvt_fix(m: Any) -> str:
    if m.carrSoln == 2:
        return "rtk_fixed"
    if m.carrSoln == 1:
        return "rtk_float"
    if m.fixType in (3, 4) and m.gnssFixOk:
        return "dgnss" if m.diffSoln else "single"
    return "none"


def _nearest_fix(epochs: list[Epoch], t: dt.datetime) -> str | None:
    """The fix of the epoch (``epochs`` in time order) nearest ``t`` when within :data:`NMEA_MATCH_S`."""
    i = bisect.bisect_left(epochs, t, key=lambda e: e.t_utc)
    near = [e for e in epochs[max(i - 1, 0):i + 1] if abs((e.t_utc - t).total_seconds()) <= NMEA_MATCH_S]
    return min(near, key=lambda e: abs((e.t_utc - t).total_seconds())).fix if near else None
