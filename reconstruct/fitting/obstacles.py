"""Stumps and rocks from the scan points standing above the fitted ground (:func:`find_obstacles`).

One obstacle per physical body, from the points no fitted log explains, reported only with enough support:

1. **Evidence**: points within ``obstacle_log_tolerance_m`` of a fitted log's surface (radially: up to its
   radius plus that from its axis), over its length and ``obstacle_log_end_reach_m`` past each placed end,
   are the log's (its smeared flanks, its top where it was fitted a little thin, the rest of it past an end
   placed short), not an obstacle's (:func:`explained_by_logs`).
2. **Clusters**: points more than ``obstacle_min_height_m`` above the ground are clustered with open3d's
   DBSCAN; each cluster then takes in the lower points (``obstacle_flank_height_m`` and up) connected to
   it, so a half-buried rock is sized by its footprint and not only by the cap above the threshold.
3. **One body, one obstacle**: clusters with a log's footprint between them (a log lying across a rock
   hides a band of it, :func:`_merge_across_logs`), and clusters whose top-view footprints touch or overlap
   within ``obstacle_join_gap_m`` (a stump's rim below its top: apart in height, across the side wall the
   cameras do not see, not apart over the ground; :func:`_join_touching`) are one obstacle, unless the body
   would then hold a log's axis or be wider than ``obstacle_max_size_m``.
4. **Support**: a cluster needs ``obstacle_min_points`` voxels, ``obstacle_min_size_m`` of horizontal extent
   and its top ``obstacle_min_top_m`` above the ground around it (:func:`_supported`).

Cluster points over a log's footprint higher than its underside are the log's (stereo smear at a stack of
log ends) and are dropped, and a stump is no taller than the lowest log underside over it. A cluster with a
flat, circular top at least its radius high, covering the cluster, is a stump (:class:`StumpSpec`, no roots:
they are not visible), any other a rock (:class:`RockSpec`, the convex hull of its points extended down
into the ground)."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from reconstruct.errors import FitError
from reconstruct.fitting.fit_config import FitConfig
from reconstruct.fitting.geometry import UNDER_LOG_GAP_M, _distance_to_logs, _footprint_distance, _underside_z
from synth.scene.pile import LogSpec, RockSpec, StumpSpec, TerrainSpec

# an obstacle's top: this percentile of its points' heights over the ground [%]; its top band (for a
# stump's flat top) this deep [m]
TOP_PERCENTILE = 95
TOP_BAND_M = 0.04
# a stump's top radius [m] and height [m] lie within these; its foot is this much wider than its top [-]
STUMP_RADIUS_RANGE_M = (0.03, 1.0)
STUMP_HEIGHT_RANGE_M = (0.05, 2.0)
STUMP_FOOT_SPREAD = 1.1
# a cluster is a strip of log surface when its top-view variance along its main direction is this many
# times that across [-], that direction within this of the log's [deg]
SLIVER_MIN_ELONGATION = 4
SLIVER_MAX_ANGLE_DEG = 20
# log axes are sampled this often to find one inside a merged obstacle [m]
AXIS_SAMPLE_STEP_M = 0.05
# a log lies between two clusters when one of these many points over the middle of the gap between their
# nearest points (this stretch of it, [-]) lies inside its footprint
GAP_SAMPLES = 5
GAP_MIDDLE = (0.25, 0.75)
# a rock's hull reaches this far into the ground [m]
ROCK_BURY_M = 0.05
# a stump's top radius is this percentile of its top points' distances from the circle's centre (the top
# is a disc, not a ring) [%], its outline the points beyond this share of that radius [-]
DISC_RADIUS_PERCENTILE = 95
OUTLINE_MIN_SHARE = 0.6


def find_obstacles(points: np.ndarray, terrain: TerrainSpec, cfg: FitConfig | None = None,
                   logs: Sequence[LogSpec] = (), flank_points: np.ndarray | None = None,
                   ) -> tuple[list[StumpSpec], list[RockSpec], list[dict]]:
    """Stumps and rocks from points above the terrain (see the module docstring for the steps).

    ``logs``: the fitted logs; points they explain are no obstacle's (:func:`explained_by_logs`), and two
    clusters with one of them between (a log lying across a rock or against a stump hides a band of it)
    are one obstacle (:func:`_merge_across_logs`).
    ``flank_points``: lower points (``obstacle_flank_height_m`` above the ground or more) that a
    cluster takes in where they connect to it: the flanks of a half-buried rock, so that its size
    is its footprint and not only the cap above ``obstacle_min_height_m``."""
    import open3d as o3d

    cfg = cfg or FitConfig()
    P = np.asarray(points, dtype=np.float64)
    if logs and len(P):
        P = P[~explained_by_logs(P, logs, cfg)]
    if logs and flank_points is not None and len(flank_points):
        flank_points = np.asarray(flank_points, dtype=np.float64)
        flank_points = flank_points[~explained_by_logs(flank_points, logs, cfg)]
    if len(P) == 0:
        return [], [], []
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc = pc.voxel_down_sample(cfg.obstacle_voxel_m)
    Q = np.asarray(pc.points)
    labels = np.asarray(pc.cluster_dbscan(eps=cfg.dbscan_eps_m, min_points=cfg.dbscan_min_points))
    clusters = [Q[labels == lab] for lab in range(int(labels.max()) + 1 if labels.size else 0)]
    clusters = _merge_across_logs(clusters, logs, cfg)
    if flank_points is not None and len(flank_points) and clusters:
        clusters = _grow_into_flanks(clusters, np.asarray(flank_points, dtype=np.float64), cfg)
    clusters = _join_touching(clusters, logs, cfg)
    if logs:
        clusters = [_clip_log_smear(C, terrain, logs, cfg) for C in clusters]
        # nothing on the ground stands above a log's underside inside its footprint: points
        # there are the log's (stereo smear at stacked log ends, end faces) and go
        clusters = [C[C[:, 2] < _underside_z(logs, C[:, :2])] for C in clusters]
    stumps: list[StumpSpec] = []
    rocks: list[RockSpec] = []
    info: list[dict] = []
    half = terrain.extent_m / 2
    for C in clusters:
        if not _supported(C, terrain, cfg) or _log_sliver(C, logs, cfg):
            continue
        ext = C[:, :2].max(0) - C[:, :2].min(0)
        ground = terrain.height_at(C[:, 0], C[:, 1])
        h = C[:, 2] - ground
        top = float(np.percentile(h, TOP_PERCENTILE))
        top_pts = C[h > top - TOP_BAND_M]
        flat_frac = len(top_pts) / len(C)
        cx, cy, r, rms = _circle_fit_xy(top_pts[:, :2])
        # a stump stands up: flat round top as wide as the cluster, height at least its radius;
        # rocks are domes or slabs
        (r_lo, r_hi), (h_lo, h_hi) = STUMP_RADIUS_RANGE_M, STUMP_HEIGHT_RANGE_M
        is_stump = (flat_frac >= cfg.stump_flat_fraction and np.isfinite(r) and r_lo <= r <= r_hi
                    and rms <= cfg.stump_max_circle_rms * r and h_lo <= top <= h_hi
                    and top >= cfg.stump_min_aspect * r and abs(cx) < half and abs(cy) < half
                    and r >= cfg.stump_min_cover * 0.5 * float(ext.max()))
        if is_stump and logs:
            # a stump is solid over its whole disc: no higher than the lowest log underside over
            # it (its foot as the twin sets it: the lowest ground under its rim and centre)
            rb = min(r_hi, r * STUMP_FOOT_SPREAD)
            foot = float(np.min(terrain.height_at(np.array([cx - rb, cx, cx + rb, cx, cx]),
                                                  np.array([cy, cy - rb, cy, cy + rb, cy]))))
            room = float(_underside_z(logs, np.array([[cx, cy]]), rb)[0]) - UNDER_LOG_GAP_M - foot
            if room < cfg.obstacle_min_height_m:
                continue  # under a log all over: the log's own points
            top = min(top, room)
        if is_stump:
            stumps.append(StumpSpec(position_m=(float(cx), float(cy)), height_m=float(np.clip(top, h_lo, h_hi)),
                                    bottom_radius_m=float(min(r_hi, r * STUMP_FOOT_SPREAD)), top_radius_m=float(r)))
            info.append({"kind": "stump", "position_m": [float(cx), float(cy)], "height_m": top,
                         "radius_m": float(r), "n_points": int(len(C)), "flat_fraction": flat_frac})
        else:
            rock = _rock_from_points(C, terrain, cfg)
            rocks.append(rock)
            info.append({"kind": "rock", "position_m": list(rock.position_m), "size_m": rock.size_m(),
                         "n_points": int(len(C)), "flat_fraction": flat_frac})
    return stumps, rocks, info


def explained_by_logs(P: np.ndarray, logs: Sequence[LogSpec], cfg: FitConfig) -> np.ndarray:
    """Mask of the points ``P`` ((N, 3), pile frame) that a fitted log explains: within its radius (at
    that place along a taper) plus ``obstacle_log_tolerance_m`` of its axis, anywhere from
    ``obstacle_log_end_reach_m`` before its one placed end to as far past the other."""
    P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
    return _distance_to_logs(P, logs, pad_m=cfg.obstacle_log_end_reach_m) <= cfg.obstacle_log_tolerance_m


def _supported(C: np.ndarray, terrain: TerrainSpec, cfg: FitConfig) -> bool:
    """Whether cluster ``C`` (voxels) has the support of an obstacle: ``obstacle_min_points`` voxels (30
    voxels of 2 cm: 0.012 m^2 seen, a 6 cm disc), ``obstacle_min_size_m`` of horizontal extent, and its top
    (the ``TOP_PERCENTILE`` of its heights above the fitted ground) at least ``obstacle_min_top_m``."""
    if len(C) < cfg.obstacle_min_points:
        return False
    if float((C[:, :2].max(0) - C[:, :2].min(0)).max()) < cfg.obstacle_min_size_m:
        return False
    h = C[:, 2] - terrain.height_at(C[:, 0], C[:, 1])
    return float(np.percentile(h, TOP_PERCENTILE)) >= cfg.obstacle_min_top_m


def _join_touching(clusters: list[np.ndarray], logs: Sequence[LogSpec], cfg: FitConfig) -> list[np.ndarray]:
    """Join clusters whose top-view footprints touch or overlap (nearest points at most
    ``obstacle_join_gap_m`` apart across the ground): parts of one body that only height separates (a
    stump's rim seen below its top across the side wall the cameras do not see; a rock's cap above its
    shoulder). Two parts stay apart when their body would hold a log's axis (:func:`_hull_holds_a_log`: a
    log lies between them) or be wider than ``obstacle_max_size_m`` (no obstacle is)."""
    if len(clusters) < 2:
        return clusters
    from scipy.spatial import cKDTree

    groups = [[C] for C in clusters]
    axis_samples = _axis_samples(logs)
    joined = True
    while joined:  # until no two groups touch: each join is checked on the whole body it makes
        joined = False
        for i in range(len(groups)):
            for j in range(i + 1, len(groups)):
                A, B = np.vstack(groups[i]), np.vstack(groups[j])
                d, _ = cKDTree(A[:, :2]).query(B[:, :2], distance_upper_bound=cfg.obstacle_join_gap_m)
                if not np.isfinite(d).any():
                    continue
                union = np.vstack([A, B])
                if float((union[:, :2].max(0) - union[:, :2].min(0)).max()) > cfg.obstacle_max_size_m:
                    continue
                if len(axis_samples) and _hull_holds_a_log(union, axis_samples):
                    continue
                groups[i] = groups[i] + groups.pop(j)
                joined = True
                break
            if joined:
                break
    return [np.vstack(g) for g in groups]


def _axis_samples(logs: Sequence[LogSpec]) -> np.ndarray:
    """Points along every log's axis, ``AXIS_SAMPLE_STEP_M`` apart ((0, 3) without logs)."""
    if not logs:
        return np.zeros((0, 3))
    return np.vstack([a + np.outer(np.linspace(0, 1, max(2, int(log.length_m / AXIS_SAMPLE_STEP_M))), b - a)
                      for log in logs for a, b in [log.endpoints_m()]])


