"""reconstruct.survey.gnss: survey CSV reader/writer, raw NMEA/UBX logs with time windows, checks."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

import numpy as np
import pytest

from reconstruct.survey import gnss
from reconstruct.errors import (
    GnssFileError,
    GnssFormatError,
    GnssOutlierError,
    GnssQualityError,
    ReconstructError,
)
from synth.geometry import geodesy
from synth.geometry.frames import make_T, rot_z
from synth.scene.pile import Georeference

DATA = Path(__file__).resolve().parents[2] / "data" / "gnss"
GEOREF = Georeference(64.1, 20.0, 250.0, tuple(tuple(float(v) for v in r) for r in make_T(rot_z(0.2), (0.5, -0.3, 0.1))))
HEADER = "log_id,end,lat_deg,lon_deg,h_ell_m,fix,h_acc_m,v_acc_m,time_utc"


def _ends(n=3, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        c = rng.uniform(-2, 2, 3) * (1, 1, 0.1)
        a = rng.uniform(0, math.pi)
        d = np.array([math.cos(a), math.sin(a), 0.05]) * rng.uniform(1.5, 2.5)
        out.append((c - d, c + d))
    return out


def _write(tmp_path, body, name="s.csv", header=HEADER, meta="# crs: EPSG:4619\n"):
    p = tmp_path / name
    p.write_text(meta + header + "\n" + body)
    return p


def _rows(lat0=64.1, lon0=20.0):
    return (
        f"log0,a,{lat0:.9f},{lon0:.9f},250.1,rtk_fixed,0.014,0.02,2026-05-14T09:30:05Z\n"
        f"log0,b,{lat0 + 2e-5:.9f},{lon0 + 3e-5:.9f},250.2,rtk_fixed,0.015,0.02,2026-05-14T09:30:45Z\n"
        f"log1,a,{lat0 + 1e-5:.9f},{lon0 - 2e-5:.9f},250.3,rtk_fixed,0.014,0.02,\n"
        f"log1,b,{lat0 + 3e-5:.9f},{lon0 + 1e-5:.9f},250.0,rtk_fixed,,,\n"
    )


# -- CSV round trips ------------------------------------------------------------------------
@pytest.mark.parametrize("crs,tol_m", [("EPSG:4619", 1e-4), ("EPSG:3006", 5e-4)])
def test_simulated_survey_csv_round_trip(tmp_path, crs, tol_m):
    ends = _ends(4)
    s = gnss.simulate_survey(ends, GEOREF, np.random.default_rng(1), n_float=1)
    path = gnss.write_gnss_csv(s, tmp_path / "survey.csv", crs=crs)
    text = path.read_text()
    assert text.startswith("# format: loggrasp.gnss-csv 1.0\n") and f"# crs: {crs}" in text
    back = gnss.read_gnss_csv(path, allow_float=True)
    assert [(p.log_id, p.end, p.fix) for p in back.points] == [(p.log_id, p.end, p.fix) for p in s.points]
    d = np.linalg.norm(back.points_site(GEOREF) - s.points_site(GEOREF), axis=1)
    assert d.max() < tol_m
    for p, q in zip(s.points, back.points):
        assert abs(p.h_acc_m - q.h_acc_m) < 1e-4 and p.time_utc == q.time_utc
    assert any("float" in w for w in back.warnings)
    with pytest.raises(GnssQualityError, match="rtk_float"):
        gnss.read_gnss_csv(path)  # float not allowed by default


def test_simulated_noise_is_realistic_and_endpoints_site_exact_without_noise():
    ends = _ends(150, seed=3)
    truth = np.array(ends).reshape(-1, 3)
    s0 = gnss.simulate_survey(ends, GEOREF, np.random.default_rng(0), sigma_h_m=0.0, sigma_v_m=0.0)
    got = s0.endpoints_site(GEOREF)
    assert list(got) == [f"log{i}" for i in range(150)]
    est = np.array([[got[k][0], got[k][1]] for k in got]).reshape(-1, 3)
    assert np.abs(est - truth).max() < 1e-6
    pile_ends = s0.endpoints_pile(GEOREF)["log7"]
    assert np.abs(geodesy.pile_to_site(GEOREF, np.stack(pile_ends)) - np.array(ends[7])).max() < 1e-6
    s = gnss.simulate_survey(ends, GEOREF, np.random.default_rng(0), sigma_h_m=0.015, sigma_v_m=0.025)
    err = s.points_site(GEOREF) - truth
    rms_h = math.sqrt(np.mean(err[:, 0] ** 2 + err[:, 1] ** 2))
    rms_v = math.sqrt(np.mean(err[:, 2] ** 2))
    assert 0.012 < rms_h < 0.018 and 0.020 < rms_v < 0.030
    assert all(p.fix == "rtk_fixed" for p in s.points)
    s2 = gnss.simulate_survey(ends, GEOREF, np.random.default_rng(0), n_float=5)
    assert sum(p.fix == "rtk_float" for p in s2.points) == 5


def test_default_origin_and_georeference():
    s = gnss.simulate_survey(_ends(3), GEOREF, np.random.default_rng(2))
    site = s.points_site()
    assert np.abs(site.mean(axis=0)).max() < 1e-3  # origin = mean point
    g = s.georeference()
    assert np.allclose(s.endpoints_site(g)["log0"][0], s.endpoints_site()["log0"][0])


def test_checked_in_examples_read(tmp_path):
    geo = gnss.read_gnss_csv(DATA / "survey_sweref99.csv")
    tm = gnss.read_gnss_csv(DATA / "survey_sweref99tm.csv")
    assert geo.log_ids == tm.log_ids == ["log0", "log1"]
    assert np.abs(geo.points_site(GEOREF) - tm.points_site(GEOREF)).max() < 1e-3


# -- errors -------------------------------------------------------------------------------
def test_missing_file(tmp_path):
    with pytest.raises(GnssFileError, match="nope.csv"):
        gnss.read_gnss_csv(tmp_path / "nope.csv")


def test_malformed_rows_name_file_line_and_log(tmp_path):
    p = _write(tmp_path, _rows() + "log2,a,64.1,20.0,250.0,rtk_fixed\n")
    with pytest.raises(GnssFormatError, match=r"s\.csv:7: 6 fields"):
        gnss.read_gnss_csv(p)
    p = _write(tmp_path, _rows().replace("250.3", "25O.3"))
    with pytest.raises(GnssFormatError, match=r"s\.csv:5: h_ell_m '25O.3' is not a number") as ei:
        gnss.read_gnss_csv(p)
    assert isinstance(ei.value, ReconstructError) and isinstance(ei.value, ValueError)
    p = _write(tmp_path, _rows().replace("log1,b", "log1,c"))
    with pytest.raises(GnssFormatError, match=r"s\.csv:6.*log 'log1'.*'a' or 'b'"):
        gnss.read_gnss_csv(p)
    p = _write(tmp_path, _rows().replace("rtk_fixed,0.014,0.02,\n", "rtk_fixd,0.014,0.02,\n"))
    with pytest.raises(GnssFormatError, match="fix must be one of"):
        gnss.read_gnss_csv(p)
    p = _write(tmp_path, _rows(), header=HEADER + ",colour")
    with pytest.raises(GnssFormatError, match="unknown column"):
        gnss.read_gnss_csv(p)


def test_missing_and_duplicated_ends(tmp_path):
    rows = _rows().splitlines(keepends=True)
    p = _write(tmp_path, "".join(rows[:3]))
    with pytest.raises(GnssFormatError, match="log 'log1' has no end 'b'"):
        gnss.read_gnss_csv(p)
    p = _write(tmp_path, "".join(rows) + rows[0])
    with pytest.raises(GnssFormatError, match=r"log 'log0' end 'a' is measured twice \(.*s\.csv:3 and .*s\.csv:7\)"):
        gnss.read_gnss_csv(p)


def test_fix_quality(tmp_path):
    p = _write(tmp_path, _rows().replace("250.2,rtk_fixed", "250.2,rtk_float"))
    with pytest.raises(GnssQualityError, match=r"s\.csv:4: log 'log0' end 'b' is rtk_float.*--allow-float"):
        gnss.read_gnss_csv(p)
    assert gnss.read_gnss_csv(p, allow_float=True).point("log0", "b").fix == "rtk_float"
    p = _write(tmp_path, _rows().replace("250.2,rtk_fixed", "250.2,single"))
    with pytest.raises(GnssQualityError, match="single"):
        gnss.read_gnss_csv(p, allow_float=True)


def test_far_points(tmp_path):
    far = _rows().replace("log1,a,64.100010000", "log1,a,64.101010000")  # ~110 m north
    p = _write(tmp_path, far)
    with pytest.raises(GnssOutlierError, match=r"log 'log1' end 'a' lies 1\d\d\.\d m from the median"):
        gnss.read_gnss_csv(p)
    assert gnss.read_gnss_csv(p, max_distance_m=200.0).log_ids == ["log0", "log1"]
    p = _write(tmp_path, _rows())
    with pytest.raises(GnssOutlierError, match="scanned area"):
        gnss.read_gnss_csv(p, area=(64.102, 20.0, 250.0))
    assert gnss.read_gnss_csv(p, area=GEOREF).log_ids == ["log0", "log1"]


def test_swapped_lat_lon_and_bad_crs(tmp_path):
    swapped = "\n".join(
        ",".join([f[0], f[1], f[3], f[2], *f[4:]]) for f in (r.split(",") for r in _rows().splitlines())
    ) + "\n"
    p = _write(tmp_path, swapped)
    with pytest.raises(GnssFormatError, match=r"s\.csv:3.*swapped"):
        gnss.read_gnss_csv(p)
    p = _write(tmp_path, _rows(), meta="# crs: EPSG:4326\n")
    with pytest.raises(GnssFormatError, match=r"s\.csv:1: CRS 'EPSG:4326' is not supported"):
        gnss.read_gnss_csv(p)
    p = _write(tmp_path, _rows(), meta="# crs: EPSG:3006\n")
    with pytest.raises(GnssFormatError, match="does not match the coordinate columns"):
        gnss.read_gnss_csv(p)
    p = _write(tmp_path, _rows(), meta="# format: loggrasp.gnss-csv 2.0\n")
    with pytest.raises(GnssFormatError, match="version 2.0 is not supported"):
        gnss.read_gnss_csv(p)
    tm = ("log_id,end,easting_m,northing_m,h_ell_m,fix,h_acc_m,v_acc_m\n"
          "log0,a,7117723.2,743495.0,250,rtk_fixed,0.01,0.02\n")
    p = tmp_path / "tm.csv"
    p.write_text(tm)
    with pytest.raises(GnssFormatError, match=r"tm\.csv:2.*swapped"):
        gnss.read_gnss_csv(p)


# -- raw logs -------------------------------------------------------------------------------
T0 = dt.datetime(2026, 5, 14, 9, 30, 0, tzinfo=dt.timezone.utc)


def _survey_truth():
    ends = _ends(2, seed=5)
    pts = np.array(ends).reshape(-1, 3)
    lat, lon, h = geodesy.site_to_geodetic(GEOREF, pts)
    return [("log0", "a"), ("log0", "b"), ("log1", "a"), ("log1", "b")], lat, lon, h


def _windows_file(tmp_path, keys, n_epochs, gap_s=30):
    lines = ["# operator's tags", "log_id,end,t_start_utc,t_end_utc"]
    for k, (log_id, end) in enumerate(keys):
        t0 = T0 + dt.timedelta(seconds=k * gap_s)
        t1 = t0 + dt.timedelta(seconds=n_epochs - 1)
        lines.append(f"{log_id},{end},{t0.isoformat().replace('+00:00', 'Z')},{t1.isoformat()}")
    p = tmp_path / "windows.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


def _nmea_coord(v, width):
    d = int(v)
    return f"{d:0{width}d}{(v - d) * 60:011.8f}"


def _nmea_log(tmp_path, lat, lon, h, n_epochs=5, gap_s=30, quality=None, jitter=1e-7):
    import pynmea2

    sep = 20.123
    lines = []
    for k in range(len(lat)):
        for j in range(n_epochs):
            t = T0 + dt.timedelta(seconds=k * gap_s + j)
            ts = t.strftime("%H%M%S.00")
            dlat = jitter * (j - (n_epochs - 1) / 2)  # symmetric: the mean is the truth
            q = quality(k, j) if quality else 4
            la, lo = lat[k] + dlat, lon[k]
            gga = pynmea2.GGA("GN", "GGA", (ts, _nmea_coord(la, 2), "N", _nmea_coord(lo, 3), "E", str(q), "20",
                                            "0.6", f"{h[k] - sep:.4f}", "M", f"{sep:.3f}", "M", "1.0", "0000"))
            rmc = pynmea2.RMC("GN", "RMC", (ts, "A", _nmea_coord(la, 2), "N", _nmea_coord(lo, 3), "E", "0.0",
                                            "0.0", t.strftime("%d%m%y"), "", "", "D"))
            gst = pynmea2.GST("GN", "GST", (ts, "0.5", "0.010", "0.008", "12.0", "0.009", "0.012", "0.021"))
            lines += [str(gga), str(rmc), str(gst)]
    lines.insert(7, lines[7][:-2] + "00")  # a corrupt copy of a sentence (bad checksum)
    p = tmp_path / "rover.nmea"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_nmea_gga_log_with_windows(tmp_path):
    keys, lat, lon, h = _survey_truth()
    log = _nmea_log(tmp_path, lat, lon, h)
    win = _windows_file(tmp_path, keys, 5)
    s = gnss.read_raw_gnss(log, win, area=GEOREF)
    assert [(p.log_id, p.end) for p in s.points] == keys
    truth = geodesy.geodetic_to_site(GEOREF, lat, lon, h)
    assert np.abs(s.points_site(GEOREF) - truth).max() < 1e-3  # ellipsoidal h = altitude + separation
    p = s.points[0]
    assert p.fix == "rtk_fixed" and p.n_epochs == 5
    assert abs(p.h_acc_m - math.hypot(0.009, 0.012)) < 1e-9 and abs(p.v_acc_m - 0.021) < 1e-9
    assert 0.01 < p.spread_h_m < 0.03  # +-2e-7 deg of latitude ~ +-2.2 cm
    assert any("checksum" in w for w in s.warnings)
    # round trip through the CSV keeps the averaging metadata
    back = gnss.read_gnss_csv(gnss.write_gnss_csv(s, tmp_path / "avg.csv"))
    assert back.points[0].n_epochs == 5 and abs(back.points[0].spread_h_m - p.spread_h_m) < 1e-4


def test_nmea_float_epoch_and_empty_window(tmp_path):
    keys, lat, lon, h = _survey_truth()
    log = _nmea_log(tmp_path, lat, lon, h, quality=lambda k, j: 5 if (k == 2 and j == 3) else 4)
    win = _windows_file(tmp_path, keys, 5)
    with pytest.raises(GnssQualityError, match=r"windows\.csv:5: log 'log1' end 'a' is rtk_float"):
        gnss.read_raw_gnss(log, win)
    s = gnss.read_raw_gnss(log, win, allow_float=True)
    assert s.point("log1", "a").fix == "rtk_float" and s.point("log0", "a").fix == "rtk_fixed"
    log = _nmea_log(tmp_path, lat, lon, h, quality=lambda k, j: 0 if k == 1 else 4)
    with pytest.raises(GnssQualityError, match="log 'log0' end 'b'.*no position fix"):
        gnss.read_raw_gnss(log, win)
    late = tmp_path / "late.csv"
    late.write_text("log_id,end,t_start_utc,t_end_utc\nlog0,a,2026-05-14T10:00:00Z,2026-05-14T10:01:00Z\n"
                    "log0,b,2026-05-14T10:02:00Z,2026-05-14T10:03:00Z\n")
    # the window and the logs' time span are named
    with pytest.raises(GnssQualityError, match=r"late\.csv:2.*0 receiver epochs between 2026-05-14T10:00:00.000Z and "
                       r"2026-05-14T10:01:00.000Z.*the logs span rover\.nmea 2026-05-14T09:30:00.000Z to "
                       r"2026-05-14T09:31:34.000Z"):
        gnss.read_raw_gnss(log, late)


def _ubx_log(tmp_path, lat, lon, h, n_epochs=4, gap_s=30, carr=lambda k, j: 2, hp=True):
    from pyubx2 import GET, UBXMessage

    out = b""
    for k in range(len(lat)):
        for j in range(n_epochs):
            t = T0 + dt.timedelta(seconds=k * gap_s + j)
            itow = 100_000 + (k * gap_s + j) * 1000
            la, lo, hm = lat[k], lon[k], h[k] * 1000.0
            pvt = UBXMessage("NAV", "NAV-PVT", GET, iTOW=itow, year=t.year, month=t.month, day=t.day,
                             hour=t.hour, min=t.minute, second=t.second, validDate=1, validTime=1,
                             fixType=3, gnssFixOk=1, diffSoln=1, carrSoln=carr(k, j), numSV=22,
                             lat=round(la, 7), lon=round(lo, 7), height=int(round(hm)),
                             hMSL=int(round(hm)) - 20000, hAcc=25, vAcc=40)
            out += pvt.serialize()
            if hp:
                lat7, lon7 = math.floor(la * 1e7) / 1e7, math.floor(lo * 1e7) / 1e7
                h_int = math.floor(hm)
                hpm = UBXMessage("NAV", "NAV-HPPOSLLH", GET, iTOW=itow, lat=lat7,
                                 _HPlat=round(la - lat7, 9), lon=lon7, _HPlon=round(lo - lon7, 9),
                                 height=h_int, _HPheight=round(hm - h_int, 1), hMSL=h_int - 20000,
                                 hAcc=12.3, vAcc=18.7, invalidLlh=0)
                out += hpm.serialize()
    p = tmp_path / "rover.ubx"
    p.write_bytes(out)
    return p


def test_ubx_log_with_windows(tmp_path):
    keys, lat, lon, h = _survey_truth()
    win = _windows_file(tmp_path, keys, 4)
    s = gnss.read_raw_gnss(_ubx_log(tmp_path, lat, lon, h), win)
    truth = geodesy.geodetic_to_site(GEOREF, lat, lon, h)
    assert np.abs(s.points_site(GEOREF) - truth).max() < 1e-3  # HPPOSLLH: 1e-9 deg, 0.1 mm
    assert s.points[0].fix == "rtk_fixed" and s.points[0].n_epochs == 4
    # the message carries 0.1 mm; pyubx2 truncates 18.7 mm to 18.6 when encoding
    assert abs(s.points[0].h_acc_m - 0.0123) < 1.5e-4 and abs(s.points[0].v_acc_m - 0.0187) < 1.5e-4
    # without HPPOSLLH: NAV-PVT's 1e-7 deg (~1 cm) position and mm accuracies
    s2 = gnss.read_raw_gnss(_ubx_log(tmp_path, lat, lon, h, hp=False), win)
    assert np.abs(s2.points_site(GEOREF) - truth).max() < 0.01
    assert abs(s2.points[0].h_acc_m - 0.025) < 1e-9
    # carrSoln 1 = float
    f = _ubx_log(tmp_path, lat, lon, h, carr=lambda k, j: 1 if k == 3 else 2)
    with pytest.raises(GnssQualityError, match="log 'log1' end 'b' is rtk_float"):
        gnss.read_raw_gnss(f, win)


def test_raw_log_errors(tmp_path):
    keys, lat, lon, h = _survey_truth()
    win = _windows_file(tmp_path, keys, 4)
    with pytest.raises(GnssFileError, match="missing.ubx"):
        gnss.read_raw_gnss(tmp_path / "missing.ubx", win)
    bad = tmp_path / "w.csv"
    bad.write_text("log_id,end,start,stop\n")
    with pytest.raises(GnssFormatError, match="header must be"):
        gnss.read_raw_gnss(_ubx_log(tmp_path, lat, lon, h), bad)
    bad.write_text("log_id,end,t_start_utc,t_end_utc\nlog0,a,2026-05-14T09:31:00Z,2026-05-14T09:30:00Z\n")
    with pytest.raises(GnssFormatError, match=r"w\.csv:2 \(log 'log0'\): t_end_utc must be after"):
        gnss.read_raw_gnss(_ubx_log(tmp_path, lat, lon, h), bad)
    dup = _windows_file(tmp_path, keys[:3] + [("log0", "a")], 4)
    with pytest.raises(GnssFormatError, match="measured twice"):
        gnss.read_raw_gnss(_ubx_log(tmp_path, lat, lon, h), dup)
    win = _windows_file(tmp_path, keys, 4)
    junk = tmp_path / "x.sbf"
    junk.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(GnssFormatError, match=r"x\.sbf is not a receiver log: 0 % of its 2048 bytes"):
        gnss.read_raw_gnss(junk, win)
