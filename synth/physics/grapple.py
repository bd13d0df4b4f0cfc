"""The forestry grapple twin: a boom tip under kinematic control, a compliant rotator, two claws.

One pybullet multibody, built with ``createMultiBody`` (no URDF file), added to a
:class:`~synth.physics.world.World`'s client:

====  ==============  ===========================  ===========================================
link  name            joint (parent)               role
====  ==============  ===========================  ===========================================
 0    carriage_x      prismatic x (fixed base)     boom tip x, velocity/position motor
 1    carriage_y      prismatic y (0)              boom tip y
 2    boom_tip        prismatic z (1)              boom tip z; lowered / lifted at set speeds
 3    swing_a         revolute x, unactuated (2)   compliance (the dual swing damper's first hinge)
 4    swing_b         revolute y, unactuated (3)   compliance (second hinge)
 5    head            revolute z, actuated (4)     the rotator: sets the grasp angle ``phi``
 6    claw_neg        revolute, actuated (5)       claw on the -u side of the closing axis
 7    claw_pos        revolute, actuated (5)       claw on the +u side
====  ==============  ===========================  ===========================================

The two swing hinges are viscous dampers (a dual swing damper), so the grapple hangs plumb when
empty, folds when pressed against a log or an obstacle, bounces off hard hits (the paper's
compliance) and, holding a load, swings until the load's centre of mass hangs under the hinges. The
claws close symmetrically under position motors whose torque is limited to a real grapple's
closing strength (see :class:`GrappleConfig`). Collision geometry is cuboids only; the carriage
and swing links have none. Grapple–terrain contacts are disabled, as in the paper, to reduce the
dependence on the lowering controller.

Head frame (link 5): origin on the rotator axis at the yaw joint, ``u`` = local x = the closing
axis (claw tip to claw tip), ``v`` = local y = along the claws' width (the log direction of a
clean grasp), ``z`` up along the rotator axis. The claw hinges lie at ``(±hinge_offset_m, 0,
-head_drop_m)``. A claw's joint angle ``q`` is 0 when fully closed and grows as it opens; both
claws use the same ``q`` (mirror images).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, Grasp

# link indices of the multibody
CARRIAGE_X, CARRIAGE_Y, BOOM_TIP, SWING_A, SWING_B, HEAD, CLAW_NEG, CLAW_POS = range(8)
GRAPPLE_LINKS = (SWING_A, SWING_B, HEAD, CLAW_NEG, CLAW_POS)  # links that may carry geometry
CONTACT_LINKS = (HEAD, CLAW_NEG, CLAW_POS)  # links with collision geometry


@dataclass(frozen=True)
class GrappleConfig:
    """Geometry, masses and actuator limits of the grapple (SI units).

    Sized after a 0.35 m² forwarder grapple (the field trial's Loglift FX 36 class; the paper
    scaled a Cranab CR HD the same way): closed, the two claws enclose about 0.35 m²; open, the
    claw tips reach 1.60 m apart so the paper's whole width range 0.30–1.55 m can be set. Masses
    add up to ~235 kg (grapple ~190 kg + rotator/link ~45 kg), the usual weight of such a grapple
    and rotator. The closing torque (4.0 kN·m per claw over a 0.83 m hinge-to-tip arm, i.e.
    ~4.8 kN at each tip, ~9.6 kN squeeze) is our estimate of a forwarder grapple's closing
    strength — no datasheet value was available offline; it is well above what 1–7 logs of
    40–60 kg need and low enough that the claws do not sink into logs at the chosen time steps.
    """

    # geometry [m]
    hinge_offset_m: float = 0.12  # claw hinge distance from the rotator axis along u [m]
    head_drop_m: float = 0.42  # yaw joint to the claw hinge line, downwards [m]
    swing_link_m: float = 0.16  # boom tip (hinge a) to hinge b, downwards [m]
    yaw_drop_m: float = 0.08  # hinge b to the yaw joint, downwards [m]
    # closed right (+u) claw as a polyline from its hinge, (u, z) in the head frame, hinge at 0 [m]
    claw_profile_m: tuple[tuple[float, float], ...] = (
        (0.0, 0.0), (0.16, -0.16), (0.19, -0.46), (0.08, -0.72), (-0.12, -0.82),
    )
    claw_width_m: float = 0.22  # claw extent along v (across the closing plane) [m]
    claw_thickness_m: float = 0.05  # claw plate thickness in the closing plane [m]
    head_size_m: tuple[float, float, float] = (0.42, 0.30, 0.30)  # u, v, z box of the head [m]
    rotator_size_m: tuple[float, float, float] = (0.22, 0.22, 0.30)  # rotator box above the head [m]
    max_opening_m: float = 1.60  # claw tip distance at the opening limit [m]
    # masses [kg]
    head_mass_kg: float = 125.0  # head + rotator rotor [kg]
    claw_mass_kg: float = 35.0  # each [kg]
    swing_mass_kg: float = 20.0  # each swing link (rotator stator, link) [kg]
    carriage_mass_kg: float = 5.0  # each virtual carriage link (no geometry) [kg]
    # actuators
    claw_torque_limit_nm: float = 4000.0  # per claw [N·m]
    closing_speed_rad_s: float = 1.0  # claw angular speed limit [rad/s]
    # the claws interleave (tines of one pass between the other's), so the cylinder stroke ends
    # only where the bowl left between the claws and the head is this small: a single log this
    # thin is still squeezed, not left loose in the bowl [m]
    closed_bowl_diameter_m: float = 0.19
    hinge_damping_nms: float = 1300.0  # viscous damping of each unactuated swing hinge [N·m·s/rad]
    hinge_friction_nm: float = 5.0  # residual (seal) friction of each swing hinge [N·m]
    rotator_torque_limit_nm: float = 2500.0  # yaw motor [N·m]
    boom_force_limit_n: float = 1.0e6  # carriage motors: stiff enough to be kinematic [N]
    # contact
    friction: float = 0.6  # steel on bark [-]
    claw_spinning_friction_m: float = 0.10  # torsional friction arm of a claw's contact patch [m]
    colour: tuple[float, float, float] = (0.85, 0.45, 0.10)  # RGB in [0, 1]

    def __post_init__(self) -> None:
        prof = np.asarray(self.claw_profile_m, dtype=float)
        if prof.ndim != 2 or prof.shape[1] != 2 or prof.shape[0] < 2:
            raise ValueError("claw_profile_m needs at least two (u, z) points")
        if not np.allclose(prof[0], 0.0):
            raise ValueError("claw_profile_m must start at the hinge, (0, 0)")
        for name in ("hinge_offset_m", "head_drop_m", "swing_link_m", "claw_width_m",
                     "claw_thickness_m", "head_mass_kg", "claw_mass_kg", "swing_mass_kg",
                     "carriage_mass_kg", "claw_torque_limit_nm", "closing_speed_rad_s",
                     "rotator_torque_limit_nm", "boom_force_limit_n"):
            if not getattr(self, name) > 0:
                raise ValueError(f"grapple {name} must be > 0, got {getattr(self, name)}")
        if self.yaw_drop_m < 0 or self.hinge_friction_nm < 0 or self.hinge_damping_nms < 0:
            raise ValueError("grapple yaw_drop_m, hinge_friction_nm and hinge_damping_nms must be >= 0")
        if not 0.05 <= self.closed_bowl_diameter_m <= 0.5:
            raise ValueError(f"grapple closed_bowl_diameter_m must be in [0.05, 0.5] m, got {self.closed_bowl_diameter_m}")
        if not MAX_WIDTH_M <= self.max_opening_m <= 3.0:
            raise ValueError(
                f"grapple max_opening_m must be in [{MAX_WIDTH_M}, 3] m so every grasp width fits, "
                f"got {self.max_opening_m}"
            )
        if self.closed_gap_m() > MIN_WIDTH_M:
            raise ValueError("the closed claw profile leaves the tips wider apart than the minimum width")

    # -- claw kinematics (head frame, +u claw; the -u claw is its mirror image) --------------
    def tip_in_head(self, q_rad: float | np.ndarray) -> np.ndarray:
        """(..., 2) position (u, z) [m] of the +u claw tip in the head frame at opening angle q."""
        q = np.asarray(q_rad, dtype=float)
        tu, tz = self.claw_profile_m[-1]
        c, s = np.cos(q), np.sin(q)
        # opening rotates the +u claw's tip outwards (towards +u) and upwards
        u = self.hinge_offset_m + tu * c - tz * s
        z = -self.head_drop_m + tu * s + tz * c
        return np.stack([u, z], axis=-1)

    def gap_at(self, q_rad: float | np.ndarray) -> np.ndarray:
        """Tip-to-tip distance [m] at claw angle ``q_rad`` (negative = tips overlap)."""
        return 2.0 * self.tip_in_head(q_rad)[..., 0]

    def closed_gap_m(self) -> float:
        return float(self.gap_at(0.0))

    def claw_polyline_m(self, q_rad: float) -> np.ndarray:
        """(k, 2) the +u claw's profile (u, z) [m] in the head frame at claw angle ``q_rad``."""
        return _claw_polyline(self, q_rad)

    def head_bottom_z_m(self) -> float:
        """Height [m] of the head box's underside in the head frame: the top of the claws' bowl."""
        return -self.head_drop_m - _HEAD_BELOW_HINGES_M

    def bowl_diameter_m(self, q_rad: float) -> float:
        """Diameter [m] of the largest log (a circle in the closing plane) that fits loose in the
        bowl between both claws and the head when both claws stand at angle ``q_rad``; 0 when the
        claws do not close the bowl below (the tips have not met). The circle sits on the
        rotator axis (the claws are mirror images) above the point where the claws cross it."""
        return _bowl_diameter(self, round(float(q_rad), 9))

    def close_angle_rad(self) -> float:
        """Claw angle [rad] (<= 0) where the stroke ends: the bowl is ``closed_bowl_diameter_m``."""
        return _close_angle(self)

    def max_angle_rad(self) -> float:
        return float(self.angle_for_gap(self.max_opening_m))

    def angle_for_gap(self, gap_m: float) -> float:
        """Claw angle [rad] that opens the tips ``gap_m`` apart (monotonic on [0, pi/2])."""
        qs = np.linspace(0.0, math.pi / 2, 2001)
        gaps = self.gap_at(qs)
        if not gaps[0] - 1e-9 <= gap_m <= gaps[-1]:
            raise ValueError(f"claw gap {gap_m:.3f} m is outside [{gaps[0]:.3f}, {gaps[-1]:.3f}] m")
        return float(np.interp(gap_m, gaps, qs))

    def mass_kg(self) -> float:
        return self.head_mass_kg + 2 * self.claw_mass_kg + 2 * self.swing_mass_kg

    def enclosed_area_m2(self) -> float:
        """Area [m²] enclosed by the closed claws and the hinge line (shoelace formula)."""
        prof = np.asarray(self.claw_profile_m, dtype=float)
        right = prof + [self.hinge_offset_m, 0.0]
        left = right[::-1] * [-1.0, 1.0]
        poly = np.vstack([right, left])
        x, y = poly[:, 0], poly[:, 1]
        return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))

    def hang_height_m(self, q_rad: float) -> float:
        """Height [m] of the boom tip above the claw tips when hanging plumb at angle ``q_rad``."""
        return self.swing_link_m + self.yaw_drop_m - float(self.tip_in_head(q_rad)[1])


