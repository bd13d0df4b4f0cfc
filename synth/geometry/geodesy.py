"""Coordinates on Earth: SWEREF 99, SWEREF 99 TM, WGS 84 and the local site frame.

Shared by :mod:`reconstruct` (GNSS surveys of log ends) and :mod:`field` (telling the operator
where the grasp is), so it lives at the bottom, next to :class:`synth.scene.pile.Georeference`.

Reference systems (EPSG codes, the ecosystem's own names):

* ``EPSG:4619`` — SWEREF 99 geodetic latitude/longitude [deg] on GRS80; ``EPSG:4977`` the same
  with ellipsoidal height [m]. RTK GNSS through SWEPOS delivers these.
* ``EPSG:3006`` — SWEREF 99 TM: Transverse Mercator, central meridian 15°E, scale 0.9996,
  false easting 500 000 m. Always handled as (easting, northing) — pyproj is used with
  ``always_xy=True`` everywhere (EPSG:3006 is northing-first natively).
* ``EPSG:4326`` — WGS 84. SWEREF 99 (ETRS89 realised at epoch 1999.5) and today's WGS 84 differ
  by roughly 0.5–1 m (plate drift); PROJ treats the two as identical (a null transformation), so
  WGS 84 values here are SWEREF 99 values with a WGS 84 label — fine for a web map, never for
  millimetre work.
* The *site frame*: a local East-North-Up frame [m] at a site origin (lat, lon, ellipsoidal h),
  computed by a PROJ ``cart`` + ``topocentric`` pipeline. Its ``y`` axis is TRUE north at the
  origin; SWEREF 99 TM's grid north differs from it by the meridian convergence (≈4.5° at
  64.1°N 20°E).
* The *pile frame*: see :mod:`synth.scene.pile`; ``Georeference.T_site_pile`` maps it into the site
  frame.

Heights are ellipsoidal (GRS80) unless a name says ``rh2000``. RH 2000 (EPSG:5613) heights need
Lantmäteriet's SWEN17_RH2000 geoid grid; without it PROJ would silently fall back to a "ballpark"
transformation that leaves the height unchanged (tens of metres wrong). Here that fails loudly
with :class:`GridUnavailableError` instead.

Angles: bearings/headings are degrees clockwise from north (grid north or true north, as the
name says); pile-frame angles are radians counter-clockwise from the pile ``+x`` axis.

All values are float64; transformers are built once and cached (pyproj ≥ 3.1 transformers are
thread-safe). pyproj is imported lazily.
"""

from __future__ import annotations

import functools
import math
import warnings
from typing import Any

import numpy as np

from synth.errors import SynthError
from synth.geometry.frames import apply_T, invert_T

EPSG_SWEREF99 = "EPSG:4619"  # SWEREF 99 lat/lon [deg]
EPSG_SWEREF99_3D = "EPSG:4977"  # SWEREF 99 lat/lon [deg] + ellipsoidal height [m]
EPSG_SWEREF99_TM = "EPSG:3006"  # SWEREF 99 TM easting/northing [m]
EPSG_WGS84 = "EPSG:4326"  # WGS 84 lat/lon [deg]
EPSG_RH2000 = "EPSG:5613"  # RH 2000 normal heights [m]
RH2000_GRID = "se_lantmateriet_SWEN17_RH2000.tif"  # the geoid grid PROJ needs for RH 2000

# GRS80, the ellipsoid of SWEREF 99.
GRS80_A_M = 6378137.0
GRS80_INV_F = 298.257222101

# Plausibility windows for Sweden (EPSG:3006's area of use is 10.03–24.17°E, 54.96–69.07°N).
SWEDEN_LAT_DEG = (55.0, 70.0)
SWEDEN_LON_DEG = (10.0, 24.5)
SWEREF_TM_EASTING_M = (180_000.0, 1_090_000.0)  # area of use projected, rounded outwards
SWEREF_TM_NORTHING_M = (6_080_000.0, 7_700_000.0)
ELLIPSOIDAL_H_M = (-100.0, 2_500.0)  # Swedish terrain + geoid (~15–45 m) + margin


class GeodesyError(SynthError):
    """A coordinate conversion failed or was asked for something it cannot do honestly."""


