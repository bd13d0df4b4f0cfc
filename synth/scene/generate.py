"""Pile generation as in the paper: terrain, 0–7 obstacles, a stack of logs dropped and settled.

Unstable or unphysical results (logs still moving, interpenetrating, off the terrain) are detected
and regenerated with the next attempt's seed; they are never returned. Everything is drawn from a
``numpy`` generator seeded by ``(seed, attempt)``, so the same seed gives the same pile.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from synth.errors import GenerationError, PileValidationError
from synth.scene.pile import (
    LightingSpec, LogSpec, PileSpec, RockSpec, RootSpec, StumpSpec, TerrainSpec, quat_from_euler,
)
from synth.physics.world import PhysicsConfig, World


@dataclass(frozen=True)
class GenerationConfig:
    """How random piles are drawn. Lengths/diameters follow the paper's distributions."""

    n_logs: int = 4  # logs per pile [-]
    n_obstacles: int = 0  # stumps + rocks [-]
    packed: bool = False  # N aligned, tightly packed logs instead of a dropped stack
    length_mean_m: float = 2.5  # [m]
    length_std_m: float = 0.2  # [m]
    diameter_mean_m: float = 0.16  # [m]
    diameter_std_m: float = 0.02  # [m]
    taper_fraction: float = 0.0  # share of logs that are conical [-]
    extent_m: float = 5.0  # terrain side [m]
    terrain_resolution: int = 64  # physics heightfield samples per side [-]
    terrain_amplitude_m: float = 0.15  # relief [m]
    pile_spread_m: float = 0.3  # std of log centres around the pile centre [m]
    yaw_spread_rad: float = 0.35  # std of log yaw around the pile direction [rad]
    rock_size_m: tuple[float, float] = (0.3, 1.3)  # rock diameter range [m]
    settle_window_s: float = 0.25  # pose comparison window [s]
    settle_tol_m: float = 0.002  # max displacement per window when at rest [m]
    settle_tol_rad: float = 0.01  # max rotation per window when at rest [rad]
    settle_windows: int = 3  # consecutive quiet windows needed [-]
    settle_max_s: float = 10.0  # give up (and regenerate) after [s]
    max_attempts: int = 20  # regenerations before failing [-]
    penetration_tol_m: float = 0.01  # [m]

    def __post_init__(self) -> None:
        if not 1 <= self.n_logs <= 16:
            raise ValueError(f"n_logs must be in [1, 16], got {self.n_logs}")
        if not 0 <= self.n_obstacles <= 12:
            raise ValueError(f"n_obstacles must be in [0, 12], got {self.n_obstacles}")
        if self.length_mean_m <= 0.5 or self.diameter_mean_m <= 0.04:
            raise ValueError("log length/diameter means are too small")
        if not 0 <= self.taper_fraction <= 1:
            raise ValueError("taper_fraction must be in [0, 1]")
        if not 0.3 <= self.rock_size_m[0] <= self.rock_size_m[1] <= 2.0:
            raise ValueError("rock_size_m must be an increasing range inside [0.3, 2] m")


def _colour(rng: np.random.Generator, base: tuple[float, float, float]) -> tuple[float, float, float]:
    v = rng.uniform(0.2, 0.8)
    rgb = np.clip(np.asarray(base) / np.mean(base) * v + rng.normal(0, 0.03, 3), 0.0, 1.0)
    return tuple(float(c) for c in rgb)


def _rock(rng: np.random.Generator, terrain: TerrainSpec, xy: np.ndarray, size_m: float) -> RockSpec:
    n = int(rng.integers(10, 18))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    axes = np.array([1.0, rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.8)]) * size_m / 2
    verts = d * axes * rng.uniform(0.8, 1.0, size=(n, 1))
    ground = float(np.min(terrain.height_at(xy[0] + verts[:, 0], xy[1] + verts[:, 1])))
    z = ground + axes[2] * rng.uniform(0.0, 0.4)  # partly sunk into the ground
    yaw = rng.uniform(0, 2 * math.pi)
    return RockSpec(
        position_m=(float(xy[0]), float(xy[1]), float(z)), orientation=quat_from_euler(0, 0, yaw),
        vertices_m=tuple(tuple(float(c) for c in v) for v in verts),
        colour=_colour(rng, (0.5, 0.5, 0.5)),
    )


