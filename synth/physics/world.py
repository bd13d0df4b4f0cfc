"""The pybullet world: a :class:`~synth.scene.pile.PileSpec` loaded into a physics client.

Logs *render* as cylinders/cones but *collide* as a compound of pentagonal-prism segments with
rolling friction (one convex hull per log jitters forever on a heightfield; see
``shared/notes/platform-findings.md``). Obstacles are static. Every :class:`World` owns its own
DIRECT client, so worlds never share state and a world rebuilt from the same spec behaves the same.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from dataclasses import dataclass, replace

import numpy as np

from synth.common.closing import Closing
from synth.errors import PileValidationError
from synth.scene.pile import LogSpec, PileSpec, quat_from_x_axis, rotate

#: Instance-map codes (see :mod:`synth.render.ortho`): 0 ground, log i -> i + 1, obstacle j -> OBSTACLE_BASE + j.
GROUND_CODE = 0
OBSTACLE_BASE = 1000


@dataclass(frozen=True)
class PhysicsConfig:
    """Physics settings; fix them once per data set (they change outcomes)."""

    dt_s: float = 1.0 / 240.0  # time step [s]
    solver_iterations: int = 50  # [-]
    gravity_m_s2: float = 9.81  # [m/s²]
    log_density_kg_m3: float = 850.0  # fresh softwood [kg/m³]
    log_friction: float = 0.6  # lateral friction coefficient [-]
    log_rolling_friction: float = 0.02  # [m]; damps the heightfield creep
    log_segments: int = 4  # pentagonal-prism segments per log [-]
    terrain_friction: float = 0.9  # [-]
    obstacle_friction: float = 0.8  # [-]
    deterministic_overlapping_pairs: bool = True

    def __post_init__(self) -> None:
        if not 1e-4 <= self.dt_s <= 0.05:
            raise ValueError(f"dt_s must be in [1e-4, 0.05] s, got {self.dt_s}")
        if not 1 <= self.solver_iterations <= 1000:
            raise ValueError(f"solver_iterations must be in [1, 1000], got {self.solver_iterations}")
        if not 1 <= self.log_segments <= 16:
            raise ValueError(f"log_segments must be in [1, 16], got {self.log_segments}")
        if self.log_density_kg_m3 <= 0:
            raise ValueError("log_density_kg_m3 must be > 0")


@contextlib.contextmanager
def _quiet_stdout():
    """Silence C-level writes to stdout (file descriptor 1) for the duration."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError):  # no real stdout (e.g. captured): nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


