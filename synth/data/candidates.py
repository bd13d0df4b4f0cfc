"""Rule-based geometric grasp candidates for a target subset (the paper's "Grasp candidate
reduction" input), from the *exact* pile geometry.

This search is only for data generation: it needs every log's and obstacle's true pose and shape.
It takes no dynamics into account; the candidates are then tested in simulation by the paper's
Algorithm 1, :func:`reduce_candidates`.

Geometry, all in the pile-frame plane (x, y):

* a log is its axis segment (end centres projected) with radius ``max(butt, top) / 2`` and the
  height of its axis interpolated along the segment;
* a stump is a disc (bottom radius plus the horizontal reach of its roots);
* a rock is the convex hull of its posed vertices projected down;
* a grasp ``(x, y, φ, w)`` has its *closing segment* from claw to claw, ``c ± a·w/2`` with
  ``a = (cos φ, sin φ)``, and each claw is a segment of ``claw_width_m`` across ``a`` (along
  ``b = (-sin φ, cos φ)``) at one end.

A candidate for targets ``T``

1. has its closing axis at ``φ = φ̄ + δ`` where ``φ̄`` is the mean perpendicular of the targets'
   axes and ``|δ| <= max_dphi_rad``;
2. is centred on a line through a point ``s`` of the targets' *common extent* (the stretch of the
   mean axis that every target covers, shortened by ``end_margin_m`` at both ends);
3. crosses every target axis inside the target (at least ``end_margin_m`` from its ends), and
   spans all crossings plus each target's radius plus ``side_margin_m`` on both sides: the
   width is that span (at least 0.30 m; candidates needing more than 1.55 m are dropped);
4. keeps both claws ``claw_clearance_m`` away from every log (targets included) and obstacle;
5. has no non-target log crossing its closing segment higher than ``under_tolerance_m`` below the
   lowest target crossing (that log would be reached before the targets), and no obstacle
   footprint inside the grapple's footprint (claw to claw, ``claw_width_m`` wide).

Besides the narrowest width (rule 3), each position is also tried ``extra_widths_m`` wider, centred
and shifted by ±extra/2 along the closing axis, so that a claw that would land on a neighbour can
reach past it (the candidate list stays sorted narrowest first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator, Sequence

import numpy as np

from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, RECT_WIDTH_M, Grasp
from synth.scene.pile import PileSpec, rotate


@dataclass(frozen=True)
class CandidateConfig:
    """How candidates are sampled and filtered.

    The rules only drop what the trial would refuse anyway, so that the trial budget
    (``max_trials_per_subset``) goes to grasps that can work: docs/trials.md ("Negatives and the
    candidate rules") has the measurement behind each value."""

    n_phi: int = 9  # closing-axis angles sampled around the mean perpendicular [-] (11.25 deg apart)
    max_dphi_rad: float = math.radians(45.0)  # largest deviation from the mean perpendicular [rad]:
    # crossed logs' best closing axis can lie 45 deg off their mean perpendicular
    step_m: float = 0.10  # spacing of candidate centres along the targets' common extent [m]
    end_margin_m: float = 0.15  # keep crossings this far from a target's ends [m]: the 0.22 m claw
    # plate, centred 0.15 m in, still bears on the log
    side_margin_m: float = 0.08  # free space between the outermost target and a claw [m]
    claw_width_m: float = 0.22  # claw extent across the closing axis [m]
    claw_clearance_m: float = 0.03  # claws keep this far from logs and obstacles (> half the 5 cm plate) [m]
    under_tolerance_m: float = 0.20  # a non-target this far below the lowest target may cross [m]: nearer,
    # the closing claws sweep it up with the targets (MORE_THAN_INTENDED)
    extra_widths_m: tuple[float, ...] = (0.0, 0.15, 0.30)  # also try this much wider, shifted [m]
    max_candidates: int | None = None  # keep at most this many (narrowest first); None = all

    def __post_init__(self) -> None:
        if not 1 <= self.n_phi <= 181:
            raise ValueError(f"n_phi must be in [1, 181], got {self.n_phi}")
        if not 0 <= self.max_dphi_rad < math.pi / 2:
            raise ValueError("max_dphi_rad must be in [0, pi/2)")
        for name in ("step_m", "claw_width_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 m, got {getattr(self, name)}")
        for name in ("end_margin_m", "side_margin_m", "claw_clearance_m", "under_tolerance_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be a finite number >= 0 m, got {getattr(self, name)}")
        if not self.extra_widths_m or any(not (math.isfinite(e) and e >= 0) for e in self.extra_widths_m):
            raise ValueError(f"extra_widths_m must be finite widths >= 0 m, got {self.extra_widths_m}")
        if self.max_candidates is not None and self.max_candidates < 1:
            raise ValueError("max_candidates must be >= 1 or None")


# ---------------------------------------------------------------------------------------------
# plane geometry
# ---------------------------------------------------------------------------------------------
def _psd(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """Distance from point p to segment ab (plain floats: this is the search's inner loop)."""
    dx, dy = bx - ax, by - ay
    L2 = dx * dx + dy * dy
    t = 0.0 if L2 < 1e-18 else min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / L2))
    return math.hypot(px - ax - t * dx, py - ay - t * dy)