def _stump(rng: np.random.Generator, xy: np.ndarray) -> StumpSpec:
    r = float(np.clip(rng.normal(0.2, 0.05), 0.1, 0.35))
    h = float(np.clip(rng.normal(0.4, 0.12), 0.15, 0.8))
    roots = tuple(
        RootSpec(azimuth_rad=float(a), length_m=float(rng.uniform(0.3, 0.6)),
                 radius_m=float(r * rng.uniform(0.3, 0.5)), tilt_rad=float(rng.uniform(0.9, 1.3)))
        for a in np.sort(rng.uniform(0, 2 * math.pi, size=int(rng.integers(3, 7))))
    )
    return StumpSpec(position_m=(float(xy[0]), float(xy[1])), height_m=h, bottom_radius_m=r,
                     top_radius_m=r * float(rng.uniform(0.75, 0.95)), roots=roots,
                     colour=_colour(rng, (0.55, 0.45, 0.3)))


def _log_dims(rng: np.random.Generator, cfg: GenerationConfig) -> tuple[float, float, float | None]:
    length = float(np.clip(rng.normal(cfg.length_mean_m, cfg.length_std_m), 1.0, cfg.extent_m - 1.0))
    d = float(np.clip(rng.normal(cfg.diameter_mean_m, cfg.diameter_std_m), 0.06, 0.5))
    top = None
    if rng.random() < cfg.taper_fraction:
        top = float(d * rng.uniform(0.5, 0.8))
    return length, d, top


def draw_pile(seed: int, cfg: GenerationConfig, attempt: int = 0) -> PileSpec:
    """An *unsettled* random pile: terrain, obstacles and logs in their drop poses."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(attempt), 0x106]))
    terrain = TerrainSpec(
        seed=int(rng.integers(0, 2**31 - 1)), extent_m=cfg.extent_m, resolution=cfg.terrain_resolution,
        amplitude_m=cfg.terrain_amplitude_m, colour=_colour(rng, (0.45, 0.4, 0.3)),
    )
    half = cfg.extent_m / 2
    centre = rng.uniform(-0.5, 0.5, size=2)
    direction = rng.uniform(0, math.pi)

    stumps, rocks = [], []
    for _ in range(cfg.n_obstacles):
        xy = rng.uniform(-half + 0.7, half - 0.7, size=2)
        if rng.random() < 0.5:
            stumps.append(_stump(rng, xy))
        else:
            size = float(rng.uniform(*cfg.rock_size_m))
            rocks.append(_rock(rng, terrain, xy, size))

    grid = terrain.height_grid()
    top_obstacle = max([0.0] + [s.height_m + 0.1 for s in stumps] + [r.position_m[2] + 0.7 for r in rocks])
    logs = []
    z_stack = 0.0
    for i in range(cfg.n_logs):
        length, d, top = _log_dims(rng, cfg)
        if cfg.packed:
            # side by side across the pile direction, touching
            offset = (i - (cfg.n_logs - 1) / 2) * (cfg.diameter_mean_m + 0.004)
            normal = np.array([-math.sin(direction), math.cos(direction)])
            xy = centre + normal * offset
            yaw = direction
        else:
            xy = centre + rng.normal(0, cfg.pile_spread_m, size=2)
            yaw = direction + rng.normal(0, cfg.yaw_spread_rad)
        axis = np.array([math.cos(yaw), math.sin(yaw)])
        # keep the whole log on the patch
        reach = np.abs(axis) * length / 2 + 0.15
        xy = np.clip(xy, -half + reach, half - reach)
        # clear the highest ground under the whole length (not just the centre)
        s = np.linspace(-length / 2, length / 2, 9)
        ground = float(np.max(_height(grid, cfg.extent_m, xy[0] + axis[0] * s, xy[1] + axis[1] * s)))
        if cfg.packed:
            z = ground + d / 2 + 0.01
        else:
            z = max(ground, top_obstacle * 0.0) + d / 2 + 0.05 + z_stack
            z_stack += d + 0.02
            z = max(z, ground + d / 2 + 0.05)
        roll = rng.uniform(0, 2 * math.pi)
        pitch = 0.0 if cfg.packed else rng.normal(0, 0.03)
        logs.append(LogSpec(
            centre_m=(float(xy[0]), float(xy[1]), float(z)), orientation=quat_from_euler(roll, pitch, yaw),
            length_m=length, diameter_m=d, top_diameter_m=top, colour=_colour(rng, (0.6, 0.5, 0.35)),
        ))
    # logs dropped above obstacles start above them
    logs = _lift_above_obstacles(logs, stumps, rocks)
    light = LightingSpec(
        direction=tuple(float(v) for v in (rng.normal(0, 0.4), rng.normal(0, 0.4), 1.0)),
        ambient=float(rng.uniform(0.5, 0.7)), diffuse=float(rng.uniform(0.25, 0.4)), specular=0.05,
    )
    return PileSpec(terrain=terrain, logs=tuple(logs), stumps=tuple(stumps), rocks=tuple(rocks),
                    lighting=light, seed=int(seed), source="packed" if cfg.packed else "generated")


def _height(grid: np.ndarray, extent: float, x, y) -> np.ndarray:
    from synth.scene.pile import height_at

    return height_at(grid, extent, x, y)


def _lift_above_obstacles(logs: list[LogSpec], stumps, rocks) -> list[LogSpec]:
    """Raise logs whose drop pose overlaps an obstacle's footprint above its top."""
    out = []
    for log in logs:
        p0, p1 = log.endpoints_m()
        z_need = log.centre_m[2]
        for obstacle_xy, r, top in (
            [((s.position_m[0], s.position_m[1]), s.bottom_radius_m + 0.6, s.height_m + 0.3) for s in stumps]
            + [((r.position_m[0], r.position_m[1]), r.size_m() / 2, r.position_m[2] + r.size_m() / 2) for r in rocks]
        ):
            q = np.asarray(obstacle_xy)
            a, b = p0[:2], p1[:2]
            t = np.clip(np.dot(q - a, b - a) / max(np.dot(b - a, b - a), 1e-9), 0, 1)
            if np.linalg.norm(a + t * (b - a) - q) < r + log.diameter_m:
                z_need = max(z_need, top + log.diameter_m / 2 + 0.05)
        c = log.centre_m
        out.append(replace(log, centre_m=(c[0], c[1], float(z_need))) if z_need != c[2] else log)
    return out


