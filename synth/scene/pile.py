"""The simulator pile: one versioned, JSON-serialisable description of a scene.

A :class:`PileSpec` is what every part of loggrasp exchanges: the generator writes it, the
reconstruction writes it from a field scan, the twin loads it, the planner's observations are
rendered from it. This module is the only reader and writer of ``pile.json``.

Frames and units (written once, here and in :mod:`synth.geometry.frames`):

* The *pile frame* is right-handed, metres, z up, origin at the centre of the square terrain
  patch at height datum 0. ``x`` points to the image's right, ``y`` to the image's top.
* Orientations are quaternions ``(x, y, z, w)`` (pybullet's order) rotating body-local
  coordinates into the pile frame. A log's axis is its local ``x`` axis; its butt end (the end
  of ``diameter_m``) is at local ``-x``.
* Log ``i`` in ``logs`` is log ``i`` everywhere: in masks (instance value ``i + 1``), in target
  subsets, in reports.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from synth.common.formats import VersionedJson
from synth.errors import PileFormatError

#: Format of ``pile.json``. Readers accept any minor version of the same major version.
PILE_FORMAT_VERSION = "1.0"
PILE_FORMAT_NAME = "loggrasp.pile"
PILE = VersionedJson(PILE_FORMAT_NAME, PILE_FORMAT_VERSION, "pile", PileFormatError,
                     fix="upgrade loggrasp or re-export the pile", filename="pile.json")

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


def _finite(name: str, values: Any) -> None:
    arr = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {values!r}")


@dataclass(frozen=True)
class TerrainSpec:
    """A square heightfield patch centred on the pile frame origin.

    Either procedural (Perlin noise from ``seed``) or explicit (``heights_m`` given, e.g. by the
    reconstruction): explicit heights win when present.
    """

    seed: int = 0
    extent_m: float = 5.0  # side of the square patch [m]
    resolution: int = 64  # physics heightfield samples per side [-]
    amplitude_m: float = 0.15  # peak-to-peak scale of the Perlin relief [m]
    feature_size_m: float = 2.0  # wavelength of the coarsest noise octave [m]
    colour: Vec3 = (0.45, 0.40, 0.30)  # default RGB in [0, 1]
    heights_m: tuple[tuple[float, ...], ...] | None = None  # rows along +y, columns along +x [m]

    def __post_init__(self) -> None:
        if not 1.0 <= self.extent_m <= 100.0:
            raise ValueError(f"terrain extent_m must be in [1, 100] m, got {self.extent_m}")
        if not 8 <= self.resolution <= 512:
            raise ValueError(f"terrain resolution must be in [8, 512] samples, got {self.resolution}")
        if not 0.0 <= self.amplitude_m <= 2.0:
            raise ValueError(f"terrain amplitude_m must be in [0, 2] m, got {self.amplitude_m}")
        if self.feature_size_m <= 0:
            raise ValueError(f"terrain feature_size_m must be > 0, got {self.feature_size_m}")
        if self.heights_m is not None:
            h = np.asarray(self.heights_m, dtype=float)
            if h.shape != (self.resolution, self.resolution):
                raise ValueError(
                    f"terrain heights_m must be {self.resolution}x{self.resolution} "
                    f"(the terrain resolution), got shape {h.shape}"
                )
            _finite("terrain heights_m", h)

    def height_grid(self) -> np.ndarray:
        """Heights [m] on the ``resolution``² grid; ``[iy, ix]``, iy along +y, ix along +x."""
        if self.heights_m is not None:
            return np.asarray(self.heights_m, dtype=np.float64)
        from synth.scene.terrain import perlin_heightfield

        return perlin_heightfield(
            self.seed, self.resolution, self.extent_m, self.amplitude_m, self.feature_size_m
        )

    def grid_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """Pile-frame x and y [m] of the height grid's samples (1-D each)."""
        half = self.extent_m / 2.0
        xs = np.linspace(-half, half, self.resolution)
        return xs, xs.copy()

    def height_at(self, x_m: np.ndarray | float, y_m: np.ndarray | float) -> np.ndarray:
        """Bilinear terrain height [m] at pile-frame points (clamped to the patch)."""
        return height_at(self.height_grid(), self.extent_m, x_m, y_m)