class World(Closing):
    """One pile in its own pybullet DIRECT client. Use as a context manager; ``close`` is idempotent."""

    def __init__(self, pile: PileSpec, physics: PhysicsConfig | None = None, visuals: bool = True,
                 ground_uv_m: float | None = None) -> None:
        """``visuals=False`` builds collision shapes only (no meshes to parse): for worlds that are
        never rendered, e.g. grasp trials; the physics is identical. ``ground_uv_m``: metres of
        terrain per ground-texture repeat (the terrain mesh's UVs; see
        :class:`synth.render.textures.TextureConfig`)."""
        import pybullet as p
        from pybullet_utils.bullet_client import BulletClient

        self.pile = pile
        self.physics = physics or PhysicsConfig()
        self.visuals = visuals
        if ground_uv_m is None:
            from synth.render.textures import TextureConfig

            ground_uv_m = TextureConfig.ground_uv_m  # the one default, owned by the texture config
        self.ground_uv_m = float(ground_uv_m)
        self.p = p
        with _quiet_stdout():  # pybullet's C code prints "argv[0]=" on every connect
            self.client = BulletClient(connection_mode=p.DIRECT)
        self._closed = False
        try:
            self._build()
        except Exception:
            self.close()
            raise

    # -- construction ----------------------------------------------------------------------
    def _build(self) -> None:
        c, ph = self.client, self.physics
        c.resetSimulation()
        c.setGravity(0, 0, -ph.gravity_m_s2)
        c.setPhysicsEngineParameter(
            fixedTimeStep=ph.dt_s,
            numSolverIterations=ph.solver_iterations,
            deterministicOverlappingPairs=int(ph.deterministic_overlapping_pairs),
        )
        self.terrain_id = self._add_terrain()
        self.obstacle_ids: list[int] = []
        for stump in self.pile.stumps:
            self.obstacle_ids.append(self._add_stump(stump))
        for rock in self.pile.rocks:
            self.obstacle_ids.append(self._add_rock(rock))
        self.log_ids = [self._add_log(log) for log in self.pile.logs]
        # body id -> instance code
        self.instance_of_body = {self.terrain_id: GROUND_CODE}
        for i, b in enumerate(self.log_ids):
            self.instance_of_body[b] = i + 1
        for j, b in enumerate(self.obstacle_ids):
            self.instance_of_body[b] = OBSTACLE_BASE + j

    def _add_terrain(self) -> int:
        c, p, t = self.client, self.p, self.pile.terrain
        self.height_grid = t.height_grid()
        n = t.resolution
        step = t.extent_m / (n - 1)
        data = self.height_grid.astype(np.float64).ravel()  # index ix + iy * n
        shape = c.createCollisionShape(
            p.GEOM_HEIGHTFIELD, meshScale=[step, step, 1.0], heightfieldData=data.tolist(),
            numHeightfieldRows=n, numHeightfieldColumns=n,
        )
        zc = (float(data.min()) + float(data.max())) / 2
        # TinyRenderer shades heightfields badly: render an OBJ of the same grid instead
        from synth.physics.meshes import grid_mesh

        vis = (c.createVisualShape(p.GEOM_MESH, fileName=grid_mesh(self.height_grid, t.extent_m, zc, uv_m=self.ground_uv_m))
               if self.visuals else -1)
        body = c.createMultiBody(0, shape, vis, [0.0, 0.0, zc], [0, 0, 0, 1])
        c.changeDynamics(body, -1, lateralFriction=self.physics.terrain_friction)
        if self.visuals:
            c.changeVisualShape(body, -1, rgbaColor=[*t.colour, 1.0])
        return body

    def _add_log(self, log: LogSpec) -> int:
        from synth.physics.meshes import frustum, unit_pentagonal_prism

        c, p, ph = self.client, self.p, self.physics
        k = ph.log_segments
        seg_len = log.length_m / k
        prism = unit_pentagonal_prism()
        files, scales, positions = [], [], []
        for s in range(k):
            x_mid = -log.length_m / 2 + (s + 0.5) * seg_len
            t = (s + 0.5) / k
            d = log.diameter_m + (log.top_d_m - log.diameter_m) * t
            files.append(prism)
            scales.append([seg_len, d, d])
            positions.append([x_mid, 0.0, 0.0])
        col = c.createCollisionShapeArray(
            shapeTypes=[p.GEOM_MESH] * k, fileNames=files, meshScales=scales,
            collisionFramePositions=positions,
        )
        vis = c.createVisualShape(
            p.GEOM_MESH, fileName=frustum(log.length_m, log.diameter_m, log.top_d_m, uv_m=0.5),
            rgbaColor=[*log.colour, 1.0],
        ) if self.visuals else -1
        mass = log.volume_m3() * ph.log_density_kg_m3
        body = c.createMultiBody(mass, col, vis, list(log.centre_m), list(log.orientation))
        c.changeDynamics(
            body, -1, lateralFriction=ph.log_friction, rollingFriction=ph.log_rolling_friction,
            spinningFriction=ph.log_rolling_friction,
        )
        return body

    def _add_stump(self, stump) -> int:
        from synth.physics.meshes import frustum

        c, p = self.client, self.p
        x, y = stump.position_m
        foot = self._ground_under(x, y, stump.bottom_radius_m)
        sink = 0.05
        h = stump.height_m + sink
        main = frustum(h, 2 * stump.bottom_radius_m, 2 * stump.top_radius_m, sides=16, uv_m=0.3, axis="z")
        files, scales, pos, orn = [main], [[1, 1, 1]], [[0, 0, h / 2]], [[0, 0, 0, 1]]
        for root in stump.roots:
            mesh = frustum(root.length_m, 2 * root.radius_m, 0.4 * root.radius_m, sides=10, uv_m=0.3)
            direction = (
                math.cos(root.azimuth_rad) * math.sin(root.tilt_rad + math.pi / 2),
                math.sin(root.azimuth_rad) * math.sin(root.tilt_rad + math.pi / 2),
                math.cos(root.tilt_rad + math.pi / 2),
            )
            d = np.asarray(direction)
            start = np.array([math.cos(root.azimuth_rad), math.sin(root.azimuth_rad), 0.0]) * stump.bottom_radius_m * 0.6
            start[2] = sink + root.radius_m * 0.5
            centre = start + d * root.length_m / 2
            files.append(mesh)
            scales.append([1, 1, 1])
            pos.append(centre.tolist())
            orn.append(list(quat_from_x_axis(d)))
        col = c.createCollisionShapeArray(
            shapeTypes=[p.GEOM_MESH] * len(files), fileNames=files, meshScales=scales,
            collisionFramePositions=pos, collisionFrameOrientations=orn,
        )
        vis = c.createVisualShapeArray(
            shapeTypes=[p.GEOM_MESH] * len(files), fileNames=files, meshScales=scales,
            visualFramePositions=pos, visualFrameOrientations=orn,
        ) if self.visuals else -1
        body = c.createMultiBody(0, col, vis, [x, y, foot - sink], [0, 0, 0, 1])
        c.changeDynamics(body, -1, lateralFriction=self.physics.obstacle_friction)
        if self.visuals:
            c.changeVisualShape(body, -1, rgbaColor=[*stump.colour, 1.0])
        return body

    def _add_rock(self, rock) -> int:
        from synth.physics.meshes import convex_hull_mesh

        c, p = self.client, self.p
        mesh = convex_hull_mesh(np.asarray(rock.vertices_m))
        col = c.createCollisionShape(p.GEOM_MESH, fileName=mesh)
        vis = c.createVisualShape(p.GEOM_MESH, fileName=mesh, rgbaColor=[*rock.colour, 1.0]) if self.visuals else -1
        body = c.createMultiBody(0, col, vis, list(rock.position_m), list(rock.orientation))
        c.changeDynamics(body, -1, lateralFriction=self.physics.obstacle_friction)
        return body

    def _ground_under(self, x: float, y: float, radius: float) -> float:
        t = self.pile.terrain
        xs = np.array([x - radius, x, x + radius, x, x])
        ys = np.array([y, y - radius, y, y + radius, y])
        return float(np.min(t.height_at(xs, ys)))

    # -- state -------------------------------------------------------------------------------
    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.client.stepSimulation()

    def log_poses(self) -> np.ndarray:
        """(n_logs, 7) array of position [m] and quaternion (x, y, z, w) per log."""
        out = np.empty((len(self.log_ids), 7))
        for i, b in enumerate(self.log_ids):
            pos, orn = self.client.getBasePositionAndOrientation(b)
            out[i, :3] = pos
            out[i, 3:] = orn
        return out

    def settled_pile(self) -> PileSpec:
        """The pile with every log at its current pose."""
        logs = []
        for log, pose in zip(self.pile.logs, self.log_poses()):
            q = pose[3:] / np.linalg.norm(pose[3:])
            logs.append(replace(log, centre_m=tuple(float(v) for v in pose[:3]),
                                orientation=tuple(float(v) for v in q)))
        return self.pile.with_logs(tuple(logs))

    def replace_log(self, i: int, log: LogSpec) -> int:
        """Log ``i`` rebuilt as ``log`` (its body removed, a new one added: a log of another length or
        diameter needs a new shape); ``self.pile`` follows. Returns the new body id."""
        self.client.removeBody(self.log_ids[i])
        body = self._add_log(log)
        self.instance_of_body.pop(self.log_ids[i], None)
        self.log_ids[i] = body
        self.instance_of_body[body] = i + 1
        logs = list(self.pile.logs)
        logs[i] = log
        self.pile = self.pile.with_logs(tuple(logs))
        return body

    def deepest_contact(self, i: int) -> tuple[float, int | None]:
        """Log ``i``'s deepest interpenetration with any other body: (depth [m], >= 0; that body's id,
        None when it touches nothing)."""
        self.client.performCollisionDetection()
        depth, other = 0.0, None
        for cp in self.client.getContactPoints(bodyA=self.log_ids[i]):
            if -cp[8] > depth:
                depth, other = -cp[8], cp[2]
        return depth, other

    def penetrations(self, tolerance_m: float = 0.01) -> list[tuple[str, str, float]]:
        """Pairs of bodies interpenetrating deeper than ``tolerance_m``: (a, b, depth_m)."""
        names = {self.terrain_id: "terrain"}
        names.update({b: f"log {i}" for i, b in enumerate(self.log_ids)})
        names.update({b: f"obstacle {j}" for j, b in enumerate(self.obstacle_ids)})
        self.client.performCollisionDetection()
        worst: dict[tuple[int, int], float] = {}
        for b in self.log_ids:
            for cp in self.client.getContactPoints(bodyA=b):
                a, o, dist = cp[1], cp[2], cp[8]
                if dist < -tolerance_m:
                    key = (min(a, o), max(a, o))
                    worst[key] = min(worst.get(key, 0.0), dist)
        return [(names.get(a, str(a)), names.get(o, str(o)), -d) for (a, o), d in sorted(worst.items())]

    def check_valid(self, tolerance_m: float = 0.01) -> None:
        """Raise :class:`PileValidationError` if logs interpenetrate or lie off/below the terrain."""
        bad = self.penetrations(tolerance_m)
        if bad:
            a, b, d = bad[0]
            raise PileValidationError(
                f"{a} and {b} interpenetrate by {d * 100:.1f} cm (tolerance {tolerance_m * 100:.1f} cm); "
                "move the logs apart or lift them onto the terrain"
            )
        half = self.pile.terrain.extent_m / 2
        for i, (log, pose) in enumerate(zip(self.pile.logs, self.log_poses())):
            axis = rotate(tuple(pose[3:]), (1.0, 0.0, 0.0))
            for end in (pose[:3] - axis * log.length_m / 2, pose[:3] + axis * log.length_m / 2):
                if abs(end[0]) > half or abs(end[1]) > half:
                    raise PileValidationError(
                        f"log {i} reaches ({end[0]:.2f}, {end[1]:.2f}) m, outside the "
                        f"{self.pile.terrain.extent_m} m terrain patch"
                    )
            ground = float(self.pile.terrain.height_at(pose[0], pose[1]))
            if pose[2] < ground - tolerance_m:
                raise PileValidationError(
                    f"log {i}'s axis is {ground - pose[2]:.2f} m below the terrain surface"
                )

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self.client.disconnect()
            except Exception:  # already gone
                pass



def log_axis_xy(log: LogSpec) -> np.ndarray:
    a = rotate(log.orientation, (1, 0, 0))
    return a[:2] / (np.linalg.norm(a[:2]) + 1e-12)
