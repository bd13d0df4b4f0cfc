"""The chosen grasp in GNSS coordinates, for the operator: numbers, GeoJSON and a map picture.

Coordinates (see :mod:`synth.geometry.geodesy` for the frames):

* **SWEREF 99 TM** (``EPSG:3006``) easting/northing [m], rounded to the millimetre (float64):
  what the crane computer and Swedish maps use.
* **Heights** are ellipsoidal (GRS80) [m], NOT heights above sea level (RH 2000 needs a geoid
  grid that is not installed; :func:`synth.geometry.geodesy.ellipsoidal_to_rh2000` fails loudly).
* **Latitude/longitude** are SWEREF 99. SWEREF 99 and WGS 84 agree to about 0.5–1 m (plate drift
  since 1999.5, not modelled by PROJ); the WGS 84 GeoJSON below therefore carries SWEREF 99
  values — right for a web map, not for centimetre work: use the EPSG:3006 numbers for that.
* **Headings** of the grapple's closing axis (claw tip to claw tip) are degrees clockwise from
  north in ``[0, 180)`` (a grasp and its 180° turn are the same grasp): ``heading_grid_deg`` from
  SWEREF 99 TM grid north, ``heading_true_deg`` from true north (they differ by the meridian
  convergence, ≈4.5° at 64°N 20°E).

GeoJSON variants (format ``loggrasp.geojson`` 1.0, in the ``loggrasp`` foreign member):

* ``crs="EPSG:4326"`` (default): RFC 7946 GeoJSON, positions ``[lon, lat, h]`` in degrees
  (9 decimals ≈ 0.1 mm) — for web maps, phones, geojson.io.
* ``crs="EPSG:3006"``: positions ``[easting, northing, h]`` in metres with the (pre-RFC, 2008)
  ``"crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::3006"}}`` member that
  QGIS/GDAL read — for QGIS users over Lantmäteriet maps. Not RFC 7946 (which allows only WGS 84).

Features (``properties.kind``): ``log`` (LineString butt -> top; index, length_m, diameter_m,
top_diameter_m, target), ``stump`` and ``rock`` (Polygon footprints), ``grasp_rectangle``
(Polygon: ``width_m`` along the closing axis x ``RECT_WIDTH_M`` across; heading/width
properties) and ``grasp_point`` (Point with all :class:`GraspGeo` numbers).
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from field.errors import FieldError
from synth.geometry import geodesy
from synth.common.files import atomic_write_bytes
from synth.common.formats import VersionedJson
from synth.geometry.grasp import RECT_WIDTH_M, Grasp
from synth.scene.pile import PileSpec

GEOJSON_FORMAT = "loggrasp.geojson"
GEOJSON_VERSION = "1.0"
CRS_WGS84 = geodesy.EPSG_WGS84
CRS_TM = geodesy.EPSG_SWEREF99_TM
_TM_CRS_MEMBER = {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::3006"}}


class GeoExportError(FieldError, ValueError):
    """Earth coordinates of a pile or grasp could not be produced or failed validation (no
    georeference, coordinates outside Sweden, a malformed or newer-version GeoJSON file)."""


#: the ``loggrasp`` member of a GeoJSON file written here (format, version, CRS, plan)
GEOJSON = VersionedJson(GEOJSON_FORMAT, GEOJSON_VERSION, "GeoJSON", GeoExportError)


@dataclass(frozen=True)
class GraspGeo:
    """A grasp on Earth (see the module docstring for the conventions)."""

    easting_m: float  # SWEREF 99 TM [m], mm resolution
    northing_m: float  # SWEREF 99 TM [m], mm resolution
    h_ell_m: float  # ellipsoidal height (GRS80) of the grasp point [m], mm resolution
    lat_deg: float  # SWEREF 99 latitude [deg] (≈ WGS 84 to ~1 m)
    lon_deg: float  # SWEREF 99 longitude [deg]
    heading_grid_deg: float  # closing axis, clockwise from grid north [deg], [0, 180)
    heading_true_deg: float  # closing axis, clockwise from true north [deg], [0, 180)
    width_m: float  # opening width [m] (ground metres, not grid metres)
    convergence_deg: float  # meridian convergence at the point: true -> grid north [deg]
    crs: str = CRS_TM

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> str:
        """Two lines an operator can read out over the radio."""
        e = f"{self.easting_m:,.3f}".replace(",", " ")
        n = f"{self.northing_m:,.3f}".replace(",", " ")
        return (
            f"Grasp at E {e} m, N {n} m (SWEREF 99 TM), h {self.h_ell_m:.3f} m (ellipsoidal)\n"
            f"Closing axis {self.heading_grid_deg:.1f}° from grid north "
            f"({self.heading_true_deg:.1f}° from true north), opening {self.width_m:.2f} m"
        )


def _georef(pile_or_georef: Any) -> Any:
    g = getattr(pile_or_georef, "georef", pile_or_georef)
    if g is None or not hasattr(g, "T_site_pile"):
        raise GeoExportError(
            "the pile has no georeference (PileSpec.georef is None); survey the log ends with RTK "
            "GNSS (reconstruct.survey.gnss) or give the site origin before asking for GNSS coordinates"
        )
    return g


def grasp_to_gnss(grasp: Grasp, georef: Any, z_m: float) -> GraspGeo:
    """The grasp ``(x, y, phi, width)`` at pile-frame height ``z_m`` [m] in GNSS coordinates.

    The one conversion from the pile frame to SWEREF 99 TM: the field trial's command, the
    GeoJSON / map exports and ``GraspCommand.from_pile_grasp`` all use it (inverse:
    :func:`tm_to_grasp`).

    ``georef``: a :class:`~synth.scene.pile.Georeference` (or a pile carrying one)."""
    g = _georef(georef)
    if not math.isfinite(z_m):
        raise ValueError(f"z_m must be finite, got {z_m}")
    p = np.array([grasp.x_m, grasp.y_m, z_m], dtype=np.float64)
    try:
        e, n, h = geodesy.pile_to_sweref_tm(g, p)
        lat, lon, _ = geodesy.pile_to_geodetic(g, p)
        grid, true = geodesy.pile_angle_to_bearings(g, grasp.phi_rad, p)
        gamma = float(geodesy.meridian_convergence_deg(lat, lon))
    except geodesy.GeodesyError as exc:
        raise GeoExportError(f"cannot place the grasp on Earth: {exc}") from exc
    return GraspGeo(
        easting_m=round(float(e), 3), northing_m=round(float(n), 3), h_ell_m=round(float(h), 3),
        lat_deg=float(lat), lon_deg=float(lon),
        heading_grid_deg=grid % 180.0, heading_true_deg=true % 180.0,
        width_m=float(grasp.width_m), convergence_deg=gamma,
    )


def tm_to_grasp(easting_m: float, northing_m: float, h_ell_m: float, heading_grid_deg: float, width_m: float,
                georef: Any) -> tuple[Grasp, float]:
    """Inverse of :func:`grasp_to_gnss`: ``(Grasp in the pile frame, z_m)`` of a grasp given in
    SWEREF 99 TM (easting, northing [m]), ellipsoidal height [m] and grid heading of the closing
    axis [deg]. The one conversion from TM numbers to the pile frame: the laptop
    (:func:`gnss_to_grasp`) and the controller twin (``GraspCommand.to_pile_grasp``) use it."""
    g = _georef(georef)
    try:
        p = geodesy.sweref_tm_to_pile(g, easting_m, northing_m, h_ell_m)
        p = np.asarray(p, dtype=float).reshape(3)
        phi = float(geodesy.grid_bearing_to_pile_angle(g, heading_grid_deg, p))
    except geodesy.GeodesyError as exc:
        raise GeoExportError(f"cannot map the GNSS grasp into the pile frame: {exc}") from exc
    return Grasp(float(p[0]), float(p[1]), phi, width_m), float(p[2])


def gnss_to_grasp(geo: GraspGeo, georef: Any) -> tuple[Grasp, float]:
    """Inverse of :func:`grasp_to_gnss`: ``(Grasp in the pile frame, z_m)`` from the TM numbers
    and the grid heading (:func:`tm_to_grasp`)."""
    return tm_to_grasp(geo.easting_m, geo.northing_m, geo.h_ell_m, geo.heading_grid_deg, geo.width_m, georef)


# -- geometry of a pile in the pile frame ----------------------------------------------------
def _log_outline(log) -> np.ndarray:
    """Plan-view outline (4, 3) of a (tapered) log in the pile frame."""
    butt, top = log.endpoints_m()
    a = top - butt
    side = np.array([-a[1], a[0], 0.0])
    ns = np.linalg.norm(side)
    side = side / ns if ns > 1e-9 else np.array([0.0, 1.0, 0.0])
    rb, rt = log.diameter_m / 2, log.top_d_m / 2
    return np.array([butt - side * rb, top - side * rt, top + side * rt, butt + side * rb])


def _stump_outline(pile: PileSpec, s, n: int = 24) -> np.ndarray:
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    x = s.position_m[0] + s.bottom_radius_m * np.cos(t)
    y = s.position_m[1] + s.bottom_radius_m * np.sin(t)
    z = np.full(n, float(pile.terrain.height_at(s.position_m[0], s.position_m[1])))
    return np.stack([x, y, z], axis=1)


def _rock_outline(r) -> np.ndarray:
    from scipy.spatial import ConvexHull

    from synth.scene.pile import quat_to_matrix

    v = np.asarray(r.vertices_m, float) @ quat_to_matrix(r.orientation).T + np.asarray(r.position_m)
    hull = ConvexHull(v[:, :2])
    return v[hull.vertices]


def _grasp_z(pile: PileSpec, grasp: Grasp, z_m: float | None) -> float:
    return float(pile.terrain.height_at(grasp.x_m, grasp.y_m)) if z_m is None else float(z_m)


# -- GeoJSON --------------------------------------------------------------------------------
def pile_geojson(pile: PileSpec, grasp: Grasp | None = None, plan_extra: Mapping[str, Any] | None = None,
                 *, crs: str = CRS_WGS84, grasp_z_m: float | None = None) -> dict[str, Any]:
    """A GeoJSON FeatureCollection of the pile (and grasp) — see the module docstring.

    ``plan_extra``: JSON-serialisable planner information, stored as ``loggrasp.plan`` and added
    to the grasp features' properties; its ``target_logs`` (log indices) mark logs as targets.
    ``grasp_z_m``: pile-frame height of the grasp point (default: the terrain under it)."""
    if crs not in (CRS_WGS84, CRS_TM):
        raise ValueError(f"crs must be {CRS_WGS84} (RFC 7946) or {CRS_TM} (QGIS), got {crs!r}")
    g = _georef(pile)
    plan = dict(plan_extra or {})
    targets = {int(i) for i in plan.get("target_logs", ())}

    def pos(points_pile: np.ndarray) -> list[list[float]]:
        pts = np.asarray(points_pile, float).reshape(-1, 3)
        try:
            if crs == CRS_TM:
                e, n, h = geodesy.pile_to_sweref_tm(g, pts)
                return [[round(float(a), 3), round(float(b), 3), round(float(c), 3)] for a, b, c in zip(e, n, h)]
            lat, lon, h = geodesy.pile_to_geodetic(g, pts)
            lat, lon = geodesy.sweref_to_wgs84(lat, lon)
            return [[round(float(b), 9), round(float(a), 9), round(float(c), 3)] for a, b, c in zip(lat, lon, h)]
        except geodesy.GeodesyError as exc:
            raise GeoExportError(f"cannot place the pile on Earth: {exc}") from exc

    def ring(points_pile: np.ndarray) -> list[list[list[float]]]:
        c = pos(points_pile)
        xy = np.array([p[:2] for p in c])
        area2 = float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))
        if area2 < 0:  # RFC 7946: exterior rings counter-clockwise
            c = c[::-1]
        return [c + [c[0]]]

    feats: list[dict[str, Any]] = []
    for i, log in enumerate(pile.logs):
        feats.append(_feature("LineString", pos(np.stack(log.endpoints_m())), {
            "kind": "log", "index": i, "length_m": round(log.length_m, 4),
            "diameter_m": round(log.diameter_m, 4), "top_diameter_m": round(log.top_d_m, 4),
            "target": i in targets,
        }))
    for i, s in enumerate(pile.stumps):
        feats.append(_feature("Polygon", ring(_stump_outline(pile, s)), {
            "kind": "stump", "index": i, "radius_m": s.bottom_radius_m, "height_m": s.height_m,
        }))
    for i, r in enumerate(pile.rocks):
        feats.append(_feature("Polygon", ring(_rock_outline(r)), {
            "kind": "rock", "index": i, "size_m": round(r.size_m(), 3),
        }))
    if grasp is not None:
        z = _grasp_z(pile, grasp, grasp_z_m)
        geo = grasp_to_gnss(grasp, g, z)
        common = {"heading_grid_deg": round(geo.heading_grid_deg, 3),
                  "heading_true_deg": round(geo.heading_true_deg, 3), "width_m": geo.width_m, **plan}
        rect = np.column_stack([grasp.rectangle(RECT_WIDTH_M), np.full(4, z)])
        feats.append(_feature("Polygon", ring(rect), {"kind": "grasp_rectangle", **common}))
        feats.append(_feature("Point", pos(np.array([grasp.x_m, grasp.y_m, z]))[0], {
            "kind": "grasp_point", **geo.to_dict(), **plan,
        }))
    fc: dict[str, Any] = {
        "type": "FeatureCollection",
        "loggrasp": {
            "format": GEOJSON_FORMAT, "format_version": GEOJSON_VERSION, "crs": crs,
            "heights": "ellipsoidal (GRS80) [m]",
            "datum": ("SWEREF 99 values labelled WGS 84 (they differ by ~0.5-1 m)"
                      if crs == CRS_WGS84 else "SWEREF 99 TM easting, northing [m]"),
            "plan": plan,
        },
        "features": feats,
    }
    if crs == CRS_TM:
        fc["crs"] = _TM_CRS_MEMBER
    validate_geojson(fc)
    return fc


def _feature(kind: str, coords: Any, props: dict[str, Any]) -> dict[str, Any]:
    return {"type": "Feature", "geometry": {"type": kind, "coordinates": coords}, "properties": props}


def _positions(geom: Mapping[str, Any]) -> list[list[float]]:
    t, c = geom.get("type"), geom.get("coordinates")
    if t == "Point":
        return [c]
    if t == "LineString":
        return list(c)
    if t == "Polygon":
        out = []
        for r in c:
            if len(r) < 4 or r[0] != r[-1]:
                raise GeoExportError("a GeoJSON Polygon ring must be closed and have >= 4 positions")
            out += r
        return out
    raise GeoExportError(f"unsupported GeoJSON geometry type {t!r}")


def validate_geojson(fc: Mapping[str, Any]) -> None:
    """Check a loggrasp FeatureCollection: structure, JSON round trip, closed rings and every
    position inside Sweden in its CRS. Raises :class:`GeoExportError`."""
    if fc.get("type") != "FeatureCollection" or not isinstance(fc.get("features"), list):
        raise GeoExportError("not a GeoJSON FeatureCollection")
    meta = fc.get("loggrasp", {})
    crs = meta.get("crs", CRS_WGS84)
    if crs == CRS_TM and fc.get("crs") != _TM_CRS_MEMBER:
        raise GeoExportError("an EPSG:3006 FeatureCollection needs its 'crs' member for QGIS")
    if crs not in (CRS_WGS84, CRS_TM):
        raise GeoExportError(f"unknown CRS {crs!r} in the loggrasp member")
    try:
        if json.loads(json.dumps(fc, allow_nan=False)) != fc:
            raise GeoExportError("the FeatureCollection does not survive a JSON round trip")
    except (TypeError, ValueError) as exc:
        if isinstance(exc, GeoExportError):
            raise
        raise GeoExportError(f"the FeatureCollection is not valid JSON: {exc}") from exc
    for i, f in enumerate(fc["features"]):
        if f.get("type") != "Feature" or "geometry" not in f:
            raise GeoExportError(f"feature {i} is not a GeoJSON Feature")
        pts = np.array(_positions(f["geometry"]), dtype=float)
        what = f"feature {i} ({f.get('properties', {}).get('kind', '?')})"
        try:
            if crs == CRS_TM:
                geodesy.check_sweref_tm(pts[:, 0], pts[:, 1], what)
            else:
                geodesy.check_geodetic(pts[:, 1], pts[:, 0], what)
        except geodesy.CoordinateError as exc:
            raise GeoExportError(str(exc)) from exc


def write_geojson(pile: PileSpec, path: str | Path, grasp: Grasp | None = None,
                  plan_extra: Mapping[str, Any] | None = None, *, crs: str = CRS_WGS84,
                  grasp_z_m: float | None = None) -> Path:
    """Write :func:`pile_geojson` atomically to ``path`` (``.geojson``). Returns the path."""
    fc = pile_geojson(pile, grasp, plan_extra, crs=crs, grasp_z_m=grasp_z_m)
    path = Path(path)
    atomic_write_bytes(path, json.dumps(fc, indent=1).encode("utf-8"))
    return path


def write_geojson_pair(pile: PileSpec, out_dir: str | Path, grasp: Grasp | None = None,
                       plan_extra: Mapping[str, Any] | None = None, *, stem: str = "pile",
                       grasp_z_m: float | None = None) -> tuple[Path, Path]:
    """Write both variants: ``<stem>.geojson`` (WGS 84, RFC 7946) and
    ``<stem>.sweref99tm.geojson`` (EPSG:3006, for QGIS). Returns both paths."""
    out = Path(out_dir)
    a = write_geojson(pile, out / f"{stem}.geojson", grasp, plan_extra, crs=CRS_WGS84, grasp_z_m=grasp_z_m)
    b = write_geojson(pile, out / f"{stem}.sweref99tm.geojson", grasp, plan_extra, crs=CRS_TM,
                      grasp_z_m=grasp_z_m)
    return a, b


def read_geojson(path: str | Path) -> dict[str, Any]:
    """Read and validate a GeoJSON file written by :func:`write_geojson`."""
    path = Path(path)
    try:
        fc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise GeoExportError(f"cannot read {path}: {exc}") from exc
    except json.JSONDecodeError as exc:
        raise GeoExportError(f"{path} is not valid JSON: {exc}") from exc
    meta = fc.get("loggrasp") if isinstance(fc, dict) else None
    if not isinstance(meta, dict):
        raise GeoExportError(f"{path} is not a loggrasp GeoJSON (no 'loggrasp' member)")
    GEOJSON.check(meta, path)
    try:
        validate_geojson(fc)
    except GeoExportError as exc:
        raise GeoExportError(f"{path}: {exc}") from exc
    return fc


# -- the map picture ------------------------------------------------------------------------
def draw_grasp_map(pile: PileSpec, grasp: Grasp | None, path: str | Path, *,
                   grasp_z_m: float | None = None, target_logs: Sequence[int] = (),
                   title: str | None = None, dpi: int = 150) -> Path:
    """A PNG map of the pile in SWEREF 99 TM metres: log outlines and axes (numbered, targets
    in ``target_logs`` highlighted), obstacles, the grasp rectangle and point, a grid-north
    and a true-north arrow, a 1 m scale bar and the grasp's numbers. Written atomically."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    g = _georef(pile)

    def tm(points_pile: np.ndarray) -> np.ndarray:
        e, n, _ = geodesy.pile_to_sweref_tm(g, np.asarray(points_pile, float).reshape(-1, 3))
        return np.column_stack([e, n])

    fig = Figure(figsize=(10.0, 8.6), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.10, 0.20, 0.62, 0.72))  # the map; compass and legend to its right
    ax.set_anchor("W")
    _map_obstacles(ax, pile, tm)
    _map_logs(ax, pile, tm, {int(t) for t in target_logs})
    extent_pts = [np.asarray(a.get_xy()) for a in ax.patches[1:]]  # all but the scanned area
    info = ""
    if grasp is not None:
        info, pts = _map_grasp(ax, pile, g, grasp, grasp_z_m, tm)
        extent_pts += pts
    centre = _map_frame(ax, np.concatenate(extent_pts))
    _map_north_arrows(fig, ax, centre)
    fig.legend(*ax.get_legend_handles_labels(), loc="upper left", bbox_to_anchor=(0.74, 0.62),
               fontsize=8, frameon=True)
    ax.set_title(title or f"Log pile — {len(pile.logs)} logs (heights ellipsoidal, GRS80)", fontsize=11)
    if info:
        fig.text(0.5, 0.035, info, ha="center", va="bottom", fontsize=9.5, family="monospace",
                 bbox={"fc": "#fff4f4", "ec": "#c00000", "boxstyle": "round,pad=0.5"})
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi,
                metadata={"Software": f"loggrasp field.geo {GEOJSON_VERSION}",
                          "Description": "grasp map, SWEREF 99 TM (EPSG:3006)"})
    path = Path(path)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _map_obstacles(ax, pile: PileSpec, tm) -> None:
    """The scanned area's outline (the first patch), stumps and rocks."""
    from matplotlib.patches import Polygon as MplPolygon

    half = pile.terrain.extent_m / 2
    patch = tm(np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]]))
    ax.add_patch(MplPolygon(patch, closed=True, fill=False, ls="--", lw=0.8, ec="0.5",
                            label="scanned area"))
    for i, s in enumerate(pile.stumps):
        ax.add_patch(MplPolygon(tm(_stump_outline(pile, s)), closed=True, fc="0.35", ec="k", lw=0.6,
                                label="stump / rock" if i == 0 else None))
    for i, r in enumerate(pile.rocks):
        ax.add_patch(MplPolygon(tm(_rock_outline(r)), closed=True, fc="0.55", ec="k", lw=0.6,
                                label="stump / rock" if (i == 0 and not pile.stumps) else None))