def _sint(p1x, p1y, p2x, p2y, q1x, q1y, q2x, q2y) -> bool:
    d1x, d1y, d2x, d2y = p2x - p1x, p2y - p1y, q2x - q1x, q2y - q1y
    den = d1x * d2y - d1y * d2x
    if abs(den) < 1e-15:
        return False  # parallel: the distance test covers touching
    wx, wy = q1x - p1x, q1y - p1y
    t = (wx * d2y - wy * d2x) / den
    u = (wx * d1y - wy * d1x) / den
    return -1e-12 <= t <= 1 + 1e-12 and -1e-12 <= u <= 1 + 1e-12


def _ssd(p1x, p1y, p2x, p2y, q1x, q1y, q2x, q2y) -> float:
    if _sint(p1x, p1y, p2x, p2y, q1x, q1y, q2x, q2y):
        return 0.0
    return min(_psd(p1x, p1y, q1x, q1y, q2x, q2y), _psd(p2x, p2y, q1x, q1y, q2x, q2y),
               _psd(q1x, q1y, p1x, p1y, p2x, p2y), _psd(q2x, q2y, p1x, p1y, p2x, p2y))


def _cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def _point_segment_dist(p, a, b) -> float:
    return _psd(float(p[0]), float(p[1]), float(a[0]), float(a[1]), float(b[0]), float(b[1]))


def segments_intersect(p1, p2, q1, q2) -> bool:
    """Do the closed segments p1p2 and q1q2 intersect (2-D)?"""
    return _sint(*(float(v) for pt in (p1, p2, q1, q2) for v in pt[:2]))


def segment_distance(p1, p2, q1, q2) -> float:
    """Shortest distance between two 2-D segments."""
    return _ssd(*(float(v) for pt in (p1, p2, q1, q2) for v in pt[:2]))


def _inside_convex_f(px: float, py: float, poly: Sequence[tuple[float, float]]) -> bool:
    pos = neg = False
    n = len(poly)
    for i in range(n):
        ax, ay = poly[i]
        bx, by = poly[(i + 1) % n]
        c = (bx - ax) * (py - ay) - (by - ay) * (px - ax)
        pos |= c > 1e-12
        neg |= c < -1e-12
    return not (pos and neg)


def _inside_convex(p, poly) -> bool:
    return _inside_convex_f(float(p[0]), float(p[1]), [(float(x), float(y)) for x, y in poly])


def segment_polygon_distance(p1, p2, poly) -> float:
    """Distance from a segment to a convex polygon (0 when they overlap)."""
    P = [(float(x), float(y)) for x, y in poly]
    return _seg_poly_f(float(p1[0]), float(p1[1]), float(p2[0]), float(p2[1]), P)


def _seg_poly_f(p1x, p1y, p2x, p2y, P) -> float:
    if _inside_convex_f(p1x, p1y, P) or _inside_convex_f(p2x, p2y, P):
        return 0.0
    n = len(P)
    return min(_ssd(p1x, p1y, p2x, p2y, *P[i], *P[(i + 1) % n]) for i in range(n))


def _convex_overlap_f(A, B) -> bool:
    """Do two convex polygons (lists of (x, y)) overlap or touch?"""
    if any(_inside_convex_f(x, y, B) for x, y in A) or any(_inside_convex_f(x, y, A) for x, y in B):
        return True
    na, nb = len(A), len(B)
    return any(_sint(*A[i], *A[(i + 1) % na], *B[j], *B[(j + 1) % nb]) for i in range(na) for j in range(nb))