def height_at(grid: np.ndarray, extent_m: float, x_m: Any, y_m: Any) -> np.ndarray:
    """Bilinear interpolation of a square height grid centred on the origin."""
    n = grid.shape[0]
    step = extent_m / (n - 1)
    fx = np.clip((np.asarray(x_m, dtype=float) + extent_m / 2) / step, 0, n - 1 - 1e-9)
    fy = np.clip((np.asarray(y_m, dtype=float) + extent_m / 2) / step, 0, n - 1 - 1e-9)
    ix, iy = np.floor(fx).astype(int), np.floor(fy).astype(int)
    tx, ty = fx - ix, fy - iy
    h00, h10 = grid[iy, ix], grid[iy, ix + 1]
    h01, h11 = grid[iy + 1, ix], grid[iy + 1, ix + 1]
    return (h00 * (1 - tx) + h10 * tx) * (1 - ty) + (h01 * (1 - tx) + h11 * tx) * ty


@dataclass(frozen=True)
class LogSpec:
    """One log: a cylinder (or a truncated cone when ``top_diameter_m`` is set)."""

    centre_m: Vec3  # centre of the axis in the pile frame [m]
    orientation: Quat  # (x, y, z, w), local x = log axis, butt at local -x
    length_m: float  # [m]
    diameter_m: float  # butt diameter [m]
    top_diameter_m: float | None = None  # top diameter for a tapered log [m]; None = cylinder
    colour: Vec3 = (0.6, 0.5, 0.35)  # RGB in [0, 1]

    def __post_init__(self) -> None:
        _finite("log centre_m", self.centre_m)
        _finite("log orientation", self.orientation)
        if len(self.centre_m) != 3 or len(self.orientation) != 4:
            raise ValueError("log centre_m needs 3 values and orientation 4 (x, y, z, w)")
        if abs(np.linalg.norm(self.orientation) - 1.0) > 1e-3:
            raise ValueError(f"log orientation must be a unit quaternion, got {self.orientation}")
        if not 0.3 <= self.length_m <= 12.0:
            raise ValueError(f"log length_m must be in [0.3, 12] m, got {self.length_m}")
        if not 0.03 <= self.diameter_m <= 1.2:
            raise ValueError(f"log diameter_m must be in [0.03, 1.2] m, got {self.diameter_m}")
        if self.top_diameter_m is not None and not 0.02 <= self.top_diameter_m <= self.diameter_m:
            raise ValueError(
                f"log top_diameter_m must be in [0.02, diameter_m={self.diameter_m}] m, "
                f"got {self.top_diameter_m}"
            )

    @property
    def top_d_m(self) -> float:
        return self.diameter_m if self.top_diameter_m is None else self.top_diameter_m

    @property
    def mean_diameter_m(self) -> float:
        return 0.5 * (self.diameter_m + self.top_d_m)

    def volume_m3(self) -> float:
        """Volume of the (truncated) cone [m³]."""
        r1, r2 = self.diameter_m / 2, self.top_d_m / 2
        return math.pi * self.length_m * (r1 * r1 + r1 * r2 + r2 * r2) / 3.0

    def axis(self) -> np.ndarray:
        """Unit axis vector (butt → top) in the pile frame."""
        return rotate(self.orientation, (1.0, 0.0, 0.0))

    def endpoints_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Butt and top end centres in the pile frame [m]."""
        c, a = np.asarray(self.centre_m, dtype=float), self.axis()
        return c - a * self.length_m / 2, c + a * self.length_m / 2

    @staticmethod
    def from_endpoints(
        butt_m: Any, top_m: Any, diameter_m: float, top_diameter_m: float | None = None,
        colour: Vec3 = (0.6, 0.5, 0.35),
    ) -> "LogSpec":
        """A log from its two end centres (how a GNSS survey measures it)."""
        p0, p1 = np.asarray(butt_m, dtype=float), np.asarray(top_m, dtype=float)
        d = p1 - p0
        length = float(np.linalg.norm(d))
        if length < 1e-6:
            raise ValueError("log endpoints coincide: cannot define an axis")
        return LogSpec(
            centre_m=tuple(float(v) for v in (p0 + p1) / 2),
            orientation=quat_from_x_axis(d / length),
            length_m=length,
            diameter_m=float(diameter_m),
            top_diameter_m=None if top_diameter_m is None else float(top_diameter_m),
            colour=colour,
        )


@dataclass(frozen=True)
class RootSpec:
    """A root flare of a stump: a smaller truncated cone leaning out from the main body."""

    azimuth_rad: float  # direction around the stump, from +x towards +y [rad]
    length_m: float  # [m]
    radius_m: float  # radius at the stump end [m]
    tilt_rad: float = 0.6  # angle down from horizontal... measured from the vertical axis [rad]


@dataclass(frozen=True)
class StumpSpec:
    """A tree stump: truncated cone standing on the terrain, with root cones around its foot."""

    position_m: tuple[float, float]  # x, y of the stump's axis [m]; base sits on the terrain
    height_m: float  # above the terrain [m]
    bottom_radius_m: float  # [m]
    top_radius_m: float  # [m]
    roots: tuple[RootSpec, ...] = ()
    colour: Vec3 = (0.5, 0.4, 0.3)

    def __post_init__(self) -> None:
        _finite("stump position_m", self.position_m)
        if not 0.05 <= self.height_m <= 2.0:
            raise ValueError(f"stump height_m must be in [0.05, 2] m, got {self.height_m}")
        if not 0.03 <= self.top_radius_m <= self.bottom_radius_m <= 1.0:
            raise ValueError(
                "stump radii must satisfy 0.03 <= top_radius_m <= bottom_radius_m <= 1 m, got "
                f"{self.top_radius_m}, {self.bottom_radius_m}"
            )


@dataclass(frozen=True)
class RockSpec:
    """An irregular convex rock: the convex hull of ``vertices_m`` (local frame), posed."""

    position_m: Vec3  # [m] pile frame position of the local origin
    orientation: Quat  # (x, y, z, w)
    vertices_m: tuple[Vec3, ...]  # local vertices [m]; the rock is their convex hull
    colour: Vec3 = (0.5, 0.5, 0.5)

    def __post_init__(self) -> None:
        _finite("rock position_m", self.position_m)
        v = np.asarray(self.vertices_m, dtype=float)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 4:
            raise ValueError("rock vertices_m needs at least 4 points of 3 coordinates")
        _finite("rock vertices_m", v)

    def size_m(self) -> float:
        v = np.asarray(self.vertices_m)
        return float(np.max(np.linalg.norm(v[:, None] - v[None], axis=-1)))


@dataclass(frozen=True)
class LightingSpec:
    """Light of the orthographic renders (TinyRenderer's model)."""

    direction: Vec3 = (0.3, 0.2, 1.0)  # towards the light, pile frame [-]
    ambient: float = 0.6  # [-]
    diffuse: float = 0.35  # [-]
    specular: float = 0.05  # [-]

    def __post_init__(self) -> None:
        _finite("light direction", self.direction)
        if np.linalg.norm(self.direction) < 1e-6:
            raise ValueError("light direction must be non-zero")
        for name in ("ambient", "diffuse", "specular"):
            v = getattr(self, name)
            if not 0.0 <= v <= 2.0:
                raise ValueError(f"light {name} must be in [0, 2], got {v}")


@dataclass(frozen=True)
class Georeference:
    """Where the pile frame lies on Earth.

    The *site frame* is a local East-North-Up frame (metres) at ``origin``, given in SWEREF 99
    geodetic coordinates (EPSG:4619 latitude/longitude [deg], ellipsoidal height [m]).
    ``T_site_pile`` is the 4x4 homogeneous transform taking pile-frame points to the site frame.
    """

    origin_lat_deg: float
    origin_lon_deg: float
    origin_h_m: float  # ellipsoidal height (GRS80) [m]
    T_site_pile: tuple[tuple[float, ...], ...] = (
        (1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0),
    )
    crs: str = "EPSG:4619"  # geodetic CRS of the origin (SWEREF 99)

    def __post_init__(self) -> None:
        if not (-90 <= self.origin_lat_deg <= 90 and -180 <= self.origin_lon_deg <= 180):
            raise ValueError(
                f"site origin ({self.origin_lat_deg}, {self.origin_lon_deg}) is not a latitude/longitude"
            )
        T = np.asarray(self.T_site_pile, dtype=float)
        if T.shape != (4, 4) or not np.allclose(T[3], (0, 0, 0, 1)):
            raise ValueError("T_site_pile must be a 4x4 homogeneous transform")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise ValueError("T_site_pile's rotation part must be orthonormal")

    def matrix(self) -> np.ndarray:
        return np.asarray(self.T_site_pile, dtype=np.float64)


@dataclass(frozen=True)
class PileSpec:
    """A whole scene: terrain, logs, obstacles, lighting and an optional georeference."""

    terrain: TerrainSpec
    logs: tuple[LogSpec, ...]
    stumps: tuple[StumpSpec, ...] = ()
    rocks: tuple[RockSpec, ...] = ()
    lighting: LightingSpec = field(default_factory=LightingSpec)
    georef: Georeference | None = None
    seed: int | None = None  # generation seed, if generated
    source: str = "manual"  # "generated", "packed", "manual", "reconstructed", ...
    notes: str = ""

    def __post_init__(self) -> None:
        if len(self.logs) == 0:
            raise ValueError("a pile needs at least one log")
        half = self.terrain.extent_m / 2
        for i, log in enumerate(self.logs):
            for end in log.endpoints_m():
                if abs(end[0]) > half or abs(end[1]) > half:
                    raise ValueError(
                        f"log {i} end at ({end[0]:.2f}, {end[1]:.2f}) m lies outside the "
                        f"{self.terrain.extent_m} m terrain patch; move it or enlarge the terrain"
                    )

    @property
    def n_logs(self) -> int:
        return len(self.logs)

    @property
    def n_obstacles(self) -> int:
        return len(self.stumps) + len(self.rocks)

    def with_logs(self, logs: tuple[LogSpec, ...]) -> "PileSpec":
        return replace(self, logs=tuple(logs))

    # -- serialisation -------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return {"format": PILE_FORMAT_NAME, "format_version": PILE_FORMAT_VERSION, **d}

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "PileSpec":
        return _pile_from_dict(d)


def _tup(x: Any) -> Any:
    if isinstance(x, (list, tuple)):
        return tuple(_tup(v) for v in x)
    return x


def _pile_from_dict(d: dict[str, Any]) -> PileSpec:
    PILE.check(d)
    try:
        terrain = TerrainSpec(**{k: _tup(v) for k, v in d["terrain"].items()})
        logs = tuple(LogSpec(**{k: _tup(v) for k, v in log.items()}) for log in d["logs"])
        stumps = tuple(
            StumpSpec(
                **{k: _tup(v) for k, v in s.items() if k != "roots"},
                roots=tuple(RootSpec(**r) for r in s.get("roots", ())),
            )
            for s in d.get("stumps", ())
        )
        rocks = tuple(RockSpec(**{k: _tup(v) for k, v in r.items()}) for r in d.get("rocks", ()))
        lighting = LightingSpec(**{k: _tup(v) for k, v in d.get("lighting", {}).items()})
        g = d.get("georef")
        georef = None if g is None else Georeference(**{k: _tup(v) for k, v in g.items()})
        return PileSpec(
            terrain=terrain, logs=logs, stumps=stumps, rocks=rocks, lighting=lighting,
            georef=georef, seed=d.get("seed"), source=d.get("source", "manual"),
            notes=d.get("notes", ""),
        )
    except PileFormatError:
        raise
    except KeyError as exc:
        raise PileFormatError(f"malformed pile: missing key {exc}") from exc
    except (TypeError, ValueError, AttributeError) as exc:
        raise PileFormatError(f"malformed pile: {exc}") from exc


def write_pile(pile: PileSpec, path: str | Path) -> Path:
    """Write ``pile`` as ``pile.json`` (atomically). Returns the path written."""
    return PILE.write(path, pile.to_dict())


def read_pile(path: str | Path) -> PileSpec:
    """Read a ``pile.json`` (or a folder holding one). Raises :class:`PileFormatError`."""
    path = PILE.path(path)
    d = PILE.read(path)
    try:
        return _pile_from_dict(d)
    except PileFormatError as exc:
        raise PileFormatError(f"{path}: {exc}") from exc


# -- small rotation helpers (quaternions x, y, z, w) ----------------------------------------
def quat_to_matrix(q: Quat) -> np.ndarray:
    x, y, z, w = (float(v) for v in q)
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n
    return np.array(
        [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
        ]
    )


def quat_multiply(a: Quat, b: Quat) -> Quat:
    """The rotation ``b`` then ``a`` (Hamilton product ``a * b``)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def rotate(q: Quat, v: Any) -> np.ndarray:
    return quat_to_matrix(q) @ np.asarray(v, dtype=float)


def quat_from_x_axis(axis: Any, roll_rad: float = 0.0) -> Quat:
    """Quaternion rotating local +x onto ``axis`` with no roll about it (then ``roll_rad``)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    yaw = math.atan2(a[1], a[0])
    pitch = -math.asin(max(-1.0, min(1.0, a[2])))
    return quat_from_euler(roll_rad, pitch, yaw)


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    """Same convention as pybullet's ``getQuaternionFromEuler`` (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )
