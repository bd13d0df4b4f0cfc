"""field.geo: the grasp in SWEREF 99 TM / lat-lon, GeoJSON export and the grasp map PNG."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from field import geo
from field.errors import FieldError
from synth.geometry import geodesy
from synth.geometry.frames import make_T, rot_z
from synth.geometry.grasp import Grasp
from synth.scene.pile import Georeference, LogSpec, PileSpec, RockSpec, StumpSpec, TerrainSpec


def _georef(yaw=0.5, tilt=0.0, lat=64.1, lon=20.0):
    R = rot_z(yaw)
    if tilt:
        c, s = math.cos(tilt), math.sin(tilt)
        R = R @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    T = make_T(R, (0.3, -0.2, 0.05))
    return Georeference(lat, lon, 250.0, tuple(tuple(float(v) for v in r) for r in T))


def _pile(georef=None):
    logs = (
        LogSpec.from_endpoints((-1.8, 0.4, 0.15), (1.9, 0.9, 0.15), 0.28, 0.2),
        LogSpec.from_endpoints((-1.5, -0.3, 0.15), (1.7, 0.1, 0.15), 0.3),
        LogSpec.from_endpoints((-0.6, -1.9, 0.12), (0.5, -1.2, 0.1), 0.18),
    )
    rock = RockSpec((-1.8, 1.6, 0.1), (0, 0, 0, 1),
                    ((0, 0, 0), (0.3, 0, 0), (0, 0.25, 0), (0.1, 0.1, 0.2), (0.25, 0.2, 0.05)))
    return PileSpec(TerrainSpec(), logs, stumps=(StumpSpec((1.5, -1.6), 0.4, 0.25, 0.2),), rocks=(rock,),
                    georef=_georef() if georef is None else georef)


GRASP = Grasp(0.1, 0.3, math.radians(80), 1.1)


@pytest.mark.parametrize("tilt", [0.0, 0.08])
def test_grasp_gnss_round_trip_below_a_millimetre(tilt):
    g = _georef(yaw=-0.9, tilt=tilt)
    rng = np.random.default_rng(0)
    for _ in range(20):
        gr = Grasp(float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)), float(rng.uniform(-3, 3)),
                   float(rng.uniform(0.3, 1.55)))
        z = float(rng.uniform(0, 1))
        gg = geo.grasp_to_gnss(gr, g, z)
        assert 0 <= gg.heading_grid_deg < 180 and 0 <= gg.heading_true_deg < 180
        back, z2 = geo.gnss_to_grasp(gg, g)
        assert math.dist((back.x_m, back.y_m, z2), (gr.x_m, gr.y_m, z)) < 1e-3
        # claw tips agree to < 1 mm: the angle error times the half width
        dphi = abs(math.remainder(back.phi_rad - gr.phi_rad, math.pi))
        assert dphi * gr.width_m / 2 < 1e-3 and back.width_m == gr.width_m


def test_grasp_numbers_against_independent_computation():
    yaw = 0.5
    g = _georef(yaw=yaw)
    gg = geo.grasp_to_gnss(GRASP, g, 0.3)
    # Position: pile -> site by hand, then the ENU->geodetic->TM chain.
    p_site = make_T(rot_z(yaw), (0.3, -0.2, 0.05)) @ np.array([GRASP.x_m, GRASP.y_m, 0.3, 1.0])
    lat, lon, h = geodesy.site_to_geodetic((64.1, 20.0, 250.0), p_site[:3])
    e, n = geodesy.geodetic_to_tm(lat, lon)
    assert abs(gg.easting_m - float(e)) <= 5e-4 and abs(gg.northing_m - float(n)) <= 5e-4
    assert abs(gg.h_ell_m - float(h)) <= 5e-4
    assert gg.easting_m == round(gg.easting_m, 3)  # mm resolution
    # Heading: the site y axis is true north, so true bearing = 90° - (phi + yaw) (mod 180);
    # grid = true - convergence, convergence ~ (lon - 15°) sin(lat) = 4.50° here.
    true = (90.0 - math.degrees(GRASP.phi_rad + yaw)) % 180.0
    assert abs(gg.heading_true_deg - true) < 1e-3
    first_order = (gg.lon_deg - 15.0) * math.sin(math.radians(gg.lat_deg))
    assert abs(gg.convergence_deg - first_order) < 0.01
    assert abs(((gg.heading_true_deg - gg.heading_grid_deg) % 180.0) - gg.convergence_deg) < 1e-6
    assert "743 495" in gg.summary() and "grid north" in gg.summary()


def test_no_georeference_and_outside_sweden():
    pile = replace(_pile(), georef=None)
    with pytest.raises(geo.GeoExportError, match="no georeference") as ei:
        geo.pile_geojson(pile)
    assert isinstance(ei.value, FieldError)
    with pytest.raises(geo.GeoExportError, match="not in Sweden"):
        geo.grasp_to_gnss(GRASP, _georef(lat=48.0, lon=11.0), 0.0)


def test_geojson_wgs84_and_tm_variants(tmp_path):
    pile = _pile()
    wgs_path, tm_path = geo.write_geojson_pair(pile, tmp_path, GRASP, {"target_logs": [0, 1], "p_success": 0.8},
                                               grasp_z_m=0.3)
    fc = json.loads(wgs_path.read_text())
    fc_tm = json.loads(tm_path.read_text())
    assert "crs" not in fc and fc_tm["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::3006"
    kinds = [f["properties"]["kind"] for f in fc["features"]]
    assert kinds == ["log", "log", "log", "stump", "rock", "grasp_rectangle", "grasp_point"]
    logs = [f for f in fc["features"] if f["properties"]["kind"] == "log"]
    assert [f["properties"]["target"] for f in logs] == [True, True, False]
    assert logs[0]["properties"]["length_m"] == pytest.approx(pile.logs[0].length_m, abs=1e-4)
    for f in fc["features"]:  # RFC 7946: lon, lat(, h) — inside Sweden
        for lon, lat, h in geo._positions(f["geometry"]):
            assert 55 < lat < 70 and 10 < lon < 24.5 and 200 < h < 300
        if f["geometry"]["type"] == "Polygon":
            ring = np.array(f["geometry"]["coordinates"][0])[:, :2]
            area2 = np.sum(ring[:-1, 0] * ring[1:, 1] - ring[1:, 0] * ring[:-1, 1])
            assert area2 > 0  # counter-clockwise exterior ring
    # the two variants describe the same points
    for f, ft in zip(fc["features"], fc_tm["features"]):
        a = np.array(geo._positions(f["geometry"]))
        b = np.array(geo._positions(ft["geometry"]))
        lat, lon = a[:, 1], a[:, 0]
        e, n = geodesy.geodetic_to_tm(lat, lon)
        got = np.column_stack([e, n])
        ref = b[:, :2]
        # rings may be reversed independently; compare as sets of points
        dist = np.linalg.norm(got[:, None] - ref[None], axis=-1).min(axis=1)
        assert dist.max() < 1e-3
    gp = fc["features"][-1]["properties"]
    assert gp["p_success"] == 0.8 and 0 <= gp["heading_grid_deg"] < 180
    rect = fc["features"][-2]
    assert rect["properties"]["width_m"] == GRASP.width_m
    assert geo.read_geojson(wgs_path) == fc and geo.read_geojson(tm_path) == fc_tm


def test_geojson_validation_errors(tmp_path):
    fc = geo.pile_geojson(_pile())
    bad = json.loads(json.dumps(fc))
    bad["features"][0]["geometry"]["coordinates"][0][:2] = bad["features"][0]["geometry"]["coordinates"][0][1::-1]
    with pytest.raises(geo.GeoExportError, match="swapped"):
        geo.validate_geojson(bad)
    newer = json.loads(json.dumps(fc))
    newer["loggrasp"]["format_version"] = "2.0"
    p = tmp_path / "n.geojson"
    p.write_text(json.dumps(newer))
    with pytest.raises(geo.GeoExportError, match="version '2.0' is not supported"):
        geo.read_geojson(p)
    with pytest.raises(ValueError, match="crs must be"):
        geo.pile_geojson(_pile(), crs="EPSG:32633")


def test_grasp_map_png(tmp_path):
    path = geo.draw_grasp_map(_pile(), GRASP, tmp_path / "map.png", grasp_z_m=0.3, target_logs=(0, 1))
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    import matplotlib.image as mpimg

    img = mpimg.imread(path)
    assert img.shape[0] > 1000 and img.shape[1] > 1000
    # red grasp rectangle and dark stump pixels are present
    rgb = img[..., :3]
    red = (rgb[..., 0] > 0.7) & (rgb[..., 1] < 0.2) & (rgb[..., 2] < 0.2)
    assert red.sum() > 200
    path2 = geo.draw_grasp_map(_pile(), None, tmp_path / "nograsp.png")
    assert path2.stat().st_size > 10_000