def _convex_hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (monotone chain) of 2-D points."""
    pts = sorted(set(map(tuple, np.round(np.asarray(points, float), 12))))
    if len(pts) <= 2:
        return np.asarray(pts)

    def half(seq):
        h: list = []
        for p in seq:
            while len(h) >= 2 and _cross(np.subtract(h[-1], h[-2]), np.subtract(p, h[-2])) <= 0:
                h.pop()
            h.append(p)
        return h

    lower, upper = half(pts), half(reversed(pts))
    return np.asarray(lower[:-1] + upper[:-1])


# ---------------------------------------------------------------------------------------------
# the pile in the plane
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LogFootprint:
    p0: np.ndarray  # (3,) butt end centre [m]
    p1: np.ndarray  # (3,) top end centre [m]
    radius_m: float

    @property
    def a2(self) -> np.ndarray:
        return self.p0[:2]

    @property
    def b2(self) -> np.ndarray:
        return self.p1[:2]


@dataclass(frozen=True)
class PlaneScene:
    """The pile reduced to what the candidate rules need."""

    logs: tuple[LogFootprint, ...]
    discs: tuple[tuple[np.ndarray, float], ...]  # stumps: centre (2,), radius [m]
    polygons: tuple[np.ndarray, ...]  # rocks: convex (n, 2) [m]

    @staticmethod
    def from_pile(pile: PileSpec) -> "PlaneScene":
        logs = tuple(
            LogFootprint(*(np.asarray(e, float) for e in log.endpoints_m()), radius_m=max(log.diameter_m, log.top_d_m) / 2)
            for log in pile.logs
        )
        discs = []
        for s in pile.stumps:
            reach = max([0.0] + [r.length_m * math.sin(r.tilt_rad) + r.radius_m for r in s.roots])
            discs.append((np.asarray(s.position_m, float), float(max(s.bottom_radius_m, reach))))
        polys = []
        for r in pile.rocks:
            v = np.array([rotate(r.orientation, p) for p in r.vertices_m]) + np.asarray(r.position_m)
            polys.append(_convex_hull(v[:, :2]))
        return PlaneScene(logs=logs, discs=tuple(discs), polygons=tuple(polys))

    def _floats(self):
        """Plain-float copies for the inner loop (cached): logs (ax, ay, bx, by, r, z0, z1),
        discs (cx, cy, r), polygons (vertex list, centre x, centre y, bounding radius)."""
        cached = getattr(self, "_cache", None)
        if cached is None:
            logs = [(float(l.p0[0]), float(l.p0[1]), float(l.p1[0]), float(l.p1[1]), float(l.radius_m),
                     float(l.p0[2]), float(l.p1[2])) for l in self.logs]
            discs = [(float(c[0]), float(c[1]), float(r)) for c, r in self.discs]
            polys = []
            for poly in self.polygons:
                P = [(float(x), float(y)) for x, y in poly]
                cx, cy = float(np.mean(poly[:, 0])), float(np.mean(poly[:, 1]))
                polys.append((P, cx, cy, max(math.hypot(x - cx, y - cy) for x, y in P)))
            cached = (logs, discs, polys)
            object.__setattr__(self, "_cache", cached)
        return cached


def _crossing(c: np.ndarray, a: np.ndarray, log: LogFootprint) -> tuple[float, float, float] | None:
    """Where the line ``c + t·a`` crosses the log axis: (t [m], s in [0, 1] along the log,
    axis height z [m]); None if parallel."""
    p, q = log.a2, log.b2
    d = q - p
    den = _cross(a, d)
    if abs(den) < 1e-12:
        return None
    t = _cross(p - c, d) / den
    s = _cross(p - c, a) / den
    z = float(log.p0[2] + s * (log.p1[2] - log.p0[2]))
    return t, s, z


# ---------------------------------------------------------------------------------------------
# the search
# ---------------------------------------------------------------------------------------------
def generate_candidates(pile: PileSpec | PlaneScene, targets: Iterable[int],
                        config: CandidateConfig | None = None) -> list[Grasp]:
    """Geometric grasp candidates for target subset ``targets`` (log indices), narrowest first.

    ``pile`` may be a :class:`PileSpec` or an already reduced :class:`PlaneScene`. Returns an
    empty list when the targets share no common stretch or nothing passes the rules.
    """
    config = config or CandidateConfig()
    scene = pile if isinstance(pile, PlaneScene) else PlaneScene.from_pile(pile)
    T = sorted({int(t) for t in targets})
    if not T:
        raise ValueError("the target subset is empty; give at least one log index")
    if T[0] < 0 or T[-1] >= len(scene.logs):
        raise ValueError(f"target indices {T} outside the pile's {len(scene.logs)} logs")
    tl = [scene.logs[i] for i in T]
    axis = _common_axis(tl)
    if axis is None:
        return []
    dbar, origin = axis
    s_values = _stretch_positions(tl, dbar, origin, config)
    if s_values is None:
        return []
    phi0 = math.atan2(dbar[1], dbar[0]) + math.pi / 2
    dphis = np.linspace(-config.max_dphi_rad, config.max_dphi_rad, config.n_phi) if config.n_phi > 1 else [0.0]
    others = [i for i in range(len(scene.logs)) if i not in T]
    out: list[Grasp] = []
    seen: set = set()
    for dphi in dphis:
        phi = phi0 + dphi
        a = np.array([math.cos(phi), math.sin(phi)])
        b = np.array([-a[1], a[0]])
        for s in s_values:
            p = origin + dbar * s
            crossings = _crossings_within(p, a, tl, config)
            if crossings is None:
                continue
            for c, width in _closings(p, a, phi, crossings, seen, config):
                if _admissible(scene, c, a, b, width, others, crossings.z_min, config):
                    out.append(Grasp(float(c[0]), float(c[1]), float(phi), float(min(width, MAX_WIDTH_M))))
    out.sort(key=lambda g: g.width_m)
    if config.max_candidates is not None:
        out = out[: config.max_candidates]
    return out


def _common_axis(tl: list) -> tuple[np.ndarray, np.ndarray] | None:
    """The targets' mean axis direction in the plane (sign-aligned: axes are undirected) and the
    mean of their centres; None when a log stands on end or the axes cancel."""
    dirs = []
    for lg in tl:
        d = lg.b2 - lg.a2
        n = np.linalg.norm(d)
        if n < 1e-6:
            return None  # a log standing on end has no usable axis in the plane
        d = d / n
        if dirs and d @ dirs[0] < 0:
            d = -d
        dirs.append(d)
    dbar = np.mean(dirs, axis=0)
    if np.linalg.norm(dbar) < 1e-6:
        return None
    dbar /= np.linalg.norm(dbar)
    return dbar, np.mean([(lg.a2 + lg.b2) / 2 for lg in tl], axis=0)


def _stretch_positions(tl: list, dbar: np.ndarray, origin: np.ndarray, config: CandidateConfig) -> np.ndarray | None:
    """Positions along ``dbar`` (from ``origin``, every ``step_m``, centred) on the stretch all
    targets share, ``end_margin_m`` in from their ends; None when they share none."""
    lo, hi = -np.inf, np.inf
    for lg in tl:
        s0, s1 = sorted(((lg.a2 - origin) @ dbar, (lg.b2 - origin) @ dbar))
        lo, hi = max(lo, s0 + config.end_margin_m), min(hi, s1 - config.end_margin_m)
    if lo > hi:
        return None
    n_s = int(math.floor((hi - lo) / config.step_m)) + 1
    return lo + (hi - lo - (n_s - 1) * config.step_m) / 2 + config.step_m * np.arange(n_s)


@dataclass(frozen=True)
class _Crossings:
    """Where a closing line crosses the targets: its extent along the line with the side margins
    [m] and the lowest axis height under it [m]."""

    t_lo: float
    t_hi: float
    z_min: float


def _crossings_within(p: np.ndarray, a: np.ndarray, tl: list, config: CandidateConfig) -> _Crossings | None:
    """The line through ``p`` along ``a`` across every target, each crossed ``end_margin_m`` in
    from its ends; None when it misses one."""
    crossings = []
    for lg in tl:
        cr = _crossing(p, a, lg)
        if cr is None:
            return None
        t, sl, z = cr
        L = float(np.linalg.norm(lg.b2 - lg.a2))
        if not (config.end_margin_m / L <= sl <= 1 - config.end_margin_m / L):
            return None
        crossings.append((t, lg.radius_m, z))
    return _Crossings(t_lo=min(t - r for t, r, _ in crossings) - config.side_margin_m,
                      t_hi=max(t + r for t, r, _ in crossings) + config.side_margin_m,
                      z_min=min(z for _, _, z in crossings))


def _closings(p: np.ndarray, a: np.ndarray, phi: float, crossings: _Crossings, seen: set,
              config: CandidateConfig) -> Iterator[tuple[np.ndarray, float]]:
    """Grapple centres and widths on this line not tried before (``seen``): each of the
    ``extra_widths_m`` over the targets' span, centred and shifted by half the extra each way."""
    span = max(crossings.t_hi - crossings.t_lo, MIN_WIDTH_M)
    mid = (crossings.t_lo + crossings.t_hi) / 2
    for extra in config.extra_widths_m:
        width = span + extra
        if width > MAX_WIDTH_M + 1e-9:
            continue
        for shift in sorted({0.0, -extra / 2, extra / 2}):
            c = p + a * (mid + shift)
            key = (round(float(c[0]), 4), round(float(c[1]), 4), round(float(phi), 4), round(width, 4))
            if key in seen:
                continue
            seen.add(key)
            yield c, width