def settle(world: World, cfg: GenerationConfig) -> float:
    """Step until every log is at rest (pose change per window below tolerance, several windows
    in a row). Returns the simulated time [s]; raises :class:`GenerationError` if it never rests."""
    steps = max(1, int(round(cfg.settle_window_s / world.physics.dt_s)))
    prev = world.log_poses()
    quiet = 0
    t = 0.0
    while t < cfg.settle_max_s:
        world.step(steps)
        t += steps * world.physics.dt_s
        cur = world.log_poses()
        dpos = np.linalg.norm(cur[:, :3] - prev[:, :3], axis=1).max()
        dots = np.abs(np.sum(cur[:, 3:] * prev[:, 3:], axis=1)).clip(0, 1)
        drot = (2 * np.arccos(dots)).max()
        prev = cur
        quiet = quiet + 1 if (dpos < cfg.settle_tol_m and drot < cfg.settle_tol_rad) else 0
        if quiet >= cfg.settle_windows:
            return t
    raise GenerationError(f"logs still moving after {cfg.settle_max_s} s of simulation")


@dataclass
class GenerationReport:
    attempts: int
    settle_time_s: float
    rejections: list[str]


def generate_pile(seed: int, cfg: GenerationConfig | None = None,
                  physics: PhysicsConfig | None = None) -> tuple[PileSpec, GenerationReport]:
    """Draw, drop and settle a pile; regenerate until it is valid. Deterministic in ``seed``."""
    cfg = cfg or GenerationConfig()
    rejections: list[str] = []
    for attempt in range(cfg.max_attempts):
        pile = draw_pile(seed, cfg, attempt)
        with World(pile, physics, visuals=False) as world:
            try:
                t = settle(world, cfg)
                world.check_valid(cfg.penetration_tol_m)
            except (GenerationError, PileValidationError) as exc:
                rejections.append(f"attempt {attempt}: {exc}")
                continue
            settled = world.settled_pile()
        return settled, GenerationReport(attempts=attempt + 1, settle_time_s=t, rejections=rejections)
    raise GenerationError(
        f"no valid pile for seed {seed} after {cfg.max_attempts} attempts "
        f"(last: {rejections[-1] if rejections else '?'}); try fewer logs or obstacles"
    )


def validate_pile(pile: PileSpec, physics: PhysicsConfig | None = None, tolerance_m: float = 0.01) -> None:
    """Load a (hand-written or reconstructed) pile into the twin and check it is physical:
    no log through the terrain, an obstacle or another log. Raises :class:`PileValidationError`."""
    with World(pile, physics, visuals=False) as world:
        world.check_valid(tolerance_m)
