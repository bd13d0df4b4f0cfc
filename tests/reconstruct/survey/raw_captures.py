"""Synthesised receiver captures of a log-end survey, in the byte formats of three receiver kinds
(see tests/data/gnss/raw/README.md). ``python -m tests.reconstruct.survey.raw_captures`` rewrites
the checked-in captures; tests also call :func:`write_captures` on other points."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

T0 = dt.datetime(2026, 5, 14, 9, 30, 0, tzinfo=dt.timezone.utc)
GAP_S = 30  # between two log ends [s]
N_EPOCHS = 5  # 1 Hz epochs per log end
GEOID_SEP_M = 20.123
LEAP_S = 18  # GPS - UTC [s]
GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.timezone.utc)
#: the checked-in captures' log ends (SWEREF 99 lat, lon [deg], ellipsoidal h [m]): two logs near 64.1 N 20.0 E
POINTS = {("log0", "a"): (64.1000036164, 19.9999630838, 250.1131), ("log0", "b"): (64.1000182231, 20.0000401711, 250.2950),
          ("log1", "a"): (64.0999851002, 19.9999812306, 250.0412), ("log1", "b"): (64.0999977113, 20.0000633018, 250.1707)}


def epoch_times(k: int) -> list[dt.datetime]:
    """The epochs of the ``k``-th log end."""
    return [T0 + dt.timedelta(seconds=k * GAP_S + j) for j in range(N_EPOCHS)]


def windows_text(keys) -> str:
    lines = ["# format: loggrasp.gnss-windows 1.0", "# the operator's tags: which log end the rover stood on, UTC",
             "log_id,end,t_start_utc,t_end_utc"]
    for k, (log_id, end) in enumerate(keys):
        ts = epoch_times(k)
        lines.append(f"{log_id},{end},{_iso(ts[0] - dt.timedelta(seconds=0.5))},{_iso(ts[-1] + dt.timedelta(seconds=0.5))}")
    return "\n".join(lines) + "\n"


def _iso(t: dt.datetime) -> str:
    return t.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _itow(t: dt.datetime) -> int:
    s = (t - GPS_EPOCH).total_seconds() + LEAP_S
    return int(round((s % 604800) * 1000))


def _jitter(j: int) -> float:
    return 2e-8 * (j - (N_EPOCHS - 1) / 2)  # symmetric: the mean is the truth [deg]


# -- u-blox ZED-F9P: NAV-PVT + NAV-HPPOSLLH (UBX only) -------------------------------------------
def _pvt(t, lat, lon, h_mm, carr=2):
    from pyubx2 import GET, UBXMessage

    return UBXMessage("NAV", "NAV-PVT", GET, iTOW=_itow(t), year=t.year, month=t.month, day=t.day, hour=t.hour,
                      min=t.minute, second=t.second, validDate=1, validTime=1, fullyResolved=1, fixType=3,
                      gnssFixOk=1, diffSoln=1, carrSoln=carr, numSV=24, lat=round(lat, 7), lon=round(lon, 7),
                      height=int(round(h_mm)), hMSL=int(round(h_mm - GEOID_SEP_M * 1000)), hAcc=14, vAcc=21).serialize()


def _hppos(t, lat, lon, h_mm, h_acc_mm=12.3, v_acc_mm=18.7):
    from pyubx2 import GET, UBXMessage

    lat7, lon7, h_int = math.floor(lat * 1e7) / 1e7, math.floor(lon * 1e7) / 1e7, math.floor(h_mm)
    return UBXMessage("NAV", "NAV-HPPOSLLH", GET, iTOW=_itow(t), lat=lat7, _HPlat=round(lat - lat7, 9), lon=lon7,
                      _HPlon=round(lon - lon7, 9), height=h_int, _HPheight=round(h_mm - h_int, 1),
                      hMSL=h_int - int(GEOID_SEP_M * 1000), hAcc=h_acc_mm, vAcc=v_acc_mm, invalidLlh=0).serialize()


def f9p_capture(points) -> bytes:
    out = b""
    for k, (lat, lon, h) in enumerate(points.values()):
        for j, t in enumerate(epoch_times(k)):
            la = lat + _jitter(j)
            out += _pvt(t, la, lon, h * 1000.0) + _hppos(t, la, lon, h * 1000.0)
    return out


# -- an NMEA-only rover (Emlid Reach / Trimble-like: GGA + GST + RMC, with GSA/GSV chatter) -------
def _coord(v: float, width: int) -> str:
    d = int(v)
    return f"{d:0{width}d}{(v - d) * 60:011.8f}"


def nmea_capture(points) -> bytes:
    import pynmea2

    lines = []
    for k, (lat, lon, h) in enumerate(points.values()):
        for j, t in enumerate(epoch_times(k)):
            ts, la = t.strftime("%H%M%S.00"), lat + _jitter(j)
            lines.append(str(pynmea2.GGA("GN", "GGA", (ts, _coord(la, 2), "N", _coord(lon, 3), "E", "4", "21", "0.6",
                                                      f"{h - GEOID_SEP_M:.4f}", "M", f"{GEOID_SEP_M:.3f}", "M", "1.0",
                                                      "0000"))))
            lines.append(str(pynmea2.GST("GN", "GST", (ts, "0.5", "0.010", "0.008", "12.0", "0.009", "0.012",
                                                      "0.021"))))
            lines.append(str(pynmea2.RMC("GN", "RMC", (ts, "A", _coord(la, 2), "N", _coord(lon, 3), "E", "0.0", "0.0",
                                                      t.strftime("%d%m%y"), "", "", "R"))))
            lines.append(str(pynmea2.GSA("GN", "GSA", ("M", "3", "05", "13", "15", "18", "", "", "", "", "", "", "", "",
                                                      "1.1", "0.6", "0.9"))))
            lines.append("$GPGSV,3,1,11,05,43,291,45,13,65,178,47,15,30,120,41,18,22,052,38*7F")  # a bad checksum
    return ("\r\n".join(lines) + "\r\n").encode("ascii")


# -- a u-center / serial-logger capture: NMEA + UBX configuration traffic + RTCM3 in one stream ----
def _rtcm(msg_type: int) -> bytes:
    from pyrtcm import RTCMMessage

    if msg_type == 1005:
        return RTCMMessage(payload=_rtcm1005_payload()).serialize()
    raise ValueError(msg_type)


def _rtcm1005_payload() -> bytes:
    """An RTCM 1005 (reference station position, 152 bits): the type, then station 0 at ECEF 0."""
    return int(f"{1005:012b}" + "0" * 140, 2).to_bytes(19, "big")


def _ubx_raw(cls: int, mid: int, payload: bytes) -> bytes:
    from pyubx2.ubxhelpers import calc_checksum

    body = bytes((cls, mid)) + len(payload).to_bytes(2, "little") + payload
    return b"\xb5\x62" + body + calc_checksum(body)


def mixed_capture(points) -> bytes:
    """GNS + GST + ZDA for the fixes, NAV-HPPOSLLH without NAV-PVT for the positions, and the
    traffic a serial logger records beside them: UBX polls and their ACKs, a configuration
    message, a class no decoder knows, RTCM3 corrections, and a frame cut at the start."""
    import pynmea2
    from pyubx2 import POLL, SET, UBXMessage

    out = _ubx_raw(0x01, 0x07, bytes(92))[40:]  # the capture starts in the middle of a frame
    out += UBXMessage("MON", "MON-VER", POLL).serialize()
    out += UBXMessage("CFG", "CFG-VALGET", POLL, version=0, layer=0, position=0, keys=[0x20910007]).serialize()
    out += _ubx_raw(0x05, 0x01, b"\x06\x8b")  # ACK-ACK of the CFG-VALGET
    out += UBXMessage("CFG", "CFG-RATE", SET, measRate=1000, navRate=1, timeRef=0).serialize()
    # CFG-VALSET CFG-RATE-MEAS = 1000 ms, as u-center sends it (an input-only message: pyubx2's reader
    # in GET mode stops on it with "Unknown message type ... mode GET")
    out += _ubx_raw(0x06, 0x8A, bytes((0, 1, 0, 0)) + (0x30210001).to_bytes(4, "little") + (1000).to_bytes(2, "little"))
    for k, (lat, lon, h) in enumerate(points.values()):
        for j, t in enumerate(epoch_times(k)):
            ts, la = t.strftime("%H%M%S.00"), lat + _jitter(j)
            out += str(pynmea2.GNS("GN", "GNS", (ts, _coord(la, 2), "N", _coord(lon, 3), "E", "RRRN", "22", "0.6",
                                                 f"{h - GEOID_SEP_M:.4f}", f"{GEOID_SEP_M:.3f}", "1.0", "0000"))
                       ).encode() + b"\r\n"
            out += str(pynmea2.GST("GN", "GST", (ts, "0.5", "0.011", "0.009", "12.0", "0.010", "0.013", "0.022"))
                       ).encode() + b"\r\n"
            out += str(pynmea2.ZDA("GN", "ZDA", (ts, t.strftime("%d"), t.strftime("%m"), t.strftime("%Y"), "00", "00"))
                       ).encode() + b"\r\n"
            out += _hppos(t, la, lon, h * 1000.0)
            out += _rtcm(1005)
            out += _ubx_raw(0x99, 0x01, b"\x01\x02\x03\x04")  # a class pyubx2 does not know
            out += UBXMessage("NAV", "NAV-PVT", POLL).serialize()
            out += _ubx_raw(0x05, 0x00, b"\x01\x07")  # ACK-NAK of the poll
    return out


def write_captures(out_dir: Path, points=POINTS) -> dict[str, Path]:
    """The three captures and their windows file in ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {"f9p": out_dir / "f9p_rover.ubx", "nmea": out_dir / "reach_rover.nmea",
             "mixed": out_dir / "ucenter_mixed.ubx", "windows": out_dir / "windows.csv"}
    files["f9p"].write_bytes(f9p_capture(points))
    files["nmea"].write_bytes(nmea_capture(points))
    files["mixed"].write_bytes(mixed_capture(points))
    files["windows"].write_text(windows_text(list(points)))
    return files


if __name__ == "__main__":
    for name, path in write_captures(Path(__file__).resolve().parents[2] / "data" / "gnss" / "raw").items():
        print(name, path, path.stat().st_size)