def _admissible(scene: PlaneScene, c: np.ndarray, a: np.ndarray, b: np.ndarray, width: float,
                others: Sequence[int], z_min: float, cfg: CandidateConfig) -> bool:
    logs, discs, polys = scene._floats()
    cx, cy, ax, ay, bx, by = float(c[0]), float(c[1]), float(a[0]), float(a[1]), float(b[0]), float(b[1])
    hw, hr, clr = cfg.claw_width_m / 2, width / 2, cfg.claw_clearance_m
    e1x, e1y, e2x, e2y = cx - ax * hr, cy - ay * hr, cx + ax * hr, cy + ay * hr
    claws = [(ex - bx * hw, ey - by * hw, ex + bx * hw, ey + by * hw, ex, ey) for ex, ey in ((e1x, e1y), (e2x, e2y))]
    # 4. claws clear of every log and obstacle
    for lax, lay, lbx, lby, r, _, _ in logs:
        for q1x, q1y, q2x, q2y, ex, ey in claws:
            if _psd(ex, ey, lax, lay, lbx, lby) > hw + r + clr:
                continue  # the claw's bounding circle is clear
            if _ssd(q1x, q1y, q2x, q2y, lax, lay, lbx, lby) < r + clr:
                return False
    for dx, dy, r in discs:
        for q1x, q1y, q2x, q2y, _, _ in claws:
            if _psd(dx, dy, q1x, q1y, q2x, q2y) < r + clr:
                return False
    for P, pcx, pcy, R in polys:
        for q1x, q1y, q2x, q2y, ex, ey in claws:
            if math.hypot(ex - pcx, ey - pcy) > R + hw + clr:
                continue
            if _seg_poly_f(q1x, q1y, q2x, q2y, P) < clr:
                return False
    # 5a. no non-target log crossing between the claws above the targets
    for i in others:
        lax, lay, lbx, lby, r, z0, z1 = logs[i]
        if _sint(e1x, e1y, e2x, e2y, lax, lay, lbx, lby):
            cr = _crossing(c, a, scene.logs[i])
            if cr is None or cr[2] > z_min - cfg.under_tolerance_m:
                return False
    # 5b. no obstacle inside the grapple's footprint (claw to claw, claw_width wide)
    rect = [(e1x - bx * hw, e1y - by * hw), (e2x - bx * hw, e2y - by * hw),
            (e2x + bx * hw, e2y + by * hw), (e1x + bx * hw, e1y + by * hw)]
    reach = math.hypot(hr, hw)
    for dx, dy, r in discs:
        if math.hypot(dx - cx, dy - cy) > reach + r:
            continue
        if _inside_convex_f(dx, dy, rect) or min(_psd(dx, dy, *rect[k], *rect[(k + 1) % 4]) for k in range(4)) < r:
            return False
    for P, pcx, pcy, R in polys:
        if math.hypot(pcx - cx, pcy - cy) > reach + R:
            continue
        if _convex_overlap_f(rect, P):
            return False
    return True