_HEAD_BELOW_HINGES_M = 0.05  # the head box reaches this far below the claw hinge line [m]
_BOWL_SAMPLES = 801  # circle centres tried along the rotator axis [-]


def _claw_polyline(g: GrappleConfig, q_rad: float) -> np.ndarray:
    """(k, 2) the +u claw's profile (u, z) [m] in the head frame at angle ``q_rad``."""
    prof = np.asarray(g.claw_profile_m, dtype=float)
    c, s = math.cos(q_rad), math.sin(q_rad)
    return np.stack([g.hinge_offset_m + prof[:, 0] * c - prof[:, 1] * s,
                     -g.head_drop_m + prof[:, 0] * s + prof[:, 1] * c], axis=1)


@functools.lru_cache(maxsize=4096)
def _bowl_diameter(g: GrappleConfig, q_rad: float) -> float:
    P = _claw_polyline(g, q_rad)
    a, b = P[:-1], P[1:]
    cross = (a[:, 0] > 0) != (b[:, 0] > 0)
    if not cross.any():
        return 0.0
    t = a[cross, 0] / (a[cross, 0] - b[cross, 0])
    z_cross = float(np.min(a[cross, 1] + t * (b[cross, 1] - a[cross, 1])))
    top = g.head_bottom_z_m()
    if z_cross >= top:
        return 0.0
    centres = np.stack([np.zeros(_BOWL_SAMPLES), np.linspace(z_cross, top, _BOWL_SAMPLES)], axis=1)  # (m, 2)
    d = b - a  # (k, 2)
    w = centres[:, None, :] - a[None, :, :]  # (m, k, 2)
    s = np.clip((w * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
    dist = np.linalg.norm(w - s[..., None] * d, axis=-1).min(axis=1) - g.claw_thickness_m / 2
    radius = np.minimum(dist, top - centres[:, 1])
    return float(2.0 * max(0.0, radius.max()))


@functools.lru_cache(maxsize=256)
def _close_angle(g: GrappleConfig) -> float:
    lo, hi = -math.pi / 2, 0.0  # bowl diameter shrinks as q falls (the claws close further)
    if g.bowl_diameter_m(lo) > g.closed_bowl_diameter_m:
        raise ValueError(f"closed_bowl_diameter_m {g.closed_bowl_diameter_m} m is smaller than the claws "
                         f"can close ({g.bowl_diameter_m(lo):.3f} m)")
    for _ in range(40):
        mid = (lo + hi) / 2
        if g.bowl_diameter_m(mid) > g.closed_bowl_diameter_m:
            hi = mid
        else:
            lo = mid
    return hi


def _quat_about_y(angle_rad: float) -> list[float]:
    return [0.0, math.sin(angle_rad / 2), 0.0, math.cos(angle_rad / 2)]


class Grapple:
    """The grapple multibody inside a pybullet client. Built hanging plumb above a grasp.

    ``boom_xyz_m`` is the boom tip (hinge a) position in the pile frame. The rotator is turned to
    the grasp angle and the claws opened to the grasp width at construction.
    """

    def __init__(self, client, config: GrappleConfig, grasp: Grasp, boom_z_m: float,
                 terrain_id: int | None = None) -> None:
        import pybullet as p

        self.client, self.p, self.config = client, p, config
        self.grasp = grasp
        self.q_open = config.angle_for_gap(grasp.width_m)
        self.body = self._build(grasp, boom_z_m)
        if terrain_id is not None:  # the paper disables grapple-terrain contacts
            for link in (-1, *range(8)):
                client.setCollisionFilterPair(terrain_id, self.body, -1, link, 0)
        self._motors_initial(grasp, boom_z_m)

    # -- construction ------------------------------------------------------------------------
    def _claw_shape(self, sign: float) -> int:
        """Compound box collision/visual of one claw in its link (hinge) frame; sign +1 = +u claw."""
        g = self.config
        prof = np.asarray(g.claw_profile_m, dtype=float)
        half, pos, orn = [], [], []
        for a, b in zip(prof[:-1], prof[1:]):
            d = b - a
            length = float(np.hypot(*d))
            # box local x along the segment; rotation about y by ang maps x -> (cos, 0, -sin)
            ang = math.atan2(-d[1], d[0])
            mid = (a + b) / 2
            # the -u claw mirrors u; in its link frame the joint axis is mirrored as well
            half.append([length / 2 + g.claw_thickness_m / 2, g.claw_width_m / 2, g.claw_thickness_m / 2])
            pos.append([sign * mid[0], 0.0, mid[1]])
            orn.append(_quat_about_y(ang if sign > 0 else math.pi - ang))
        return half, pos, orn

    def _build(self, grasp: Grasp, boom_z_m: float) -> int:
        c, p, g = self.client, self.p, self.config
        rgba = [*g.colour, 1.0]

        def boxes(half, pos, orn=None):
            orn = orn or [[0, 0, 0, 1]] * len(half)
            col = c.createCollisionShapeArray(
                shapeTypes=[p.GEOM_BOX] * len(half), halfExtents=half,
                collisionFramePositions=pos, collisionFrameOrientations=orn,
            )
            vis = c.createVisualShapeArray(
                shapeTypes=[p.GEOM_BOX] * len(half), halfExtents=half,
                visualFramePositions=pos, visualFrameOrientations=orn,
            )
            return col, vis

        hu, hv, hz = (s / 2 for s in g.head_size_m)
        ru, rv, rz = (s / 2 for s in g.rotator_size_m)
        z_hinge = -g.head_drop_m
        head_col, head_vis = boxes(
            [[hu, hv, hz], [ru, rv, rz]],
            [[0.0, 0.0, z_hinge + hz - _HEAD_BELOW_HINGES_M], [0.0, 0.0, z_hinge + 2 * hz - _HEAD_BELOW_HINGES_M + rz]],
        )
        claw_cv = {s: boxes(*self._claw_shape(s)) for s in (-1.0, 1.0)}
        # swing links: a small visual only (the stator and link); no collision geometry
        sw_vis = c.createVisualShape(p.GEOM_BOX, halfExtents=[0.06, 0.06, g.swing_link_m / 2],
                                     visualFramePosition=[0, 0, -g.swing_link_m / 2], rgbaColor=rgba)
        m = g.carriage_mass_kg
        masses = [m, m, m, g.swing_mass_kg, g.swing_mass_kg, g.head_mass_kg, g.claw_mass_kg, g.claw_mass_kg]
        cols = [-1, -1, -1, -1, -1, head_col, claw_cv[-1.0][0], claw_cv[1.0][0]]
        viss = [-1, -1, -1, sw_vis, -1, head_vis, claw_cv[-1.0][1], claw_cv[1.0][1]]
        positions = [
            [0, 0, 0], [0, 0, 0], [0, 0, 0],
            [0, 0, 0],  # hinge a at the boom tip
            [0, 0, -g.swing_link_m],  # hinge b
            [0, 0, -g.yaw_drop_m],  # yaw joint
            [-g.hinge_offset_m, 0, z_hinge], [g.hinge_offset_m, 0, z_hinge],
        ]
        # joint axes: +u claw opens by rotating about -y, the -u claw about +y (q > 0 = opening)
        axes = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 1, 0], [0, -1, 0]]
        types = [p.JOINT_PRISMATIC] * 3 + [p.JOINT_REVOLUTE] * 5
        parents = [0, 1, 2, 3, 4, 5, 6, 6]  # pybullet: 0 = base, k = link k-1
        n = 8
        inertial_pos = [[0, 0, 0]] * n
        inertial_pos[SWING_A] = [0, 0, -g.swing_link_m / 2]
        inertial_pos[HEAD] = [0, 0, z_hinge + 0.1]
        prof = np.asarray(g.claw_profile_m)
        cu, cz = prof.mean(axis=0)
        inertial_pos[CLAW_NEG] = [-cu, 0, cz]
        inertial_pos[CLAW_POS] = [cu, 0, cz]
        body = c.createMultiBody(
            baseMass=0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=-1,
            basePosition=[0, 0, 0], baseOrientation=[0, 0, 0, 1],
            linkMasses=masses, linkCollisionShapeIndices=cols, linkVisualShapeIndices=viss,
            linkPositions=positions, linkOrientations=[[0, 0, 0, 1]] * n,
            linkInertialFramePositions=inertial_pos, linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
            linkParentIndices=parents, linkJointTypes=types, linkJointAxis=axes,
        )
        for link in range(n):
            damping = g.hinge_damping_nms if link in (SWING_A, SWING_B) else 0.0
            spinning = g.claw_spinning_friction_m if link in (CLAW_NEG, CLAW_POS) else 0.0
            c.changeDynamics(body, link, lateralFriction=g.friction, linearDamping=0.0,
                             angularDamping=0.0, jointDamping=damping, spinningFriction=spinning)
            c.changeVisualShape(body, link, rgbaColor=rgba)
        # carriage links have no geometry: give them a sane inertia
        for link in (CARRIAGE_X, CARRIAGE_Y, BOOM_TIP):
            c.changeDynamics(body, link, localInertiaDiagonal=[m * 0.01] * 3)
        self._rgba = rgba
        return body

    def _motors_initial(self, grasp: Grasp, boom_z_m: float) -> None:
        c, g = self.client, self.config
        start = {CARRIAGE_X: grasp.x_m, CARRIAGE_Y: grasp.y_m, BOOM_TIP: boom_z_m,
                 HEAD: grasp.phi_rad, CLAW_NEG: self.q_open, CLAW_POS: self.q_open,
                 SWING_A: 0.0, SWING_B: 0.0}
        for j, q in start.items():
            c.resetJointState(self.body, j, q, 0.0)
        self.hold_xyz(grasp.x_m, grasp.y_m, boom_z_m)
        c.setJointMotorControl2(self.body, HEAD, self.p.POSITION_CONTROL, targetPosition=grasp.phi_rad,
                                force=g.rotator_torque_limit_nm)
        for j in (SWING_A, SWING_B):
            c.setJointMotorControl2(self.body, j, self.p.VELOCITY_CONTROL, targetVelocity=0.0,
                                    force=g.hinge_friction_nm)
        self.set_claws(self.q_open)

    # -- commands ----------------------------------------------------------------------------
    def hold_xyz(self, x_m: float, y_m: float, z_m: float) -> None:
        """Hold the boom tip at a position (position motors at the boom force limit)."""
        c, P, f = self.client, self.p.POSITION_CONTROL, self.config.boom_force_limit_n
        for j, q in ((CARRIAGE_X, x_m), (CARRIAGE_Y, y_m), (BOOM_TIP, z_m)):
            c.setJointMotorControl2(self.body, j, P, targetPosition=q, targetVelocity=0.0, force=f,
                                    positionGain=0.5, velocityGain=1.0)

    def move_z(self, speed_m_s: float) -> None:
        """Drive the boom tip vertically at ``speed_m_s`` (positive = up); x and y stay held."""
        self.client.setJointMotorControl2(self.body, BOOM_TIP, self.p.VELOCITY_CONTROL,
                                          targetVelocity=speed_m_s, force=self.config.boom_force_limit_n)

    def set_claws(self, q_rad: float) -> None:
        """Drive both claws towards angle ``q_rad`` at the closing speed, torque-limited."""
        g = self.config
        for j in (CLAW_NEG, CLAW_POS):
            self.client.setJointMotorControl2(
                self.body, j, self.p.POSITION_CONTROL, targetPosition=q_rad, force=g.claw_torque_limit_nm,
                maxVelocity=g.closing_speed_rad_s, positionGain=0.3, velocityGain=1.0,
            )

    def close(self) -> None:
        """Close both claws as far as the torque limit allows (the tips may pass each other, so a
        small load is squeezed rather than left loose in the claws' bowl)."""
        self.set_claws(self.config.close_angle_rad())

    # -- state -------------------------------------------------------------------------------
    def boom_z(self) -> float:
        return float(self.client.getJointState(self.body, BOOM_TIP)[0])

    def claw_angles(self) -> tuple[float, float]:
        s = self.client.getJointStates(self.body, [CLAW_NEG, CLAW_POS])
        return float(s[0][0]), float(s[1][0])

    def claw_speeds(self) -> tuple[float, float]:
        s = self.client.getJointStates(self.body, [CLAW_NEG, CLAW_POS])
        return float(s[0][1]), float(s[1][1])

    def head_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Head frame: origin [m] and 3x3 rotation (columns u, v, z) in the pile frame."""
        st = self.client.getLinkState(self.body, HEAD, computeForwardKinematics=1)
        R = np.asarray(self.client.getMatrixFromQuaternion(st[5]), dtype=float).reshape(3, 3)
        return np.asarray(st[4], dtype=float), R

    def tips_in_head(self) -> np.ndarray:
        """(2, 2) claw tip (u, z) [m] in the head frame: rows -u claw, +u claw."""
        qn, qp = self.claw_angles()
        tn, tp = self.config.tip_in_head(qn), self.config.tip_in_head(qp)
        return np.array([[-tn[0], tn[1]], [tp[0], tp[1]]])

    @property
    def tip_index_neg(self) -> int:
        """Row of the -u claw tip in :meth:`enclosure_polygon`."""
        return len(self.config.claw_profile_m) - 1

    @property
    def tip_index_pos(self) -> int:
        return len(self.config.claw_profile_m)

    def enclosure_polygon(self) -> np.ndarray:
        """(2k, 2) polygon (u, z) [m] in the head frame between the claws at their current angles:
        -u hinge ... -u tip, +u tip ... +u hinge (closed by the hinge line)."""
        g = self.config
        prof = np.asarray(g.claw_profile_m, dtype=float)
        qn, qp = self.claw_angles()

        def placed(q: float) -> np.ndarray:
            c, s = math.cos(q), math.sin(q)
            u = g.hinge_offset_m + prof[:, 0] * c - prof[:, 1] * s
            z = -g.head_drop_m + prof[:, 0] * s + prof[:, 1] * c
            return np.stack([u, z], axis=1)

        neg = placed(qn) * [-1.0, 1.0]
        pos = placed(qp)
        return np.vstack([neg, pos[::-1]])

    def gap_m(self) -> float:
        """Current tip-to-tip distance along the closing axis [m] (negative = tips overlap)."""
        t = self.tips_in_head()
        return float(t[1, 0] - t[0, 0])

    def tips_world(self) -> np.ndarray:
        """(2, 3) claw tip positions in the pile frame [m]."""
        o, R = self.head_pose()
        t = self.tips_in_head()
        local = np.stack([t[:, 0], np.zeros(2), t[:, 1]], axis=1)
        return o + local @ R.T

    def cos_beta(self) -> float:
        """Balance: cosine of the angle between the grapple's axis (head z) and world z."""
        _, R = self.head_pose()
        return float(R[2, 2])

    def contact_force_n(self, bodies: set[int] | None = None) -> float:
        """Sum of normal contact forces [N] on the grapple this step (from ``bodies`` only, if given)."""
        total = 0.0
        for cp in self.client.getContactPoints(bodyA=self.body):
            if bodies is None or cp[2] in bodies:
                total += cp[9]
        return total

    def penetration_m(self, bodies: set[int] | None = None) -> float:
        """Deepest interpenetration [m] between the grapple and ``bodies`` (all if None), >= 0."""
        worst = 0.0
        for cp in self.client.getContactPoints(bodyA=self.body):
            if bodies is None or cp[2] in bodies:
                worst = max(worst, -cp[8])
        return worst

    def set_visible(self, visible: bool) -> None:
        """Show or hide (alpha 0) the grapple, e.g. before a top-down render of the pile."""
        rgba = self._rgba if visible else [*self._rgba[:3], 0.0]
        for link in range(8):
            self.client.changeVisualShape(self.body, link, rgbaColor=rgba)
