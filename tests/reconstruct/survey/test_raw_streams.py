"""Raw receiver streams as real receivers record them (tests/data/gnss/raw, synthesised to mimic a
ZED-F9P UBX log, an NMEA-only rover and a u-center capture with configuration traffic and RTCM3),
and survey CSVs as field apps export them."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest

from reconstruct.errors import GnssFormatError, GnssQualityError
from reconstruct.survey import gnss
from reconstruct.survey.stream import frames, read_receiver_log
from synth.geometry import geodesy
from tests.reconstruct.survey import raw_captures as rc

RAW = Path(__file__).resolve().parents[2] / "data" / "gnss" / "raw"
KEYS = list(rc.POINTS)
ORIGIN = (64.1, 20.0, 250.0)


def _truth_site():
    a = np.array(list(rc.POINTS.values()))
    return geodesy.geodetic_to_site(ORIGIN, a[:, 0], a[:, 1], a[:, 2])


@pytest.mark.parametrize("name,h_acc,tol_m", [("f9p_rover.ubx", 0.0123, 1e-3), ("reach_rover.nmea", 0.015, 2e-3),
                                              ("ucenter_mixed.ubx", 0.0123, 1e-3)])
def test_each_receiver_kind_gives_the_surveyed_ends(name, h_acc, tol_m):
    s = gnss.read_raw_gnss(RAW / name, RAW / "windows.csv")
    assert [(p.log_id, p.end) for p in s.points] == KEYS
    assert np.abs(s.points_site(ORIGIN) - _truth_site()).max() < tol_m
    for p in s.points:
        assert p.fix == "rtk_fixed" and p.n_epochs == rc.N_EPOCHS
        assert abs(p.h_acc_m - h_acc) < 2e-4
        assert 0.002 < p.spread_h_m < 0.005  # +-4e-8 deg of latitude about the truth


def test_mixed_capture_skips_and_counts_what_it_does_not_use():
    log = read_receiver_log(RAW / "ucenter_mixed.ubx", time_hint=rc.T0)
    n = len(KEYS) * rc.N_EPOCHS
    assert log.skipped == {"RTCM3 1005": n, "UBX 99-01": n, "UBX NAV-PVT poll": n, "UBX ACK-NAK": n, "UBX ACK-ACK": 1,
                           "UBX MON-VER poll": 1, "UBX CFG-VALGET": 1, "UBX CFG-RATE": 1,
                           "UBX CFG-VALSET": 1}
    assert log.used == {"UBX NAV-HPPOSLLH": n, "NMEA GNS": n, "NMEA GST": n, "NMEA ZDA": n}
    assert log.junk_bytes == 60  # the frame cut at the start of the capture
    # lone NAV-HPPOSLLH: timed by iTOW (GPS - 18 s) and given the fix of the NMEA epoch of the same second
    assert [e.t_utc for e in log.epochs[:rc.N_EPOCHS]] == rc.epoch_times(0)
    assert all(e.fix == "rtk_fixed" and "NAV-HPPOSLLH" in e.source for e in log.epochs)
    assert any("repeat UBX epochs" in w for w in log.warnings)


def test_pyubx2_alone_stops_on_the_mixed_capture():
    """The symptom of issue 38: pyubx2's reader in its default GET mode raises on this stream."""
    from pyubx2 import ERR_RAISE, UBX_PROTOCOL, UBXReader
    from pyubx2.exceptions import UBXMessageError, UBXParseError, UBXStreamError

    reader = UBXReader(io.BytesIO((RAW / "ucenter_mixed.ubx").read_bytes()), protfilter=UBX_PROTOCOL,
                       quitonerror=ERR_RAISE)
    with pytest.raises((UBXMessageError, UBXParseError, UBXStreamError), match="Unknown message type"):
        for _ in reader:
            pass


def test_nmea_rover_counts_bad_checksums():
    log = read_receiver_log(RAW / "reach_rover.nmea")
    assert log.skipped["NMEA bad checksum or syntax"] == len(KEYS) * rc.N_EPOCHS
    assert log.skipped["NMEA GSA"] == len(KEYS) * rc.N_EPOCHS
    assert any("checksum" in w for w in log.warnings)


def test_framing_finds_frames_between_junk_and_ignores_a_cut_frame():
    ubx = rc._hppos(rc.T0, 64.1, 20.0, 250000.0)
    rtcm = rc._rtcm(1005)
    data = b"\x00junk" + ubx + b"$GPxx" + rtcm + ubx[:-1]
    kinds = [(k, len(raw)) for k, _, raw in frames(data)]
    assert kinds == [("junk", 5), ("ubx", len(ubx)), ("junk", 5), ("rtcm3", len(rtcm)), ("junk", len(ubx) - 1)]
    bad = bytearray(rtcm)
    bad[5] ^= 1  # a flipped bit: the CRC-24Q refuses the frame
    assert [k for k, _, _ in frames(bytes(bad))] == ["junk"]