def _map_logs(ax, pile: PileSpec, tm, targets: set[int]) -> None:
    """Log outlines (lowest first, targets highlighted), axes and numbers near the butts."""
    from matplotlib.patches import Polygon as MplPolygon

    label_done: set[str] = set()
    for i in sorted(range(len(pile.logs)), key=lambda j: pile.logs[j].centre_m[2]):  # low first
        log = pile.logs[i]
        tgt = i in targets
        label = "target log" if tgt else "log"
        outline = tm(_log_outline(log))
        ax.add_patch(MplPolygon(outline, closed=True, fc="#e0a030" if tgt else "#d9c7a0",
                                ec="#6b4f1d", lw=1.4 if tgt else 0.8,
                                label=None if label in label_done else label))
        label_done.add(label)
        ends = tm(np.stack(log.endpoints_m()))
        ax.plot(ends[:, 0], ends[:, 1], color="#6b4f1d", lw=0.8, ls=":")
        tag = ends[0] + 0.12 * (ends[1] - ends[0])  # near the butt: labels of crossing logs part
        ax.text(tag[0], tag[1], str(i), ha="center", va="center", fontsize=8, weight="bold",
                bbox={"boxstyle": "circle,pad=0.15", "fc": "white", "ec": "#6b4f1d", "lw": 0.6})