# ---------------------------------------------------------------------------------------------
# Algorithm 1: grasp candidate reduction
# ---------------------------------------------------------------------------------------------
def rectangle_overlap_area(g1: Grasp, g2: Grasp, rect_width_m: float = RECT_WIDTH_M) -> float:
    """Intersection area [m²] of the two grasps' rectangles (``width_m`` x 20 cm), exact
    (OpenCV's convex-polygon intersection)."""
    import cv2

    r1 = g1.rectangle(rect_width_m).astype(np.float32)
    r2 = g2.rectangle(rect_width_m).astype(np.float32)
    area, _ = cv2.intersectConvexConvex(r1, r2)
    return max(0.0, float(area))


@dataclass
class ReductionResult:
    """What Algorithm 1 returns for one target subset."""

    accepted: list[tuple[Grasp, object]]  # (grasp, the successful trial result) in acceptance order
    trials: list[tuple[Grasp, object]]  # every simulated grasp and its result, in order
    widened: int = 0  # accepted grasps that were widened by Δw
    capped: bool = False  # stopped by max_trials with candidates left
    confirmations: dict[int, object] = field(default_factory=dict)  # trial index -> its robust repeats
    unconfirmed: int = 0  # exact successes refused because their repeats failed too often

    @property
    def n_trials(self) -> int:
        return len(self.trials)