class CoordinateError(GeodesyError, ValueError):
    """A coordinate makes no sense for Sweden (swapped axes, wrong CRS, out of range)."""


class GridUnavailableError(GeodesyError):
    """A transformation needs a PROJ grid that is not installed (e.g. the RH 2000 geoid)."""


Origin = Any  # a synth.scene.pile.Georeference, or a (lat_deg, lon_deg, h_m) triple


# -- transformers (cached) ------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def _transformer(src: str, dst: str):
    from pyproj import Transformer

    return Transformer.from_crs(src, dst, always_xy=True)


@functools.lru_cache(maxsize=64)
def _enu_transformer(lat0: float, lon0: float, h0: float):
    from pyproj import Transformer

    pipeline = (
        "+proj=pipeline +step +proj=cart +ellps=GRS80 "
        f"+step +proj=topocentric +ellps=GRS80 +lat_0={lat0!r} +lon_0={lon0!r} +h_0={h0!r}"
    )
    return Transformer.from_pipeline(pipeline)


@functools.lru_cache(maxsize=1)
def _tm_proj():
    from pyproj import Proj

    return Proj(EPSG_SWEREF99_TM)


def _run(transformer, *coords: np.ndarray, inverse: bool = False) -> tuple[np.ndarray, ...]:
    from pyproj.exceptions import ProjError

    shape = np.broadcast(*coords).shape
    flat = [np.ascontiguousarray(np.broadcast_to(c, shape), dtype=np.float64).ravel() for c in coords]
    try:
        out = transformer.transform(
            *flat, direction="INVERSE" if inverse else "FORWARD", errcheck=True
        )
    except ProjError as exc:
        raise GeodesyError(f"coordinate transformation failed ({transformer.description}): {exc}") from exc
    return tuple(np.asarray(o, dtype=np.float64).reshape(shape) for o in out)