def _map_grasp(ax, pile: PileSpec, g, grasp: Grasp, grasp_z_m: float | None, tm) -> tuple[str, list[np.ndarray]]:
    """The grasp rectangle, open claw tips and grasp point; (its numbers, the points drawn)."""
    from matplotlib.patches import Polygon as MplPolygon

    z = _grasp_z(pile, grasp, grasp_z_m)
    geo = grasp_to_gnss(grasp, g, z)
    rect = tm(np.column_stack([grasp.rectangle(RECT_WIDTH_M), np.full(4, z)]))
    ax.add_patch(MplPolygon(rect, closed=True, fc=(0.85, 0.1, 0.1, 0.25), ec="#c00000", lw=2.0,
                            label="grasp (claws close\nalong the long side)"))
    c = np.array([grasp.x_m, grasp.y_m, z])
    a = np.r_[grasp.closing_axis(), 0.0] * grasp.width_m / 2
    tips = tm(np.stack([c - a, c + a]))  # the claw tips when open
    ax.plot(tips[:, 0], tips[:, 1], color="#c00000", lw=1.2)
    ax.plot(tips[:, 0], tips[:, 1], "v", color="#c00000", ms=6)
    ax.plot([geo.easting_m], [geo.northing_m], "+", color="k", ms=14, mew=2, label="grasp point")
    return geo.summary(), [rect, tips]


