"""Coarse georegistration: a scan with no pose placed in the site frame from the GNSS end points
alone (:func:`coarse_scan_pose`): the ground plane gives the vertical (:func:`ransac_plane`), a yaw/shift
search puts the surveyed axes on the scan's raised points, the lowest log sets the height.
:mod:`reconstruct.registration` then refines it like any other scan pose."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reconstruct.errors import RegistrationError
from synth.geometry.frames import apply_T, make_T

# three-point samples scored per batch by ransac_plane (a batch x points matrix of distances) [-]
RANSAC_BATCH = 64


@dataclass(frozen=True)
class CoarseConfig:
    """Coarse placement of a scan in the site frame from the GNSS end points alone (no scan pose):
    ground plane -> vertical; yaw and horizontal shift by matching the surveyed log axes to the
    scan's raised points; height from the ground under the logs (units in the names/comments)."""

    voxel_m: float = 0.03  # cloud thinned to this first [m]
    ground_distance_m: float = 0.04  # RANSAC ground-plane inlier distance [m]
    ground_iterations: int = 2000  # RANSAC iterations [-]
    min_ground_fraction: float = 0.15  # the dominant plane must hold this share of the points [-]
    log_min_height_m: float = 0.05  # points this far above the ground plane may be logs [m]
    log_max_height_m: float = 2.0  # ... and at most this far [m]
    cell_m: float = 0.02  # raster cell of the yaw/shift search [m]
    band_m: float = 0.05  # support of an axis sample: its depth inside the raised region, full at this [m]
    end_trim_m: float = 0.15  # axis samples this close to a surveyed end are not used [m]
    yaw_step_deg: float = 2.0  # coarse yaw grid [deg]
    fine_step_deg: float = 0.25  # refined yaw grid around the best coarse yaw [deg]
    min_support: float = 0.4  # mean support of the axis samples needed [-]
    ambiguity_ratio: float = 0.9  # a distinct second yaw scoring this share of the best: error [-]
    peak_separation_deg: float = 15.0  # yaws closer than this belong to one peak [deg]
    height_ambiguity_ratio: float = 1.5  # ambiguous yaws: the chosen one's height spread must be
    #                                      this many times smaller than every other's [-]
    refine_dof: str = "6dof"  # refinement after the coarse pose: the vertical came from the ground plane
    max_correction_m: float = 0.30  # refinement limits after the coarse pose [m]
    max_correction_deg: float = 5.0  # [deg]
    pose_sigma_m: float = 0.15  # the coarse pose is right to this (1 sigma, the refinement's prior) [m]
    pose_sigma_deg: float = 3.0  # [deg]
    seed: int = 0  # RANSAC seed [-]

    def __post_init__(self) -> None:
        for name in ("voxel_m", "ground_distance_m", "log_min_height_m", "cell_m", "band_m", "yaw_step_deg",
                     "fine_step_deg", "peak_separation_deg", "max_correction_m", "max_correction_deg", "pose_sigma_m",
                     "pose_sigma_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.log_max_height_m > self.log_min_height_m:
            raise ValueError("log_max_height_m must be > log_min_height_m")
        if self.end_trim_m < 0 or self.ground_iterations < 10:
            raise ValueError("end_trim_m must be >= 0 and ground_iterations >= 10")
        if not self.height_ambiguity_ratio >= 1:
            raise ValueError(f"height_ambiguity_ratio must be >= 1, got {self.height_ambiguity_ratio}")
        for name in ("min_ground_fraction", "min_support", "ambiguity_ratio"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if self.refine_dof not in ("4dof", "6dof"):
            raise ValueError(f"refine_dof must be '4dof' or '6dof', got {self.refine_dof!r}")


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


def _axis_samples(ends: dict[str, tuple[np.ndarray, np.ndarray]], step_m: float,
                  trim_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along every surveyed axis (site frame, (N, 3)) and their log index."""
    pts, owner = [], []
    for k, (a, b) in enumerate(ends.values()):
        L = float(np.linalg.norm(b[:2] - a[:2]))
        if L <= 2 * trim_m:
            continue
        t = np.arange(trim_m, L - trim_m + 1e-9, step_m) / L
        pts.append(a + np.outer(t, b - a))
        owner.append(np.full(len(t), k))
    if not pts:
        raise RegistrationError("the surveyed logs are too short to place the scan from them")
    return np.concatenate(pts), np.concatenate(owner)


def coarse_scan_pose(points: np.ndarray, camera_positions: np.ndarray,
                     ends_site: dict[str, tuple[np.ndarray, np.ndarray]],
                     cfg: CoarseConfig | None = None) -> tuple[np.ndarray, dict]:
    """``T_site_scan`` (4x4) of a scan whose pose is unknown, from the GNSS end points alone.

    ``points``: the fused cloud (scan frame); ``camera_positions``: the pairs' left cameras
    (scan frame; they tell which side of the ground is up); ``ends_site``: ``{log_id: (a, b)}``
    log end centres in the site frame. Steps: the ground is the dominant plane (open3d
    ``segment_plane``) -> the vertical; points raised above it are rasterised; for every yaw on
    a grid the surveyed axes are rasterised and slid over that raster
    (``cv2.matchTemplate``): the yaw and horizontal shift putting the most axis samples on
    raised points wins (then a finer yaw grid); the height puts the lowest log on the ground
    (a log's axis lies half its seen top height above the ground under it). Returns the pose and
    a report (ground, scores, peaks). Raises :class:`CoarseRegistrationError` when there is no
    ground plane, the best yaw supports too few axis samples, or a distinct second yaw scores
    nearly as well (a symmetric pile: survey another log, or give a scan pose)."""
    from reconstruct.errors import CoarseRegistrationError

    cfg = cfg or CoarseConfig()
    ground = _ground_plane(points, camera_positions, cfg)
    search = _YawSearch(ground, ends_site, cfg)
    yaws = np.radians(np.arange(-180.0, 180.0, cfg.yaw_step_deg))
    sc = np.array([search.score(float(y))[0] for y in yaws])
    i_best = int(np.argmax(sc))
    sep = np.radians(cfg.peak_separation_deg)
    dist = np.abs((yaws - yaws[i_best] + np.pi) % (2 * np.pi) - np.pi)
    peak = (sc >= np.roll(sc, 1)) & (sc >= np.roll(sc, -1))  # local maxima (circular)
    other = peak & (dist > sep)
    second = float(sc[other].max()) if other.any() else 0.0
    y_second = float(yaws[other][int(np.argmax(sc[other]))]) if other.any() else math.nan
    best_yaw, best, u = search.refine_yaw(float(yaws[i_best]))
    report = {
        "ground_plane_scan": [float(v) for v in (*ground.normal, ground.offset)], "ground_fraction": ground.fraction,
        "raised_points": int(len(ground.raised)), "axis_samples": int(len(search.samples)),
        "yaw_deg": math.degrees(best_yaw), "support": best,
        "second_peak_yaw_deg": math.degrees(y_second) if np.isfinite(y_second) else None,
        "second_peak_support": second,
        "yaw_scores": {"step_deg": cfg.yaw_step_deg, "support": [round(float(v), 4) for v in sc]},
    }
    if best < cfg.min_support:
        raise CoarseRegistrationError(
            f"no yaw puts the surveyed logs on the scan: at best {best * 100:.0f} % of the axis samples lie on "
            f"raised scan points (need {cfg.min_support * 100:.0f} %). The survey belongs to another pile, the "
            "scan misses part of it, or the ground was not found; give a scan pose (scan_pose.json)")
    if second >= cfg.ambiguity_ratio * best:
        # the top view alone cannot tell: every yaw peak scoring nearly as well is placed and judged by
        # the heights (the survey's 3-D ends against the scan's tops); one must be clearly more consistent
        cand_yaws = [float(yaws[i_best])]
        for i in np.argsort(-sc):
            far = all(abs((yaws[i] - y + np.pi) % (2 * np.pi) - np.pi) > sep for y in cand_yaws)
            if peak[i] and far and sc[i] >= cfg.ambiguity_ratio * sc[i_best]:
                cand_yaws.append(float(yaws[i]))
        best_yaw, best, u = search.resolve_by_heights(cand_yaws, report, (best_yaw, best), (y_second, second))
    T_site_level = search.site_from_level(best_yaw, u, report)
    return T_site_level @ ground.T_level_scan, report


@dataclass(frozen=True)
class _Ground:
    """The scan's ground plane (``normal`` . p + ``offset`` = 0 in the scan frame, the cameras on
    its positive side, holding ``fraction`` of the thinned points), ``T_level_scan`` (level frame:
    z = height above that plane) and the points raised above it, in the level frame."""

    normal: np.ndarray
    offset: float
    fraction: float
    T_level_scan: np.ndarray
    raised: np.ndarray


def ransac_plane(points: np.ndarray, distance_m: float, iterations: int,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The plane (n, d: n . p + d = 0, |n| = 1) holding the most ``points`` within ``distance_m``:
    RANSAC over ``iterations`` three-point samples drawn from ``rng``, refitted to its inliers by
    least squares; returns it and its inliers' indices.

    Deterministic for a seeded ``rng`` (open3d's ``segment_plane`` is not, whatever its seed: on one
    unposed twin scan it gave 14,075 / 14,108 / 14,152 inliers in repeated calls, and the coarse yaw
    and every fitted log with it changed from run to run)."""
    P = np.asarray(points, dtype=np.float64)
    best_count, best = -1, (np.array([0.0, 0.0, 1.0]), 0.0)
    for start in range(0, iterations, RANSAC_BATCH):
        idx = rng.integers(0, len(P), size=(min(RANSAC_BATCH, iterations - start), 3))
        a = P[idx[:, 0]]
        n = np.cross(P[idx[:, 1]] - a, P[idx[:, 2]] - a)
        norm = np.linalg.norm(n, axis=1)
        ok = norm > 1e-12  # three distinct, non-collinear points
        n = n / np.where(ok, norm, 1.0)[:, None]
        d = -np.einsum("ij,ij->i", n, a)
        counts = np.where(ok, (np.abs(P @ n.T + d) < distance_m).sum(axis=0), -1)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best_count, best = int(counts[j]), (n[j], float(d[j]))
    inl = np.flatnonzero(np.abs(P @ best[0] + best[1]) < distance_m)
    if len(inl) >= 3:  # least squares on the inliers, then the inliers of that plane
        c = P[inl].mean(axis=0)
        n = np.linalg.svd(P[inl] - c, full_matrices=False)[2][-1]
        best = (n, float(-n @ c))
        inl = np.flatnonzero(np.abs(P @ best[0] + best[1]) < distance_m)
    return np.r_[best[0], best[1]], inl


def _ground_plane(points: np.ndarray, camera_positions: np.ndarray, cfg: CoarseConfig) -> _Ground:
    import open3d as o3d

    from reconstruct.errors import CoarseRegistrationError

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    P = np.asarray(pc.voxel_down_sample(cfg.voxel_m).points)
    if len(P) < 100:
        raise CoarseRegistrationError(f"only {len(P)} scan points: too few to find the ground")
    plane, inl = ransac_plane(P, cfg.ground_distance_m, cfg.ground_iterations, np.random.default_rng(cfg.seed))
    frac = len(inl) / len(P)
    if frac < cfg.min_ground_fraction:
        raise CoarseRegistrationError(
            f"no dominant ground plane in the scan (the best plane holds {frac * 100:.0f} % of the points, need "
            f"{cfg.min_ground_fraction * 100:.0f} %): the scan must show the ground around the pile, or give a "
            "scan pose (scan_pose.json)")
    n, d = np.asarray(plane[:3], dtype=np.float64), float(plane[3])
    norm = float(np.linalg.norm(n))
    n, d = n / norm, d / norm
    cams = np.atleast_2d(np.asarray(camera_positions, dtype=np.float64))
    if len(cams) and np.median(cams @ n + d) < 0:  # the cameras are above the ground
        n, d = -n, -d
    # R_level: the shortest rotation taking n to +z
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(n, z), float(n @ z)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    R_level = np.eye(3) + vx + vx @ vx / (1 + c) if c > -0.999999 else np.diag([1.0, -1.0, -1.0])
    T_level_scan = make_T(R_level, (0.0, 0.0, d))  # level z = height above the ground plane
    Q = apply_T(T_level_scan, P)
    raised = Q[(Q[:, 2] > cfg.log_min_height_m) & (Q[:, 2] < cfg.log_max_height_m)]
    if len(raised) < 50:
        raise CoarseRegistrationError("the scan shows (almost) nothing above the ground plane: no logs to match")
    return _Ground(n, d, float(frac), T_level_scan, raised)


class _YawSearch:
    """The surveyed axes slid over the raster of raised scan points (level frame), by yaw."""

    def __init__(self, ground: _Ground, ends_site: dict, cfg: CoarseConfig) -> None:
        import cv2
        from scipy.spatial import cKDTree

        self.cfg, self.raised = cfg, ground.raised
        # raster of raised points (level frame), dilated by the band
        self.lo = self.raised[:, :2].min(0) - 0.5
        hi = self.raised[:, :2].max(0) + 0.5
        shape = tuple(int(v) for v in np.ceil((hi - self.lo) / cfg.cell_m)[::-1] + 1)  # rows (y), cols (x)
        occ = np.zeros(shape, np.uint8)
        ij = np.floor((self.raised[:, :2] - self.lo) / cfg.cell_m).astype(np.int64)
        occ[ij[:, 1], ij[:, 0]] = 1
        occ = cv2.morphologyEx(occ, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        # how deep inside the raised region a cell lies: largest on a log's centre line (its axis seen from
        # above), so a surveyed axis scores most when it runs along the middle of a log, not just across one
        inside = cv2.distanceTransform(occ, cv2.DIST_L2, 5) * cfg.cell_m
        self.occ = (np.clip(inside, 0.0, cfg.band_m) / cfg.band_m).astype(np.float32)
        self.samples, self.owner = _axis_samples(ends_site, cfg.cell_m, cfg.end_trim_m)
        self.centre = self.samples[:, :2].mean(0)
        self.rel = self.samples[:, :2] - self.centre
        self.tree = cKDTree(self.raised[:, :2])

    def score(self, yaw: float) -> tuple[float, np.ndarray]:
        """The axis samples' mean support at ``yaw`` and the best shift (level position of their centre)."""
        import cv2

        cell = self.cfg.cell_m
        a = self.rel @ _rot_z(-yaw).T  # axis samples in the level frame, up to a shift
        amin = a.min(0)
        idx = np.floor((a - amin) / cell).astype(np.int64)
        th, tw = int(idx[:, 1].max()) + 1, int(idx[:, 0].max()) + 1
        if th >= self.occ.shape[0] or tw >= self.occ.shape[1]:
            return 0.0, np.zeros(2)
        tmpl = np.zeros((th, tw), np.float32)
        np.add.at(tmpl, (idx[:, 1], idx[:, 0]), 1.0)
        res = cv2.matchTemplate(self.occ, tmpl, cv2.TM_CCORR)
        _, best, _, loc = cv2.minMaxLoc(res)
        # level position of the samples' centre: template origin + (centre - amin)
        u = self.lo + np.array(loc, dtype=np.float64) * cell - amin
        return float(best) / len(a), u

    def refine_yaw(self, y0: float) -> tuple[float, float, np.ndarray]:
        """The best yaw on the fine grid around ``y0``, its support and shift."""
        cfg = self.cfg
        fine = np.radians(np.arange(-cfg.yaw_step_deg, cfg.yaw_step_deg + 1e-9, cfg.fine_step_deg)) + y0
        y, (b, u) = max(((float(y), self.score(float(y))) for y in fine), key=lambda t: t[1][0])
        return y, b, u

    def _level(self, yaw: float, u: np.ndarray) -> np.ndarray:
        R2 = _rot_z(yaw)
        return (self.samples[:, :2] - (self.centre - R2 @ u)) @ R2  # = R2.T @ (site - t)

    def height_spread(self, yaw: float, u: np.ndarray) -> float:
        """Median absolute deviation [m] of (surveyed axis height - scan top height under it) over
        the axis samples: nearly constant (a radius and the ground offset) at the right yaw; at a
        wrong one the survey's high logs land on low scan points and the other way round."""
        nb = self.tree.query_ball_point(self._level(yaw, u), 0.03)
        d = np.array([self.samples[k, 2] - float(np.max(self.raised[j, 2])) for k, j in enumerate(nb) if len(j)])
        if len(d) < 0.3 * len(self.samples):
            return math.inf
        return float(np.median(np.abs(d - np.median(d))))

    def resolve_by_heights(self, cand_yaws: list[float], report: dict, best: tuple[float, float],
                           second: tuple[float, float]) -> tuple[float, float, np.ndarray]:
        """Of yaws the top view cannot tell apart, the one whose heights agree clearly best with the
        survey's (``height_ambiguity_ratio``); else :class:`CoarseRegistrationError`."""
        from reconstruct.errors import CoarseRegistrationError

        cands = []
        for y0 in cand_yaws:
            y, b, uu = self.refine_yaw(y0)
            cands.append((self.height_spread(y, uu), y, b, uu))
        cands.sort(key=lambda c: c[0])
        report["height_spread_m"] = {f"{math.degrees(c[1]):.1f}": c[0] for c in cands}
        (h1, y1, b1, u1), (h2, y2, b2, _) = cands[0], cands[1]
        if not (math.isfinite(h1) and h1 * self.cfg.height_ambiguity_ratio <= h2):
            raise CoarseRegistrationError(
                f"the scan fits the surveyed logs almost equally well at yaw {math.degrees(best[0]):.0f} deg "
                f"({best[1] * 100:.0f} % support) and {math.degrees(second[0]):.0f} deg ({second[1] * 100:.0f} %), and "
                f"the heights do not tell them apart either ({h1 * 100:.1f} vs {h2 * 100:.1f} cm spread): the "
                "pile looks (nearly) symmetric. Survey a log that breaks the symmetry, or give a scan pose "
                "(scan_pose.json)")
        report.update(yaw_deg=math.degrees(y1), support=b1, resolved_by="heights")
        return y1, b1, u1

    def site_from_level(self, yaw: float, u: np.ndarray, report: dict) -> np.ndarray:
        """``T_site_level`` at ``yaw`` and shift ``u``, its height from the ground under the logs: a
        log's axis lies half its seen top height above the ground under it, if it lies on the
        ground; logs on other logs give higher grounds, so the lowest log sets the height."""
        from reconstruct.errors import CoarseRegistrationError

        R2 = _rot_z(yaw)
        t_xy = self.centre - R2 @ u  # site_xy = R2 @ level_xy + t_xy
        lvl = (self.samples[:, :2] - t_xy) @ R2  # = R2.T @ (site - t)
        grounds = []
        for k in np.unique(self.owner):
            sel = self.owner == k
            nb = self.tree.query_ball_point(lvl[sel], 0.03)
            tops = [float(np.max(self.raised[j, 2])) for j in nb if len(j)]
            if len(tops) >= 5:
                h_top = float(np.median(tops))
                grounds.append(float(np.median(self.samples[sel, 2])) - h_top / 2)
        if not grounds:
            raise CoarseRegistrationError("no surveyed log has raised scan points along its axis")
        dz = float(min(grounds))
        T_site_level = np.eye(4)
        T_site_level[:2, :2] = R2
        T_site_level[:3, 3] = (t_xy[0], t_xy[1], dz)
        report["ground_height_site_m"] = dz
        return T_site_level