def test_lone_hppos_without_nmea_is_timed_by_the_windows_and_judged_by_its_accuracy(tmp_path):
    points = dict(list(rc.POINTS.items()))
    data = b""
    for k, (lat, lon, h) in enumerate(points.values()):
        for j, t in enumerate(rc.epoch_times(k)):
            acc = 100.0 if k == 3 else 12.3  # the last end: a 10 cm hAcc, RTK float at best
            data += rc._hppos(t, lat, lon, h * 1000.0, h_acc_mm=acc)
    log = tmp_path / "hp_only.ubx"
    log.write_bytes(data)
    with pytest.raises(GnssQualityError, match="log 'log1' end 'b' is rtk_float"):
        gnss.read_raw_gnss(log, RAW / "windows.csv")
    s = gnss.read_raw_gnss(log, RAW / "windows.csv", allow_float=True)
    assert s.point("log0", "a").fix == "rtk_fixed" and s.point("log0", "a").n_epochs == rc.N_EPOCHS
    assert any("judged from hAcc" in w for w in s.warnings)


def test_window_for_one_end_only_and_overlapping_windows(tmp_path):
    w = tmp_path / "w.csv"
    lines = rc.windows_text(KEYS).splitlines()
    w.write_text("\n".join(lines[:-1]) + "\n")  # log1 b has no window
    with pytest.raises(GnssFormatError, match=r"w\.csv:6: log 'log1' has a window for end 'a' but none for end 'b'"):
        gnss.read_raw_gnss(RAW / "f9p_rover.ubx", w)
    w.write_text("\n".join(lines[:4] + [lines[4].replace("09:30:29.500", "09:30:03.000")] + lines[5:]) + "\n")
    with pytest.raises(GnssFormatError, match=r"w\.csv:5: the window of log 'log0' end 'b' overlaps .*w\.csv:4"):
        gnss.read_raw_gnss(RAW / "f9p_rover.ubx", w)
    w.write_text("# format: loggrasp.gnss-windows 2.0\n" + "\n".join(lines[1:]) + "\n")
    with pytest.raises(GnssFormatError, match=r"w\.csv:1: loggrasp.gnss-windows version 2.0 is not supported"):
        gnss.read_raw_gnss(RAW / "f9p_rover.ubx", w)


# -- field-app exports ---------------------------------------------------------------------------
def _export(tmp_path, sep=";", comma=True) -> Path:
    lat, lon, h = (np.array(v) for v in zip(*rc.POINTS.values()))
    e, n = geodesy.geodetic_to_tm(lat, lon)
    rows = [sep.join(["Point", "E", "N", "Ell. height", "Solution", "Code", "Std dev H"])]
    for (log_id, end), ee, nn, hh in zip(KEYS, e, n, h):
        vals = [f"{log_id}{end}", f"{ee:.4f}", f"{nn:.4f}", f"{hh:.4f}", "FIX", "LOG", "0.012"]
        rows.append(sep.join(v.replace(".", ",") if comma and v[0].isdigit() else v for v in vals))
    p = tmp_path / "export.csv"
    p.write_text("\n".join(rows) + "\n")
    return p


def test_field_app_export_with_semicolons_decimal_commas_and_a_column_map(tmp_path):
    p = _export(tmp_path)
    with pytest.raises(GnssFormatError, match="no coordinate columns.*--columns"):
        gnss.read_gnss_csv(p)
    cols = gnss.parse_columns("id=Point,easting=E,northing=N,height=Ell. height,fix=Solution,h_acc=Std dev H")
    s = gnss.read_gnss_csv(p, columns=cols)
    assert [(q.log_id, q.end) for q in s.points] == KEYS and all(q.fix == "rtk_fixed" for q in s.points)
    assert np.abs(s.points_site(ORIGIN) - _truth_site()).max() < 1e-3
    assert s.points[0].h_acc_m == 0.012 and math.isnan(s.points[0].v_acc_m)
    # the same map as a file; a comma-separated export reads the same
    m = tmp_path / "map.txt"
    m.write_text("# Emlid-like export\nid = Point\neasting = E\nnorthing = N\nheight = Ell. height\nfix = Solution\n")
    s2 = gnss.read_gnss_csv(_export(tmp_path, sep=",", comma=False), columns=gnss.column_map(str(m)))
    assert np.abs(s2.points_site(ORIGIN) - s.points_site(ORIGIN)).max() < 1e-9


def test_column_map_errors(tmp_path):
    with pytest.raises(GnssFormatError, match="unknown column name"):
        gnss.column_map("colour=Point")
    with pytest.raises(GnssFormatError, match=r"no column\(s\) \['Pt', 'H', 'S'\]"):
        gnss.read_gnss_csv(_export(tmp_path), columns=gnss.parse_columns("id=Pt,easting=E,northing=N,height=H,fix=S"))
    p = _export(tmp_path)
    p.write_text(p.read_text().replace("log1b", "log1"))
    with pytest.raises(GnssFormatError, match=r"export\.csv:5: point 'log1' names no end"):
        gnss.read_gnss_csv(p, columns=gnss.parse_columns("id=Point,easting=E,northing=N,height=Ell. height,"
                                                         "fix=Solution"))
