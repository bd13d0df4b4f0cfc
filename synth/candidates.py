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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

import numpy as np

from synth.grasp import MAX_WIDTH_M, MIN_WIDTH_M, RECT_WIDTH_M, Grasp
from synth.pile import PileSpec, rotate


@dataclass(frozen=True)
class CandidateConfig:
    """How candidates are sampled and filtered."""

    n_phi: int = 7  # closing-axis angles sampled around the mean perpendicular [-]
    max_dphi_rad: float = math.radians(30.0)  # largest deviation from the mean perpendicular [rad]
    step_m: float = 0.10  # spacing of candidate centres along the targets' common extent [m]
    end_margin_m: float = 0.30  # keep crossings this far from a target's ends [m]
    side_margin_m: float = 0.08  # free space between the outermost target and a claw [m]
    claw_width_m: float = 0.22  # claw extent across the closing axis [m]
    claw_clearance_m: float = 0.05  # claws keep this far from logs and obstacles [m]
    under_tolerance_m: float = 0.10  # a non-target this far below the lowest target may cross [m]
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
        if self.max_candidates is not None and self.max_candidates < 1:
            raise ValueError("max_candidates must be >= 1 or None")


# ---------------------------------------------------------------------------------------------
# plane geometry
# ---------------------------------------------------------------------------------------------
def _point_segment_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    d = b - a
    L2 = float(d @ d)
    t = 0.0 if L2 < 1e-18 else min(1.0, max(0.0, float((p - a) @ d) / L2))
    return float(np.linalg.norm(p - (a + t * d)))


def _cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def segments_intersect(p1, p2, q1, q2) -> bool:
    """Do the closed segments p1p2 and q1q2 intersect (2-D)?"""
    p1, p2, q1, q2 = (np.asarray(v, dtype=float) for v in (p1, p2, q1, q2))
    d1, d2 = p2 - p1, q2 - q1
    den = _cross(d1, d2)
    if abs(den) < 1e-15:
        return False  # parallel: the distance test covers touching
    t = _cross(q1 - p1, d2) / den
    u = _cross(q1 - p1, d1) / den
    return -1e-12 <= t <= 1 + 1e-12 and -1e-12 <= u <= 1 + 1e-12


def segment_distance(p1, p2, q1, q2) -> float:
    """Shortest distance between two 2-D segments."""
    p1, p2, q1, q2 = (np.asarray(v, dtype=float) for v in (p1, p2, q1, q2))
    if segments_intersect(p1, p2, q1, q2):
        return 0.0
    return min(_point_segment_dist(p1, q1, q2), _point_segment_dist(p2, q1, q2),
               _point_segment_dist(q1, p1, p2), _point_segment_dist(q2, p1, p2))


def segment_polygon_distance(p1, p2, poly: np.ndarray) -> float:
    """Distance from a segment to a convex polygon (0 when they overlap)."""
    poly = np.asarray(poly, dtype=float)
    if _inside_convex(np.asarray(p1, float), poly) or _inside_convex(np.asarray(p2, float), poly):
        return 0.0
    n = len(poly)
    return min(segment_distance(p1, p2, poly[i], poly[(i + 1) % n]) for i in range(n))


def _inside_convex(p: np.ndarray, poly: np.ndarray) -> bool:
    signs = [_cross(poly[(i + 1) % len(poly)] - poly[i], p - poly[i]) for i in range(len(poly))]
    return all(s >= -1e-12 for s in signs) or all(s <= 1e-12 for s in signs)


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
    # mean axis direction (sign-aligned: axes are undirected)
    dirs = []
    for lg in tl:
        d = lg.b2 - lg.a2
        n = np.linalg.norm(d)
        if n < 1e-6:
            return []  # a log standing on end has no usable axis in the plane
        d = d / n
        if dirs and d @ dirs[0] < 0:
            d = -d
        dirs.append(d)
    dbar = np.mean(dirs, axis=0)
    if np.linalg.norm(dbar) < 1e-6:
        return []
    dbar /= np.linalg.norm(dbar)
    origin = np.mean([(lg.a2 + lg.b2) / 2 for lg in tl], axis=0)
    # common extent along dbar
    lo, hi = -np.inf, np.inf
    for lg in tl:
        s0, s1 = sorted(((lg.a2 - origin) @ dbar, (lg.b2 - origin) @ dbar))
        lo, hi = max(lo, s0 + config.end_margin_m), min(hi, s1 - config.end_margin_m)
    if lo > hi:
        return []
    n_s = int(math.floor((hi - lo) / config.step_m)) + 1
    s_values = lo + (hi - lo - (n_s - 1) * config.step_m) / 2 + config.step_m * np.arange(n_s)
    phi0 = math.atan2(dbar[1], dbar[0]) + math.pi / 2
    dphis = np.linspace(-config.max_dphi_rad, config.max_dphi_rad, config.n_phi) if config.n_phi > 1 else [0.0]
    others = [i for i in range(len(scene.logs)) if i not in T]

    out: list[Grasp] = []
    seen = set()
    for dphi in dphis:
        phi = phi0 + dphi
        a = np.array([math.cos(phi), math.sin(phi)])
        b = np.array([-a[1], a[0]])
        for s in s_values:
            p = origin + dbar * s
            crossings = []
            for lg in tl:
                cr = _crossing(p, a, lg)
                if cr is None:
                    break
                t, sl, z = cr
                L = float(np.linalg.norm(lg.b2 - lg.a2))
                if not (config.end_margin_m / L <= sl <= 1 - config.end_margin_m / L):
                    break
                crossings.append((t, lg.radius_m, z))
            else:
                t_lo = min(t - r for t, r, _ in crossings) - config.side_margin_m
                t_hi = max(t + r for t, r, _ in crossings) + config.side_margin_m
                width = max(t_hi - t_lo, MIN_WIDTH_M)
                if width > MAX_WIDTH_M:
                    continue
                c = p + a * (t_lo + t_hi) / 2
                key = (round(float(c[0]), 4), round(float(c[1]), 4), round(float(phi), 4))
                if key in seen:
                    continue
                seen.add(key)
                z_min = min(z for _, _, z in crossings)
                if _admissible(scene, c, a, b, width, others, z_min, config):
                    out.append(Grasp(float(c[0]), float(c[1]), float(phi), float(width)))
    out.sort(key=lambda g: g.width_m)
    if config.max_candidates is not None:
        out = out[: config.max_candidates]
    return out