def _map_frame(ax, points: np.ndarray) -> np.ndarray:
    """Limits around ``points`` with a margin (at least 3 m square; the scanned area's outline
    shows where it falls inside), metre ticks, labels and a 1 m scale bar; the map's centre."""
    from planner.pictures import metre_ticks
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    half_span = max(1.5, float(np.max(hi - lo)) / 2 + 0.6)
    lo, hi = centre - half_span, centre + half_span
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    step = 1.0 if half_span <= 6 else 5.0
    metre_ticks(ax, step)
    ax.grid(True, lw=0.3, color="0.8")
    ax.set_xlabel("Easting [m], SWEREF 99 TM (EPSG:3006)")
    ax.set_ylabel("Northing [m], SWEREF 99 TM")
    ax.add_artist(AnchoredSizeBar(ax.transData, 1.0, "1 m", "lower left", pad=0.6, sep=4,
                                  frameon=True, size_vertical=0.04))
    return centre


def _map_north_arrows(fig, ax, centre: np.ndarray) -> None:
    """Grid north is up; true north lies at grid bearing -convergence at the map's centre."""
    lat_c, lon_c = geodesy.tm_to_geodetic(centre[0], centre[1])
    gamma = float(geodesy.meridian_convergence_deg(lat_c, lon_c))
    fig.text(0.86, 0.925, "North", ha="center", fontsize=10, weight="bold")
    ax.annotate("grid", xy=(0.82, 0.90), xytext=(0.82, 0.72), xycoords="figure fraction",
                ha="center", va="top", fontsize=9, weight="bold",
                arrowprops={"arrowstyle": "-|>", "lw": 2.2, "color": "k"})
    b = math.radians(-gamma)
    L = 0.18
    side = "W" if gamma > 0 else "E"
    ax.annotate(f"true\n({abs(gamma):.2f}° {side}\nof grid N)", xy=(0.91 + L * math.sin(b) * 8.6 / 10.0, 0.72 + L * math.cos(b)),
                xytext=(0.91, 0.72), xycoords="figure fraction", ha="center", va="top", fontsize=8,
                color="0.3", arrowprops={"arrowstyle": "-|>", "lw": 1.4, "color": "0.3"})