def _grow_into_flanks(clusters: list[np.ndarray], flank: np.ndarray, cfg: FitConfig) -> list[np.ndarray]:
    """Each cluster plus the flank points reachable from it in steps of ``dbscan_eps_m`` (region
    growing on the voxel-downsampled flank points; a flank point joins the first cluster that
    reaches it)."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(flank)).voxel_down_sample(cfg.obstacle_voxel_m)
    F = np.asarray(pc.points)
    if not len(F):
        return clusters
    tree = cKDTree(F)
    taken = np.zeros(len(F), dtype=bool)
    out = []
    for C in clusters:
        front = C
        grown = [C]
        while len(front):
            hits = {j for row in tree.query_ball_point(front, cfg.dbscan_eps_m) for j in row}
            new = np.array(sorted(j for j in hits if not taken[j]), dtype=np.int64)
            if not len(new):
                break
            taken[new] = True
            front = F[new]
            grown.append(front)
        out.append(np.vstack(grown))
    return out


def _clip_log_smear(C: np.ndarray, terrain: TerrainSpec, logs: Sequence[LogSpec], cfg: FitConfig) -> np.ndarray:
    """A cluster whose points near a log (within ``obstacle_flank_log_gap_m`` of its top-view
    footprint) stand higher above the ground than any of its points away from logs: those
    heights are capped at the highest far point. Stereo smears a log's edge outwards at
    heights between the log's top and the ground; on an obstacle beside the log the smear
    would become a tall ridge of the obstacle, into which the log then seems to sink. A cluster
    with fewer than ``dbscan_min_points`` points away from logs is left as it is."""
    near = _footprint_distance(C[:, :2], logs) < cfg.obstacle_flank_log_gap_m
    if not near.any() or int((~near).sum()) < cfg.dbscan_min_points:
        return C
    ground = terrain.height_at(C[:, 0], C[:, 1])
    h = C[:, 2] - ground
    cap = float(h[~near].max())
    out = C.copy()
    high = near & (h > cap)
    out[high, 2] = ground[high] + cap
    return out


def _log_sliver(C: np.ndarray, logs: Sequence[LogSpec], cfg: FitConfig) -> bool:
    """True for a cluster that is a strip of log surface the fitted log does not explain (a
    log fitted a little too thin or too low): every point within ``obstacle_sliver_m`` of one
    log's top-view footprint, the strip elongated along that log's axis."""
    for log in logs:
        if float(np.max(_footprint_distance(C[:, :2], [log]))) > cfg.obstacle_sliver_m:
            continue
        xy = C[:, :2] - C[:, :2].mean(0)
        w, v = np.linalg.eigh(xy.T @ xy / len(xy))
        axis = log.axis()[:2]
        axis = axis / max(float(np.linalg.norm(axis)), 1e-9)
        along = abs(float(v[:, 1] @ axis)) > math.cos(math.radians(SLIVER_MAX_ANGLE_DEG))
        if w[1] > SLIVER_MIN_ELONGATION * w[0] and along:
            return True
    return False


def _merge_across_logs(clusters: list[np.ndarray], logs: Sequence[LogSpec], cfg: FitConfig) -> list[np.ndarray]:
    """Join clusters whose nearest points are at most ``obstacle_merge_gap_m`` apart with a log's
    top-view footprint between them (the middle of the gap inside it): the two visible parts of
    one obstacle that a log lies across or against."""
    if len(clusters) < 2 or not logs:
        return clusters
    from scipy.spatial import cKDTree

    parent = list(range(len(clusters)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    trees = [cKDTree(C[:, :2]) for C in clusters]
    axis_samples = _axis_samples(logs)
    for i in range(len(clusters)):
        for j in range(i + 1, len(clusters)):
            d, k = trees[i].query(clusters[j][:, :2], distance_upper_bound=cfg.obstacle_merge_gap_m)
            if not np.isfinite(d).any():
                continue
            m = int(np.argmin(d))
            a, b = clusters[i][k[m], :2], clusters[j][m, :2]
            between = a + np.outer(np.linspace(*GAP_MIDDLE, GAP_SAMPLES), b - a)
            if not (_footprint_distance(between, logs) < cfg.footprint_margin_m).any():
                continue
            ri, rj = root(i), root(j)
            if ri == rj:
                continue
            union = np.vstack([C for g, C in enumerate(clusters) if root(g) in (ri, rj)])
            if not _hull_holds_a_log(union, axis_samples):
                parent[rj] = ri
    groups: dict[int, list[np.ndarray]] = {}
    for i, C in enumerate(clusters):
        groups.setdefault(root(i), []).append(C)
    return [np.vstack(g) for g in groups.values()]


def _hull_holds_a_log(C: np.ndarray, axis_samples: np.ndarray) -> bool:
    """True when the obstacle that the points ``C`` would make (their convex hull down to the
    ground) contains a point of a log's axis: two clusters on either side of a log that make
    such a hull are two obstacles, not one that the log lies across (a log rests on top)."""
    from scipy.spatial import ConvexHull, Delaunay

    below = C.copy()
    below[:, 2] = C[:, 2].min() - ROCK_BURY_M
    try:
        pts = np.vstack([C, below])
        tri = Delaunay(pts[ConvexHull(pts).vertices])  # the hull's vertices span the same region, fast
    except Exception:  # flat or degenerate: no volume, holds nothing
        return False
    return bool((tri.find_simplex(axis_samples) >= 0).any())


def _circle_fit_xy(xy: np.ndarray) -> tuple[float, float, float, float]:
    """Algebraic (Kasa) circle fit: centre x, y, radius, RMS of radial residuals."""
    if len(xy) < 3:
        return math.nan, math.nan, math.nan, math.nan
    A = np.column_stack([2 * xy[:, 0], 2 * xy[:, 1], np.ones(len(xy))])
    bvec = (xy ** 2).sum(1)
    sol, *_ = np.linalg.lstsq(A, bvec, rcond=None)
    cx, cy = sol[0], sol[1]
    r2 = sol[2] + cx * cx + cy * cy
    if r2 <= 0:
        return math.nan, math.nan, math.nan, math.nan
    # the top is a filled disk, not a ring: a high percentile of the distances is the radius
    d = np.hypot(xy[:, 0] - cx, xy[:, 1] - cy)
    r_disk = float(np.percentile(d, DISC_RADIUS_PERCENTILE))
    # roundness: how far the outline deviates from a circle (outer points only)
    outer = d > OUTLINE_MIN_SHARE * r_disk
    rms = float(np.sqrt(np.mean((d[outer] - r_disk) ** 2))) if outer.any() else math.nan
    return float(cx), float(cy), r_disk, rms


def _rock_from_points(C: np.ndarray, terrain: TerrainSpec, cfg: FitConfig) -> RockSpec:
    """A convex rock: hull of the cluster plus its outline pushed ``ROCK_BURY_M`` into the ground."""
    from scipy.spatial import ConvexHull

    ground = terrain.height_at(C[:, 0], C[:, 1])
    below = C.copy()
    below[:, 2] = ground - ROCK_BURY_M
    allp = np.vstack([C, below])
    try:
        hull = ConvexHull(allp)
        V = allp[hull.vertices]
    except Exception as exc:  # scipy raises QhullError for flat sets
        raise FitError(f"cannot build a rock from a flat cluster of {len(C)} points: {exc}") from exc
    if len(V) > cfg.rock_max_vertices:  # farthest-point subsampling of the hull vertices
        keep = [int(np.argmax(V[:, 2]))]
        dmin = np.linalg.norm(V - V[keep[0]], axis=1)
        while len(keep) < cfg.rock_max_vertices:
            k = int(np.argmax(dmin))
            keep.append(k)
            dmin = np.minimum(dmin, np.linalg.norm(V - V[k], axis=1))
        V = V[keep]
    centre = V.mean(0)
    return RockSpec(position_m=tuple(float(v) for v in centre), orientation=(0.0, 0.0, 0.0, 1.0),
                    vertices_m=tuple(tuple(float(c) for c in v - centre) for v in V))