def _admissible(scene: PlaneScene, c: np.ndarray, a: np.ndarray, b: np.ndarray, width: float,
                others: Sequence[int], z_min: float, cfg: CandidateConfig) -> bool:
    e1, e2 = c - a * width / 2, c + a * width / 2
    hw = cfg.claw_width_m / 2
    claws = [(e - b * hw, e + b * hw) for e in (e1, e2)]
    # 4. claws clear of every log and obstacle
    for lg in scene.logs:
        for q1, q2 in claws:
            if segment_distance(q1, q2, lg.a2, lg.b2) < lg.radius_m + cfg.claw_clearance_m:
                return False
    for centre, r in scene.discs:
        for q1, q2 in claws:
            if _point_segment_dist(centre, q1, q2) < r + cfg.claw_clearance_m:
                return False
    for poly in scene.polygons:
        for q1, q2 in claws:
            if segment_polygon_distance(q1, q2, poly) < cfg.claw_clearance_m:
                return False
    # 5a. no non-target log crossing between the claws above the targets
    for i in others:
        lg = scene.logs[i]
        if segments_intersect(e1, e2, lg.a2, lg.b2):
            cr = _crossing(c, a, lg)
            if cr is None or cr[2] > z_min - cfg.under_tolerance_m:
                return False
    # 5b. no obstacle inside the grapple's footprint (claw to claw, claw_width wide)
    rect = np.array([e1 - b * hw, e2 - b * hw, e2 + b * hw, e1 + b * hw])
    for centre, r in scene.discs:
        if _inside_convex(centre, rect) or min(
                _point_segment_dist(centre, rect[k], rect[(k + 1) % 4]) for k in range(4)) < r:
            return False
    for poly in scene.polygons:
        if any(_inside_convex(v, rect) for v in poly) or any(_inside_convex(v, poly) for v in rect) or any(
                segments_intersect(rect[k], rect[(k + 1) % 4], poly[m], poly[(m + 1) % len(poly)])
                for k in range(4) for m in range(len(poly))):
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
                      rect_width_m: float = RECT_WIDTH_M) -> ReductionResult:
    """The paper's Algorithm 1 over ``candidates`` with ``simulate(grasp) -> result`` (a
    :class:`synth.trial.TrialResult` or anything with ``.success`` or ``.outcome``).

    While candidates remain: take the narrowest ``g`` (ties: the earliest listed) and simulate
    it; on success draw ``Δw ~ U(dw_range_m)``, simulate ``(x, y, φ, w + Δw)`` (skipped when that
    exceeds 1.55 m) and keep the wider grasp if it also succeeds; accept it and drop every
    remaining candidate whose 20 cm grasp rectangle overlaps the accepted one by more than
    ``overlap_m2``; drop ``g``. ``max_trials`` (simulations, widening included) stops early.
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
        best, best_r = g, r
        dw = float(rng.uniform(*dw_range_m))
        if g.width_m + dw <= MAX_WIDTH_M and budget_left():
            wide = Grasp(g.x_m, g.y_m, g.phi_rad, g.width_m + dw)
            r2 = simulate(wide)
            res.trials.append((wide, r2))
            if _succeeded(r2):
                best, best_r = wide, r2
                res.widened += 1
        res.accepted.append((best, best_r))
        G = [h for h in G if rectangle_overlap_area(best, h, rect_width_m) <= overlap_m2]
    return res