def _succeeded(result: object) -> bool:
    ok = getattr(result, "success", None)
    if ok is None:
        outcome = getattr(result, "outcome", None)
        ok = getattr(outcome, "ok", None)
        if ok is None:
            ok = str(getattr(outcome, "value", outcome)).lower() == "success"
    return bool(ok)


def reduce_candidates(candidates: Sequence[Grasp], simulate: Callable[[Grasp], object],
                      rng: np.random.Generator | None = None, overlap_m2: float = 0.04,
                      dw_range_m: tuple[float, float] = (0.05, 0.10), max_trials: int | None = None,
                      rect_width_m: float = RECT_WIDTH_M,
                      confirm: Callable[[Grasp], object] | None = None) -> ReductionResult:
    """The paper's Algorithm 1 over ``candidates`` with ``simulate(grasp) -> result`` (a
    :class:`synth.physics.trial.TrialResult` or anything with ``.success`` or ``.outcome``).

    While candidates remain: take the narrowest ``g`` (ties: the earliest listed) and simulate
    it; on success draw ``Δw ~ U(dw_range_m)``, simulate ``(x, y, φ, w + Δw)`` (skipped when that
    exceeds 1.55 m) and keep the wider grasp if it also succeeds; accept it and drop every
    remaining candidate whose 20 cm grasp rectangle overlaps the accepted one by more than
    ``overlap_m2``; drop ``g``. ``max_trials`` (simulations, widening included) stops early.

    With ``confirm(grasp) -> Confirmation`` (:mod:`synth.data.robust`), the grasp to be accepted
    (the wider one, else ``g``) must also pass its perturbed repeats; when the wider one does not,
    ``g`` is confirmed in its place; when neither does, nothing is accepted and no candidate is
    dropped but ``g``. Repeats are labels, not search: they do not count towards ``max_trials``.
    """
    if not overlap_m2 >= 0:
        raise ValueError(f"overlap_m2 must be >= 0 m², got {overlap_m2}")
    if not 0 <= dw_range_m[0] <= dw_range_m[1]:
        raise ValueError(f"dw_range_m must be an increasing range >= 0, got {dw_range_m}")
    if max_trials is not None and max_trials < 1:
        raise ValueError("max_trials must be >= 1 or None")
    rng = rng if rng is not None else np.random.default_rng(0)
    G = sorted(enumerate(candidates), key=lambda ig: (ig[1].width_m, ig[0]))
    G = [g for _, g in G]
    res = ReductionResult(accepted=[], trials=[])

    def budget_left() -> bool:
        return max_trials is None or res.n_trials < max_trials

    while G:
        if not budget_left():
            res.capped = True
            break
        g = G.pop(0)  # narrowest (G is kept sorted)
        r = simulate(g)
        res.trials.append((g, r))
        if not _succeeded(r):
            continue
        options = [(len(res.trials) - 1, g, r)]  # (trial index, grasp, result), preferred last
        dw = float(rng.uniform(*dw_range_m))
        if g.width_m + dw <= MAX_WIDTH_M and budget_left():
            wide = Grasp(g.x_m, g.y_m, g.phi_rad, g.width_m + dw)
            r2 = simulate(wide)
            res.trials.append((wide, r2))
            if _succeeded(r2):
                options.append((len(res.trials) - 1, wide, r2))
        chosen = _first_confirmed(options[::-1], confirm, res)
        if chosen is None:
            continue
        best, best_r = chosen
        res.widened += int(best is not g)
        res.accepted.append((best, best_r))
        G = [h for h in G if rectangle_overlap_area(best, h, rect_width_m) <= overlap_m2]
    return res


def _first_confirmed(options, confirm, res: ReductionResult) -> tuple[Grasp, object] | None:
    """The first option (trial index, grasp, result) whose repeats pass ``confirm`` (the first
    option when there is no ``confirm``); the repeats are recorded under the trial index."""
    for i, g, r in options:
        if confirm is None:
            return g, r
        c = confirm(g)
        res.confirmations[i] = c
        if c.accepted:
            return g, r
        res.unconfirmed += 1
    return None