def _f64(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


# -- sanity checks --------------------------------------------------------------------------
def check_geodetic(lat_deg: Any, lon_deg: Any, what: str = "coordinate") -> None:
    """Raise :class:`CoordinateError` unless every (lat, lon) lies in Sweden's window.

    Detects swapped latitude/longitude (the most common mistake in hand-made files) and says so.
    """
    lat, lon = (a.ravel() for a in np.broadcast_arrays(_f64(lat_deg), _f64(lon_deg)))
    ok = ((lat >= SWEDEN_LAT_DEG[0]) & (lat <= SWEDEN_LAT_DEG[1])
          & (lon >= SWEDEN_LON_DEG[0]) & (lon <= SWEDEN_LON_DEG[1]))
    if ok.all():
        return
    i = int(np.flatnonzero(~ok)[0])
    la, lo = float(lat[i]), float(lon[i])
    if not (math.isfinite(la) and math.isfinite(lo)):
        raise CoordinateError(f"{what}: latitude/longitude must be finite, got ({la}, {lo})")
    if SWEDEN_LAT_DEG[0] <= lo <= SWEDEN_LAT_DEG[1] and SWEDEN_LON_DEG[0] <= la <= SWEDEN_LON_DEG[1]:
        raise CoordinateError(
            f"{what}: latitude {la}° / longitude {lo}° look swapped (Sweden is at latitude "
            f"{SWEDEN_LAT_DEG[0]:g}–{SWEDEN_LAT_DEG[1]:g}°N, longitude "
            f"{SWEDEN_LON_DEG[0]:g}–{SWEDEN_LON_DEG[1]:g}°E); swap the columns"
        )
    raise CoordinateError(
        f"{what}: (latitude {la}°, longitude {lo}°) is not in Sweden (expected latitude "
        f"{SWEDEN_LAT_DEG[0]:g}–{SWEDEN_LAT_DEG[1]:g}°N, longitude "
        f"{SWEDEN_LON_DEG[0]:g}–{SWEDEN_LON_DEG[1]:g}°E, SWEREF 99 degrees); check the CRS "
        "and the sign/units of the values"
    )


def check_sweref_tm(easting_m: Any, northing_m: Any, what: str = "coordinate") -> None:
    """Raise :class:`CoordinateError` unless every (E, N) lies in SWEREF 99 TM's area of use."""
    e, n = (a.ravel() for a in np.broadcast_arrays(_f64(easting_m), _f64(northing_m)))
    ok = ((e >= SWEREF_TM_EASTING_M[0]) & (e <= SWEREF_TM_EASTING_M[1])
          & (n >= SWEREF_TM_NORTHING_M[0]) & (n <= SWEREF_TM_NORTHING_M[1]))
    if ok.all():
        return
    i = int(np.flatnonzero(~ok)[0])
    ee, nn = float(e[i]), float(n[i])
    if not (math.isfinite(ee) and math.isfinite(nn)):
        raise CoordinateError(f"{what}: easting/northing must be finite, got ({ee}, {nn})")
    if (SWEREF_TM_NORTHING_M[0] <= ee <= SWEREF_TM_NORTHING_M[1]
            and SWEREF_TM_EASTING_M[0] <= nn <= SWEREF_TM_EASTING_M[1]):
        raise CoordinateError(
            f"{what}: easting {ee} m / northing {nn} m look swapped (EPSG:3006 lists "
            "northing first; loggrasp always writes easting, northing); swap the columns"
        )
    raise CoordinateError(
        f"{what}: (easting {ee} m, northing {nn} m) is outside SWEREF 99 TM's area of use "
        f"(easting {SWEREF_TM_EASTING_M[0]:.0f}–{SWEREF_TM_EASTING_M[1]:.0f} m, northing "
        f"{SWEREF_TM_NORTHING_M[0]:.0f}–{SWEREF_TM_NORTHING_M[1]:.0f} m); is it really EPSG:3006?"
    )


def check_height(h_m: Any, what: str = "coordinate") -> None:
    """Raise :class:`CoordinateError` unless every ellipsoidal height is plausible for Sweden."""
    hs = _f64(h_m).ravel()
    bad = ~((hs >= ELLIPSOIDAL_H_M[0]) & (hs <= ELLIPSOIDAL_H_M[1]))  # NaN is bad too
    if bad.any():
        h = float(hs[np.flatnonzero(bad)[0]])
        raise CoordinateError(
            f"{what}: ellipsoidal height {h} m is outside [{ELLIPSOIDAL_H_M[0]:g}, "
            f"{ELLIPSOIDAL_H_M[1]:g}] m; is it in millimetres or feet?"
        )


# -- SWEREF 99 <-> SWEREF 99 TM <-> WGS 84 --------------------------------------------------
def geodetic_to_tm(lat_deg: Any, lon_deg: Any, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """SWEREF 99 (EPSG:4619) latitude/longitude [deg] -> SWEREF 99 TM (easting, northing) [m].

    Ellipsoidal heights are unchanged by the projection (pass them through).
    """
    if check:
        check_geodetic(lat_deg, lon_deg)
    e, n = _run(_transformer(EPSG_SWEREF99, EPSG_SWEREF99_TM), _f64(lon_deg), _f64(lat_deg))
    return e, n


def tm_to_geodetic(easting_m: Any, northing_m: Any, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """SWEREF 99 TM (easting, northing) [m] -> SWEREF 99 (latitude, longitude) [deg]."""
    if check:
        check_sweref_tm(easting_m, northing_m)
    lon, lat = _run(_transformer(EPSG_SWEREF99, EPSG_SWEREF99_TM), _f64(easting_m), _f64(northing_m),
                    inverse=True)
    return lat, lon


def sweref_to_wgs84(lat_deg: Any, lon_deg: Any) -> tuple[np.ndarray, np.ndarray]:
    """SWEREF 99 -> WGS 84 (latitude, longitude) [deg]. PROJ's null transformation: the values
    are equal (the real difference, ~0.5–1 m of plate drift, is not modelled)."""
    lon, lat = _run(_transformer(EPSG_SWEREF99, EPSG_WGS84), _f64(lon_deg), _f64(lat_deg))
    return lat, lon


def wgs84_to_sweref(lat_deg: Any, lon_deg: Any) -> tuple[np.ndarray, np.ndarray]:
    """WGS 84 -> SWEREF 99 (latitude, longitude) [deg]; see :func:`sweref_to_wgs84`."""
    lon, lat = _run(_transformer(EPSG_WGS84, EPSG_SWEREF99), _f64(lon_deg), _f64(lat_deg))
    return lat, lon


# -- the site frame (local ENU) -------------------------------------------------------------
def origin_of(origin: Origin) -> tuple[float, float, float]:
    """``(lat_deg, lon_deg, h_m)`` of a :class:`~synth.scene.pile.Georeference` or a triple."""
    if hasattr(origin, "origin_lat_deg"):
        crs = getattr(origin, "crs", EPSG_SWEREF99)
        if crs not in (EPSG_SWEREF99, EPSG_SWEREF99_3D):
            raise CoordinateError(
                f"georeference origin CRS {crs!r} is not SWEREF 99 ({EPSG_SWEREF99}); "
                "re-survey or convert the origin to SWEREF 99"
            )
        lat, lon, h = origin.origin_lat_deg, origin.origin_lon_deg, origin.origin_h_m
    else:
        try:
            lat, lon, h = (float(v) for v in origin)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"site origin must be a Georeference or (lat_deg, lon_deg, h_m), got {origin!r}"
            ) from exc
    check_geodetic(lat, lon, "site origin")
    check_height(h, "site origin")
    return float(lat), float(lon), float(h)


def geodetic_to_site(origin: Origin, lat_deg: Any, lon_deg: Any, h_m: Any,
                     check: bool = True) -> np.ndarray:
    """SWEREF 99 (lat, lon [deg], ellipsoidal h [m]) -> site ENU points (..., 3) [m]."""
    if check:
        check_geodetic(lat_deg, lon_deg)
    e, n, u = _run(_enu_transformer(*origin_of(origin)), _f64(lon_deg), _f64(lat_deg), _f64(h_m))
    return np.stack([e, n, u], axis=-1)


def site_to_geodetic(origin: Origin, points_site: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Site ENU points (..., 3) [m] -> SWEREF 99 (lat [deg], lon [deg], ellipsoidal h [m])."""
    p = _points(points_site, "site points")
    lon, lat, h = _run(_enu_transformer(*origin_of(origin)), p[..., 0], p[..., 1], p[..., 2],
                       inverse=True)
    return lat, lon, h


def tm_to_site(origin: Origin, easting_m: Any, northing_m: Any, h_m: Any,
               check: bool = True) -> np.ndarray:
    """SWEREF 99 TM (E, N [m]) + ellipsoidal h [m] -> site ENU points (..., 3) [m]."""
    lat, lon = tm_to_geodetic(easting_m, northing_m, check=check)
    return geodetic_to_site(origin, lat, lon, h_m, check=False)


def site_to_tm(origin: Origin, points_site: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Site ENU points (..., 3) [m] -> SWEREF 99 TM (E [m], N [m], ellipsoidal h [m])."""
    lat, lon, h = site_to_geodetic(origin, points_site)
    e, n = geodetic_to_tm(lat, lon, check=False)
    return e, n, h


def _points(points: Any, what: str) -> np.ndarray:
    p = _f64(points)
    if p.ndim == 0 or p.shape[-1] != 3:
        raise ValueError(f"{what} must have shape (..., 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{what} must be finite")
    return p


def _georef(georef: Any) -> Any:
    if georef is None or not hasattr(georef, "T_site_pile"):
        raise GeodesyError(
            "this pile has no georeference (PileSpec.georef is None); survey the site with RTK "
            "GNSS or give the site origin and T_site_pile before asking for Earth coordinates"
        )
    return georef


def pile_to_site(georef: Any, points_pile: Any) -> np.ndarray:
    """Pile-frame points (..., 3) [m] -> site ENU (..., 3) [m] via ``georef.T_site_pile``."""
    return apply_T(_georef(georef).matrix(), _points(points_pile, "pile points"))


def site_to_pile(georef: Any, points_site: Any) -> np.ndarray:
    """Site ENU points (..., 3) [m] -> pile frame (..., 3) [m] (inverse of :func:`pile_to_site`)."""
    return apply_T(invert_T(_georef(georef).matrix()), _points(points_site, "site points"))


def pile_to_geodetic(georef: Any, points_pile: Any,
                     height: str = "ellipsoidal") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pile-frame points (..., 3) -> SWEREF 99 (lat [deg], lon [deg], h [m]).

    ``height="ellipsoidal"`` (default, GRS80) or ``"rh2000"`` (needs the SWEN17 geoid grid,
    raises :class:`GridUnavailableError` without it).
    """
    lat, lon, h = site_to_geodetic(georef, pile_to_site(georef, points_pile))
    return lat, lon, _height_out(lat, lon, h, height)


def pile_to_sweref_tm(georef: Any, points_pile: Any,
                      height: str = "ellipsoidal") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pile-frame points (..., 3) -> SWEREF 99 TM (E [m], N [m], h [m]); ``height`` as in
    :func:`pile_to_geodetic`."""
    lat, lon, h = site_to_geodetic(georef, pile_to_site(georef, points_pile))
    e, n = geodetic_to_tm(lat, lon, check=False)
    return e, n, _height_out(lat, lon, h, height)


def geodetic_to_pile(georef: Any, lat_deg: Any, lon_deg: Any, h_m: Any) -> np.ndarray:
    """SWEREF 99 (lat, lon [deg], ellipsoidal h [m]) -> pile-frame points (..., 3) [m]."""
    return site_to_pile(georef, geodetic_to_site(georef, lat_deg, lon_deg, h_m))


def sweref_tm_to_pile(georef: Any, easting_m: Any, northing_m: Any, h_m: Any) -> np.ndarray:
    """SWEREF 99 TM (E, N [m]) + ellipsoidal h [m] -> pile-frame points (..., 3) [m]."""
    return site_to_pile(georef, tm_to_site(georef, easting_m, northing_m, h_m))


def _height_out(lat: np.ndarray, lon: np.ndarray, h: np.ndarray, height: str) -> np.ndarray:
    if height == "ellipsoidal":
        return h
    if height == "rh2000":
        return ellipsoidal_to_rh2000(lat, lon, h)
    raise ValueError(f"height must be 'ellipsoidal' or 'rh2000', got {height!r}")


# -- meridian convergence and headings ------------------------------------------------------
def meridian_convergence_deg(lat_deg: Any, lon_deg: Any) -> np.ndarray:
    """Meridian convergence of SWEREF 99 TM [deg]: the angle from true north to grid north,
    clockwise positive (PROJ's ``get_factors().meridian_convergence``). Positive east of 15°E,
    where grid north lies clockwise of true north; ≈ (lon − 15°)·sin(lat) to first order."""
    lat, lon = np.broadcast_arrays(_f64(lat_deg), _f64(lon_deg))
    f = _tm_proj().get_factors(lon.ravel(), lat.ravel(), errcheck=True)
    return np.asarray(f.meridian_convergence, dtype=np.float64).reshape(lat.shape)


def heading_true_from_grid(heading_grid_deg: Any, lat_deg: Any, lon_deg: Any) -> np.ndarray:
    """Bearing from true north [deg, 0–360) of a direction whose grid bearing is given."""
    return (_f64(heading_grid_deg) + meridian_convergence_deg(lat_deg, lon_deg)) % 360.0


def heading_grid_from_true(heading_true_deg: Any, lat_deg: Any, lon_deg: Any) -> np.ndarray:
    """Bearing from SWEREF 99 TM grid north [deg, 0–360) of a direction with a true bearing."""
    return (_f64(heading_true_deg) - meridian_convergence_deg(lat_deg, lon_deg)) % 360.0


def pile_angle_to_bearings(georef: Any, angle_rad: float, point_pile: Any,
                           probe_m: float = 1.0) -> tuple[float, float]:
    """A pile-frame direction (angle from pile +x, counter-clockwise, in the pile's xy plane) at
    ``point_pile`` -> (grid bearing, true bearing) [deg, 0–360).

    The direction is mapped into the site frame and levelled (its horizontal part), a point
    ``probe_m`` along it is projected to SWEREF 99 TM, and the grid bearing is read from the two
    projected points; the true bearing adds the meridian convergence at ``point_pile``.
    """
    g = _georef(georef)
    p = _points(point_pile, "pile point").reshape(3)
    R = g.matrix()[:3, :3]
    d = R @ np.array([math.cos(angle_rad), math.sin(angle_rad), 0.0])
    horiz = np.array([d[0], d[1], 0.0])
    norm = float(np.linalg.norm(horiz))
    if norm < 1e-9:
        raise GeodesyError("the pile-frame direction is vertical in the site frame: no bearing")
    c_site = pile_to_site(g, p)
    pts = np.stack([c_site, c_site + probe_m * horiz / norm])
    e, n, _ = site_to_tm(g, pts)
    grid = math.degrees(math.atan2(e[1] - e[0], n[1] - n[0])) % 360.0
    lat, lon, _ = site_to_geodetic(g, c_site)
    true = float(heading_true_from_grid(grid, lat, lon))
    return grid, true


def grid_bearing_to_pile_angle(georef: Any, heading_grid_deg: float, point_pile: Any,
                               probe_m: float = 1.0) -> float:
    """Inverse of :func:`pile_angle_to_bearings`' grid bearing: the pile-frame angle [rad, from
    +x, counter-clockwise] whose levelled site direction has this grid bearing at ``point_pile``.
    Exact for tilted piles too (the pile xy-plane direction is found, not just rotated)."""
    g = _georef(georef)
    p = _points(point_pile, "pile point").reshape(3)
    e0, n0, h0 = pile_to_sweref_tm(g, p)
    b = math.radians(heading_grid_deg)
    e1, n1 = e0 + probe_m * math.sin(b), n0 + probe_m * math.cos(b)
    pts = tm_to_site(g, np.array([e0, e1]), np.array([n0, n1]), np.array([h0, h0]), check=False)
    h = pts[1] - pts[0]
    h[2] = 0.0
    h /= np.linalg.norm(h)
    R = g.matrix()[:3, :3]
    # The pile-plane direction d (d_z = 0) whose site image lies in the vertical plane through h:
    # d is perpendicular to m = R^T (h x up), and to the pile z axis.
    m = R.T @ np.cross(h, np.array([0.0, 0.0, 1.0]))
    d = np.cross(np.array([0.0, 0.0, 1.0]), m)
    if np.linalg.norm(d[:2]) < 1e-12:
        raise GeodesyError("the grid bearing is not reachable in the pile plane (pile on its side?)")
    if float((R @ d) @ h) < 0:
        d = -d
    return math.atan2(d[1], d[0])


# -- heights --------------------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def _rh2000_transformer():
    from pyproj import Transformer
    from pyproj.exceptions import ProjError
    from pyproj.transformer import TransformerGroup

    target = f"{EPSG_SWEREF99}+{EPSG_RH2000.split(':')[1]}"
    try:
        t = Transformer.from_crs(EPSG_SWEREF99_3D, target, always_xy=True, allow_ballpark=False)
    except ProjError as exc:
        missing = []
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "best transformation not available"
                group = TransformerGroup(EPSG_SWEREF99_3D, target, always_xy=True)
            missing = [g.short_name for op in group.unavailable_operations for g in op.grids
                       if not g.available]
        except ProjError:
            pass
        grids = ", ".join(missing) or RH2000_GRID
        raise GridUnavailableError(
            f"RH 2000 heights need the geoid grid {grids}, which PROJ cannot find; install it "
            f"(`projsync --file {RH2000_GRID}` into the PROJ data dir) or enable PROJ's network "
            "access, or use ellipsoidal heights (the default). Refusing to return the ellipsoidal "
            "height as if it were RH 2000."
        ) from exc
    if "ballpark" in t.description.lower():
        raise GridUnavailableError(
            f"PROJ offered only a ballpark transformation for RH 2000 ({t.description}); "
            f"install {RH2000_GRID} or use ellipsoidal heights"
        )
    return t


def rh2000_available() -> bool:
    """True when RH 2000 heights can be computed (the SWEN17_RH2000 grid is usable)."""
    try:
        _rh2000_transformer()
    except GridUnavailableError:
        return False
    return True


def ellipsoidal_to_rh2000(lat_deg: Any, lon_deg: Any, h_ell_m: Any) -> np.ndarray:
    """SWEREF 99 ellipsoidal height -> RH 2000 height [m] with the SWEN17_RH2000 geoid.

    Raises :class:`GridUnavailableError` when the grid is missing — never a ballpark value.
    """
    t = _rh2000_transformer()
    _, _, h = _run(t, _f64(lon_deg), _f64(lat_deg), _f64(h_ell_m))
    return h
