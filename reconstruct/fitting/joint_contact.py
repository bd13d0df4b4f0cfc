"""The bodies of a pile as penalty terms: how deep a log runs into another log, an obstacle or the terrain,
over what the twin's pentagonal prism allows (:mod:`reconstruct.fitting.joint_settle` weighs these against
each log's evidence).

Every log is a cylinder of its butt and top radii about the segment between its end centres (what the scan
sees: the twin's log is round to the eye). The twin collides it as a pentagonal prism inside that round
surface, of a roll the scan cannot see: with a face toward a contact, its surface lies ``1 - cos(36 deg)`` of
its radius inside the round one. A term's ``allow_m`` starts at that (each log of a contact turned face-on)
and is lowered where the twin, with every log at its best roll, still finds the two bodies interpenetrating;
at zero the round surfaces clear, and so do the prisms inside them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from reconstruct.fitting.geometry import points_to_segment, segment_closest
from reconstruct.fitting.separation import PRISM_SIDES
from synth.scene.pile import PileSpec, rotate

#: a prism face lies this share of the round surface's radius inside it (1 - cos(pi / sides)) [-]
ROLL_SHARE = 1.0 - math.cos(math.pi / PRISM_SIDES)
#: a term samples each log this many times along it (two logs side by side meet along a line, not at a point) [-]
SAMPLES = 9
#: ... and a rock's faces this many times (rocks are a few tens of centimetres across) [-]
ROCK_SAMPLES = 41
#: a stump's foot sinks this far into the ground in the twin (synth.physics.world) [m]
STUMP_SINK_M = 0.05


@dataclass
class Segment:
    """A log as the terms see it: end centres ``a``, ``b`` [m] and radii there [m]."""

    a: np.ndarray
    b: np.ndarray
    ra: float
    rb: float

    def radius(self, t: np.ndarray | float) -> np.ndarray | float:
        return self.ra + (self.rb - self.ra) * t

    def points(self, n: int = SAMPLES) -> tuple[np.ndarray, np.ndarray]:
        t = np.linspace(0.0, 1.0, n)
        return self.a + np.outer(t, self.b - self.a), t


@dataclass
class Term:
    """One contact: log ``i`` against ``kind`` ("log", "obstacle", "terrain") number ``j`` (a log: ``j > i``),
    allowed to overlap ``allow_m`` [m] (the prism's roll)."""

    i: int
    kind: str
    j: int
    allow_m: float

    def other(self, k: int) -> str:
        """What log ``k`` meets in this contact."""
        if self.kind == "log":
            return f"log {self.j if k == self.i else self.i}"
        return "the terrain" if self.kind == "terrain" else f"{self.kind} {self.j}"


def log_log_depths(s: Segment, o: Segment) -> np.ndarray:
    """How deep two logs' round surfaces overlap [m] at their closest points and at samples along each
    (negative: apart): 1 + 2 * SAMPLES values."""
    u, v, d = segment_closest(s.a, s.b, o.a, o.b)
    out = [float(s.radius(u) + o.radius(v)) - d]
    P, t = s.points()
    tv, dv = points_to_segment(P, o.a, o.b)
    out.extend(s.radius(t) + o.radius(tv) - dv)
    Q, t = o.points()
    tu, du = points_to_segment(Q, s.a, s.b)
    out.extend(o.radius(t) + s.radius(tu) - du)
    return np.asarray(out)


def stump_point_distance(st: Segment, P: np.ndarray) -> np.ndarray:
    """Each point's signed distance [m] from a stump as a solid truncated cone with a flat top (its axis from
    ``st.a`` up to ``st.b``), negative inside: inside, the nearer of its side and its top; beside it or over
    it, the offset from that one; past its top edge, from the edge (exact for a cylinder)."""
    h = max(float(st.b[2] - st.a[2]), 1e-9)
    t = np.clip((P[:, 2] - st.a[2]) / h, 0.0, 1.0)
    dr = np.hypot(P[:, 0] - st.a[0], P[:, 1] - st.a[1]) - st.radius(t)
    dz = np.maximum(P[:, 2] - st.b[2], st.a[2] - P[:, 2])
    return np.where((dr > 0) & (dz > 0), np.hypot(dr, dz), np.maximum(dr, dz))


def log_stump_depths(s: Segment, st: Segment) -> np.ndarray:
    """How deep log ``s``'s round surface and a flat-topped stump overlap [m] (negative: apart): at the log's
    axis point nearest the stump's axis and at ``ROCK_SAMPLES`` along the log (a stump is tens of centimetres
    across, a log metres long). A log resting on the top is apart from it, not its top radius into it as the
    stump's axis segment with round ends would make it."""
    u, _, _ = segment_closest(s.a, s.b, st.a, st.b)
    P, t = s.points(ROCK_SAMPLES)
    P, t = np.vstack([s.a + u * (s.b - s.a), P]), np.concatenate([[u], t])
    return s.radius(t) - stump_point_distance(st, P)


def stump_segment(pile: PileSpec, j: int) -> Segment:
    """Stump ``j`` as a vertical segment from its sunk foot to its top, with its radii there."""
    st = pile.stumps[j]
    x, y = st.position_m
    r = st.bottom_radius_m
    foot = float(np.min(pile.terrain.height_at(np.array([x - r, x, x + r, x, x]), np.array([y, y - r, y, y + r, y]))))
    return Segment(np.array([x, y, foot - STUMP_SINK_M]), np.array([x, y, foot + st.height_m]), r, st.top_radius_m)


@dataclass(frozen=True)
class Rock:
    """A rock as the terms see it: its hull's vertices, triangles (vertex indices) and their planes
    (``n . x + b <= 0`` inside), pile frame."""

    vertices: np.ndarray
    triangles: np.ndarray
    planes: np.ndarray

    def signed_distance(self, P: np.ndarray) -> np.ndarray:
        """Each point's distance from the rock [m], negative inside (how deep): inside, the nearest face's
        plane; outside, the nearest triangle (its plane where the point lies over it, else its edges)."""
        off = P @ self.planes[:, :3].T + self.planes[:, 3]  # (N, F): outside each face's plane by
        inside = off.max(axis=1)
        T = self.vertices[self.triangles]  # (F, 3 corners, 3)
        q = P[:, None, :] - off[:, :, None] * self.planes[None, :, :3]  # each point projected on each plane
        over = np.ones(off.shape, bool)
        for c in range(3):  # over the triangle: on the inner side of each of its edges
            a, b, o = T[:, c], T[:, (c + 1) % 3], T[:, (c + 2) % 3]
            e = np.cross(b - a, self.planes[:, :3])  # in the plane, across the edge
            over &= np.sign(np.einsum("nfk,fk->nf", q - a[None], e)) == np.sign(np.einsum("fk,fk->f", o - a, e))[None]
        d = np.where(over & (off >= 0), off, np.inf).min(axis=1)
        for c in range(3):
            a, b = T[:, c], T[:, (c + 1) % 3]
            ab = b - a
            t = np.clip(np.einsum("nfk,fk->nf", P[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-12), 0, 1)
            d = np.minimum(d, np.linalg.norm(P[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1))
        return np.where(inside <= 0, inside, d)

    def depths(self, s: Segment) -> np.ndarray:
        """How deep log ``s`` and the rock overlap [m]: at each rock vertex (a corner in the log's side) and at
        samples along the log's axis (a face or an edge across it)."""
        t, d = points_to_segment(self.vertices, s.a, s.b)
        P, tp = s.points(ROCK_SAMPLES)
        return np.concatenate([s.radius(t) - d, s.radius(tp) - self.signed_distance(P)])


def rock_of(pile: PileSpec, j: int) -> Rock:
    """Rock ``j`` of ``pile`` as a :class:`Rock`."""
    from scipy.spatial import ConvexHull

    rk = pile.rocks[j]
    V = np.array([rotate(rk.orientation, v) for v in rk.vertices_m]) + np.asarray(rk.position_m, dtype=float)
    hull = ConvexHull(V)  # a rock is the hull of its vertices: the reconstruction made it from one
    return Rock(V, hull.simplices, hull.equations)


class Bodies:
    """The fixed bodies of a pile (obstacles, terrain) and the depth of a log into each. ``flat_stumps``: a
    stump is a flat-topped cone (:func:`log_stump_depths`); off, its axis segment with round ends, as a log
    (joint revision 12)."""

    def __init__(self, pile: PileSpec, flat_stumps: bool = False) -> None:
        self.pile, self.flat_stumps = pile, flat_stumps
        self.stumps = [stump_segment(pile, j) for j in range(len(pile.stumps))]
        self.rocks = [rock_of(pile, j) for j in range(len(pile.rocks))]

    @property
    def n_obstacles(self) -> int:
        return len(self.stumps) + len(self.rocks)

    def obstacle_depths(self, s: Segment, j: int) -> np.ndarray:
        """How deep log ``s`` and obstacle ``j`` (stumps first, then rocks: the twin's order) overlap [m]."""
        if j < len(self.stumps):
            return log_stump_depths(s, self.stumps[j]) if self.flat_stumps else log_log_depths(s, self.stumps[j])
        return self.rocks[j - len(self.stumps)].depths(s)

    def terrain_depths(self, s: Segment) -> np.ndarray:
        """How far log ``s``'s round underside lies under the terrain at samples along it [m]."""
        P, t = s.points()
        return self.pile.terrain.height_at(P[:, 0], P[:, 1]) - (P[:, 2] - s.radius(t))

    def depths(self, term: Term, segs: Sequence[Segment]) -> np.ndarray:
        s = segs[term.i]
        if term.kind == "log":
            return log_log_depths(s, segs[term.j])
        if term.kind == "obstacle":
            return self.obstacle_depths(s, term.j)
        return self.terrain_depths(s)

    def terms(self, segs: Sequence[Segment], reach_m: float) -> list[Term]:
        """The contacts that may matter: every pair of bodies closer than ``reach_m`` (a log's largest
        correction) beyond touching, each allowed the prism's roll."""
        out = []
        for i, s in enumerate(segs):
            r_i = 0.5 * (s.ra + s.rb)
            for j in range(i + 1, len(segs)):
                o = segs[j]
                if log_log_depths(s, o).max() > -reach_m:
                    out.append(Term(i, "log", j, ROLL_SHARE * (r_i + 0.5 * (o.ra + o.rb))))
            for j in range(self.n_obstacles):
                if self.obstacle_depths(s, j).max() > -reach_m:
                    out.append(Term(i, "obstacle", j, ROLL_SHARE * r_i))
            out.append(Term(i, "terrain", -1, ROLL_SHARE * r_i))
        return out
