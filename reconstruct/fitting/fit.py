"""Model fitting: a scan point cloud plus GNSS log end points become a :class:`PileSpec` (:func:`fit_pile`).

Everything here works in ONE frame, the *pile frame* of the pile being built (metres, z up, origin at the
centre of the terrain patch; see :mod:`synth.scene.pile`). :mod:`reconstruct.pipeline` moves the scan and
the endpoints into that frame first, and finds each log's axis in the scan and places its ends from the
scan and the survey by their accuracies (:mod:`reconstruct.fitting.fuse`).

The pile is fitted in steps, each in its own module:

* each log on its own around its survey axis (:mod:`reconstruct.fitting.cylinder`), then every scan point
  given to the log whose surface it lies on and each log fitted again among the others (here:
  :class:`_Placement`); a log seen only in part, or hidden under others, from its survey axis
  (:mod:`reconstruct.fitting.partial`);
* the ground from the points no log explains (:mod:`reconstruct.fitting.terrain`), the obstacles
  standing on it (:mod:`reconstruct.fitting.obstacles`);
* the assembled pile loaded into the twin, interpenetrating logs turned, thinned or moved apart
  (:mod:`reconstruct.fitting.separation`), a log the twin still refuses moved within the uncertainty of
  its ends (:mod:`reconstruct.fitting.clearance`).

Logs are indexed by the natural order of their ids (``log2`` before ``log10``), whatever the order of the
survey rows. The configuration and the report: :mod:`reconstruct.fitting.fit_config`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Collection, Mapping, Sequence

import numpy as np

from reconstruct.errors import FitError, LogNotSeenError, SeparationError
from reconstruct.fitting.clearance import clear_pile
from reconstruct.fitting.cylinder import CylinderFit, fit_log, log_spec_from_fit
from reconstruct.fitting.fit_config import AXIS_SOURCES, ENDPOINT_REFS, FIT_REVISION, FitConfig, LogFit, PileFit
from reconstruct.fitting.geometry import (
    _axis_shift, _distance_to_logs, _footprint_distance, _interpenetration, _owners, _segment_distance_3d,
    natural_key, points_on_no_other_log,
)
from reconstruct.fitting.obstacles import find_obstacles
from reconstruct.fitting.partial import _covered_by_others, _sandwiched_log, _survey_log, fit_radius_on_axis
from reconstruct.fitting.separation import separate_logs, thinned_keeping_top
from reconstruct.fitting.terrain import _clamp_under_logs, fit_terrain
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec

# steps the tests exercise one by one, importable from here as before the split into modules
from reconstruct.fitting.cylinder import _chunk_circles, _fit_cylinder, _initial_axis, _search_region  # noqa: F401
from reconstruct.fitting.geometry import _underside_z  # noqa: F401

__all__ = [
    "AXIS_SOURCES", "ENDPOINT_REFS", "FIT_REVISION", "CylinderFit", "FitConfig", "LogFit", "PileFit", "find_obstacles",
    "fit_log", "fit_pile", "fit_radius_on_axis", "fit_terrain", "log_spec_from_fit", "natural_key",
    "points_on_no_other_log", "sample_top_view_points", "separate_logs", "thinned_keeping_top",
]


# -- the whole pile --------------------------------------------------------------------------
@dataclass
class _PlacedLog:
    """One log of :func:`fit_pile` as placed: its fit, its LogSpec, whether end b is the butt, and how
    (``"scan"``, ``"partial"`` or ``"hidden"``)."""

    fit: CylinderFit
    spec: LogSpec
    swapped: bool
    how: str


@dataclass
class _FirstPass:
    """:func:`fit_pile`'s first pass: each log on its own."""

    specs: list[LogSpec | None]  # per log (None: hidden, until placed)
    fits: dict[int, CylinderFit]  # the logs fitted here (not given as ``first_pass``)
    hidden: dict[int, LogNotSeenError]  # logs with no scan points on them, under others


@dataclass
class _Ground:
    """Terrain and obstacles under the placed logs."""

    terrain: TerrainSpec
    is_ground: np.ndarray
    coverage: float
    stumps: list
    rocks: list
    info: list
    n_above: int


def _check_endpoints(endpoints: Mapping[str, tuple[Any, Any]], ids: Sequence[str], extent_m: float) -> None:
    half = extent_m / 2
    for log_id in ids:
        for end, p in zip("ab", endpoints[log_id]):
            p = np.asarray(p, dtype=float)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise ValueError(f"log {log_id!r} end {end!r}: need a finite 3-D point, got {p!r}")
            if abs(p[0]) > half or abs(p[1]) > half:
                raise FitError(f"log {log_id!r} end {end!r} at ({p[0]:.2f}, {p[1]:.2f}) m lies outside "
                               f"the {extent_m:g} m terrain patch; enlarge extent_m or check the point")


def _first_pass(P: np.ndarray, ids: Sequence[str], endpoints: Mapping[str, tuple[Any, Any]], cfg: FitConfig,
                rng: np.random.Generator, given: Mapping[str, LogSpec] | None,
                sigmas: Mapping[str, tuple[float, float]] | None, say: Callable[[str], None]) -> _FirstPass:
    """Each log on its own around its axis (or as ``given``); a log with no scan points on it is hidden
    when scan points stand over its axis, else the error stands."""
    out = _FirstPass([], {}, {})
    for i, log_id in enumerate(ids):
        if given is not None and log_id in given:
            out.specs.append(given[log_id])
            continue
        say(f"fitting log {log_id}")
        sa, sb = (sigmas or {}).get(log_id, (None, None))
        try:
            out.fits[i] = fit_log(P, *endpoints[log_id], cfg, log_id=log_id, rng=rng, sigma_a_m=sa, sigma_b_m=sb)
            out.specs.append(log_spec_from_fit(out.fits[i], cfg)[0])
        except LogNotSeenError as exc:
            if not _covered_by_others(P, *endpoints[log_id], cfg):
                raise  # nothing over it either: outside the scan, or wrong end points
            out.hidden[i] = exc
            out.specs.append(None)
    if out.hidden and len(out.hidden) == len(ids):
        raise next(iter(out.hidden.values()))
    return out


class _Placement:
    """:func:`fit_pile`'s second pass: every log placed among the ones placed before it. Trusted logs
    first, each refitted on the points it owns; logs seen only in part on their survey axes; hidden ones
    between the ground and the logs over them. ``placed``, ``dropped`` hold the result."""

    def __init__(self, P: np.ndarray, ids: Sequence[str], endpoints: Mapping[str, tuple[Any, Any]],
                 cfg: FitConfig, rng: np.random.Generator, sigmas: Mapping[str, tuple[float, float]] | None,
                 optional: Collection[str], say: Callable[[str], None], in_part: Collection[str] = ()):
        self.P, self.ids, self.endpoints, self.cfg, self.rng = P, ids, endpoints, cfg, rng
        self.sigmas, self.optional, self.say, self.in_part = sigmas or {}, optional, say, set(in_part)
        self.placed: dict[int, _PlacedLog] = {}
        self.dropped: dict[str, str] = {}  # optional logs left out, and why
        self.typical_d = math.nan

    def neighbours(self, i: int) -> list[LogSpec]:
        """The other logs placed so far."""
        return [self.placed[j].spec for j in self.placed if j != i]

    def room_m(self, p0: np.ndarray, p1: np.ndarray, i: int) -> float:
        """The largest radius a log on axis p0 -> p1 has between the others placed so far [m]."""
        return min((_segment_distance_3d(p0, p1, *o.endpoints_m()) - o.mean_diameter_m / 2 for o in self.neighbours(i)),
                   default=math.inf)

    def within_room(self, spec: LogSpec, i: int, slack_m: float = 0.0) -> LogSpec:
        """``spec`` thinned to the room its neighbours leave, plus ``slack_m`` (their surfaces
        and its axis are surveyed to a few cm: a little overlap is for the twin check to lift)."""
        p0, p1 = spec.endpoints_m()
        room = self.room_m(p0, p1, i) + slack_m
        return (LogSpec.from_endpoints(p0, p1, 2 * room) if self.cfg.min_radius_m <= room < spec.mean_diameter_m / 2
                else spec)

    def no_thicker_than_seen(self, spec: LogSpec) -> LogSpec:
        """A log seen only in part, no thicker than the thickest log the scan shows whole: its radius is
        the distance from its survey axis to what the scan shows of its top, and a float end puts that
        axis decimetres off, the radius with it (and the pile check then refuses the pile); then it is the
        pile's typical log."""
        whole = [p.spec.mean_diameter_m for p in self.placed.values() if p.how == "scan"]
        if not whole or spec.mean_diameter_m <= max(whole):
            return spec
        p0, p1 = spec.endpoints_m()
        return LogSpec.from_endpoints(p0, p1, self.typical_d, colour=spec.colour)

    def place_hidden(self, i: int, why: LogNotSeenError) -> None:
        cfg, P = self.cfg, self.P
        a, b = self.endpoints[self.ids[i]]
        if not _covered_by_others(P, a, b, cfg):
            raise why  # nothing over it either: outside the scan, or wrong end points
        spec = _sandwiched_log(P, a, b, self.neighbours(i), cfg)
        whence = "as thick as the gap between the ground and the logs over it"
        if spec is None:  # not lying between the ground and logs over it: the survey's axis
            spec = self.within_room(_survey_log(a, b, self.typical_d, cfg, self.ids[i]), i)
            whence = f"the pile's typical {self.typical_d * 100:.1f} cm within the room left; heights surveyed"
        ab = np.array([a, b], dtype=float)
        f = CylinderFit(centre=ab.mean(axis=0), axis=(ab[1] - ab[0]) / np.linalg.norm(ab[1] - ab[0]), ends=ab,
                        radius_a_m=spec.diameter_m / 2, radius_b_m=spec.diameter_m / 2, n_points=0, rms_m=math.nan,
                        coverage=0.0, residual_a_m=0.0, residual_b_m=0.0)
        self.placed[i] = _PlacedLog(f, spec, False, "hidden")
        self.say(f"log {self.ids[i]}: hidden under others ({why}); axis from GNSS, "
                 f"diameter {spec.diameter_m * 100:.1f} cm "
                 f"({whence})")

    def run(self, first: _FirstPass) -> None:
        cfg, P, ids, endpoints = self.cfg, self.P, self.ids, self.endpoints
        hidden = dict(first.hidden)
        specs = list(first.specs)
        # until it is placed (place_hidden), a hidden log is the pile's typical one on its survey axis
        self.typical_d = float(np.median([log.mean_diameter_m for log in specs if log is not None]))
        for i in hidden:
            specs[i] = _survey_log(*endpoints[ids[i]], self.typical_d, cfg, ids[i])
        # a first fit this far off its GNSS axis (several sigma of RTK noise) took another surface,
        # most likely: a neighbour's (a log lying under another) or the ground beside it. Its refit
        # gets only the points no other log explains
        suspect = [i in hidden or _axis_shift(log, *endpoints[log_id]) > cfg.suspect_shift_m
                   for i, (log, log_id) in enumerate(zip(specs, ids))]
        owner = _owners(P, specs, cfg.inlier_band_m, suspect)
        on_axis: list[int] = []  # logs seen only in part: placed once the others are fitted
        for i in sorted(range(len(ids)), key=lambda k: suspect[k]):  # trusted logs first
            if i in hidden:
                continue
            log_id = ids[i]
            if log_id in self.in_part:  # the scan shows a piece of it: its survey points set its axis
                on_axis.append(i)
                continue
            a, b = endpoints[log_id]
            sa, sb = self.sigmas.get(log_id, (None, None))
            mine = P[(owner == i) | (owner < 0)]
            trusted = [self.placed[j].spec for j in self.placed if not suspect[j]]
            try:
                f = fit_log(mine, a, b, cfg, log_id=log_id, rng=self.rng, sigma_a_m=sa, sigma_b_m=sb)
                spec, swapped = log_spec_from_fit(f, cfg)
                astray = _axis_shift(spec, a, b) > cfg.suspect_shift_m
            except LogNotSeenError:  # its first fit took a neighbour's points: none are left to it
                astray = True
            except FitError as exc:
                if log_id not in self.optional:
                    # the points left to it fit no cylinder (a log under others along it): as above, its
                    # first fit if it had one, else seen in part
                    astray = True
                else:
                    self.dropped[log_id] = ("no log fits the scan points left to it once the other logs took "
                                            f"theirs ({exc})")
                    self.say(f"log {log_id}: left out, {self.dropped[log_id]}")
                    continue
            if astray and not suspect[i] and i in first.fits:
                # the refit on the points left to it strayed where its first fit had not (a log
                # mostly hidden: its few points let the refit tilt): the first fit stands
                f = first.fits[i]
                spec, swapped = log_spec_from_fit(f, cfg)
                astray = False
            if astray or suspect[i] and any(_interpenetration(spec, o) > cfg.penetration_tolerance_m for o in trusted):
                # still astray, or inside a trusted neighbour: the log is seen only in part (under another)
                on_axis.append(i)
                continue
            self.placed[i] = _PlacedLog(f, spec, swapped, "scan")
        for i in on_axis:
            # its axis is the survey's, its radius what the scan shows of its top, at most the room
            # its neighbours leave around that axis
            log_id = ids[i]
            a, b = endpoints[log_id]
            try:
                f = fit_radius_on_axis(P[(owner == i) | (owner < 0)], a, b, cfg, log_id=log_id)
            except LogNotSeenError as exc:
                hidden[i] = exc
                continue
            spec, swapped = log_spec_from_fit(f, cfg)
            spec = self.no_thicker_than_seen(spec)
            self.placed[i] = _PlacedLog(f, self.within_room(spec, i, slack_m=cfg.gnss_sigma_m), swapped, "partial")
            self.say(f"log {log_id}: seen only in part; axis from GNSS, "
                     f"diameter {self.placed[i].spec.diameter_m * 100:.1f} cm")
        for i in sorted(hidden):
            if ids[i] in self.optional:
                self.dropped[ids[i]] = f"no scan points of its own once the other logs took theirs ({hidden[i]})"
                self.say(f"log {ids[i]}: left out, {self.dropped[ids[i]]}")
                continue
            self.place_hidden(i, hidden[i])
        self.drop_borrowed()

    def drop_borrowed(self) -> None:
        """Leave out a log found in the scan alone whose surface points lie mostly on the other logs
        (within ``end_walk_band_m`` of them: more than ``max_borrowed_share``): a line across the tops
        of logs that cross it, not a log (which the pile check then refuses; of a log the survey missed,
        a few per cent lie there)."""
        cfg = self.cfg
        for i in sorted(self.placed):
            log_id = self.ids[i]
            if log_id not in self.optional:
                continue
            spec = self.placed[i].spec
            on = np.abs(_distance_to_logs(self.P, [spec], pad_m=0.0)) <= cfg.inlier_band_m
            others = [self.placed[j].spec for j in self.placed if j != i]
            if not on.any() or not others:
                continue
            near = np.abs(_distance_to_logs(self.P[on], others, pad_m=0.0)) <= cfg.end_walk_band_m
            if float(near.mean()) > cfg.max_borrowed_share:
                self.dropped[log_id] = (f"{100 * near.mean():.0f} % of its scan points lie on other logs (within "
                                        f"{cfg.end_walk_band_m * 100:.0f} cm): the tops of logs crossing its line")
                self.say(f"log {log_id}: left out, {self.dropped[log_id]}")
                del self.placed[i]

    def place_ends(self, keep: Sequence[int],
                   place: Callable[[str, LogSpec, str, np.ndarray, bool, np.ndarray], tuple[LogSpec, Any]],
                   ) -> dict[int, tuple]:
        """Each kept log's ends placed by ``place`` on the points on no other log (within
        ``inlier_band_m``), those within ``end_walk_band_m`` of another log marked as not showing its
        top; a log seen only in part thinned again to the room around its placed ends. Returns what
        placed them, per log."""
        cfg = self.cfg
        specs = [self.placed[i].spec for i in keep]
        mine = dict(zip(keep, points_on_no_other_log(self.P, specs, cfg.inlier_band_m)))
        clear = dict(zip(keep, points_on_no_other_log(self.P, specs, cfg.end_walk_band_m)))
        ends_info: dict[int, tuple] = {}
        for i in keep:
            pl = self.placed[i]
            try:
                spec, info = place(self.ids[i], pl.spec, pl.how, self.P[mine[i]], bool(pl.swapped), clear[i][mine[i]])
            except FitError as exc:
                if self.ids[i] not in self.optional:
                    raise
                # a log found in the scan alone with an end the scan shows nothing of once the other logs
                # took their points: pieces of others, not a log
                self.dropped[self.ids[i]] = f"its ends cannot be placed once the other logs took their points ({exc})"
                self.say(f"log {self.ids[i]}: left out, {self.dropped[self.ids[i]]}")
                continue
            if pl.how == "partial":
                # its ends may have moved out (to its survey points): still no thicker than the room left
                spec = self.within_room(spec, i, slack_m=cfg.gnss_sigma_m)
            pl.spec = spec
            ends_info[i] = tuple(e if isinstance(e, dict) else e.to_dict() for e in info)
        return ends_info


def _log_fits(placement: _Placement, keep: Sequence[int], ends_info: Mapping[int, tuple]) -> list[LogFit]:
    """The per-log report of the kept logs, indexed as in the pile."""
    fits: list[LogFit] = []
    for index, i in enumerate(keep):
        log_id = placement.ids[i]
        pl = placement.placed[i]
        f, spec, swapped = pl.fit, pl.spec, pl.swapped
        a, b = placement.endpoints[log_id]
        butt, top = spec.endpoints_m()
        p0, p1 = np.asarray(a, float), np.asarray(b, float)
        ends = f.ends
        lf = LogFit(
            log_id=log_id, index=index, butt_m=tuple(float(v) for v in butt), top_m=tuple(float(v) for v in top),
            length_m=spec.length_m, diameter_m=spec.diameter_m, top_diameter_m=spec.top_diameter_m,
            n_points=f.n_points, rms_m=f.rms_m, coverage=f.coverage,
            gnss_residual_a_m=f.residual_a_m, gnss_residual_b_m=f.residual_b_m,
            axis_shift_m=float(max(np.linalg.norm(ends[0] - p0), np.linalg.norm(ends[1] - p1))),
            swapped=bool(swapped), end_source=tuple(reversed(f.end_source)) if swapped else tuple(f.end_source),
            radius_source=f.radius_source, fit=pl.how,
        )
        if i in ends_info:
            lf.ends = [dict(e) for e in ends_info[i]]
            srcs = tuple(e["source"] for e in ends_info[i])
            lf.end_source = tuple(reversed(srcs)) if swapped else srcs
            # each survey point's distance from the placed log's axis (NaN: no point)
            lf.gnss_residual_a_m, lf.gnss_residual_b_m = (
                float(e.get("gnss_axis_distance_m", math.nan) if e.get("gnss_axis_distance_m") is not None
                      else math.nan) for e in ends_info[i])
        fits.append(lf)
    return fits


def _ground(P: np.ndarray, logs: Sequence[LogSpec], extent_m: float, cfg: FitConfig,
            timings: dict[str, float], say: Callable[[str], None]) -> _Ground:
    """The terrain from the points off the logs (held under their undersides), then the obstacles
    standing on it."""
    import time

    half = extent_m / 2
    t1 = time.perf_counter()
    say("fitting terrain")
    dist = _distance_to_logs(P, logs, pad_m=cfg.terrain_log_pad_m)
    # not log, and not inside a log's top-view footprint (stereo smears log edges down there)
    rest = P[(dist > cfg.log_clearance_m) & (_footprint_distance(P[:, :2], logs) > cfg.footprint_margin_m)]
    terrain, is_ground, coverage = fit_terrain(rest, extent_m, cfg)
    terrain = _clamp_under_logs(terrain, logs)
    timings["terrain_s"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    say("finding obstacles")
    z_ground = terrain.height_at(rest[:, 0], rest[:, 1])
    above = rest[(~is_ground) & (rest[:, 2] > z_ground + cfg.obstacle_min_height_m)
                 & (np.abs(rest[:, 0]) < half) & (np.abs(rest[:, 1]) < half)]
    flank = rest[(rest[:, 2] > z_ground + cfg.obstacle_flank_height_m)
                 & (rest[:, 2] <= z_ground + cfg.obstacle_min_height_m)
                 & (np.abs(rest[:, 0]) < half) & (np.abs(rest[:, 1]) < half)]
    if logs and len(flank):
        flank = flank[_footprint_distance(flank[:, :2], logs) > cfg.obstacle_flank_log_gap_m]
    stumps, rocks, info = find_obstacles(above, terrain, cfg, logs, flank_points=flank)
    timings["obstacles_s"] = time.perf_counter() - t2
    return _Ground(terrain, is_ground, coverage, stumps, rocks, info, int(len(above)))


def _remeasure_hint(logs: Sequence[int], fits: Sequence[LogFit]) -> str:
    """What a pile-check refusal asks of the survey crew: the survey ids of the logs in the contact, and
    their end points that are not RTK fixed (the likeliest to be wrong), or, all fixed, what else to check."""
    named = [fits[k] for k in logs if 0 <= k < len(fits)]
    if not named:
        return ""
    ids = ", ".join(f"{lf.index} is {lf.log_id!r}" for lf in named)
    weak = [f"{lf.log_id!r} end {'ab'[j]} ({e.get('gnss_fix') or 'no point'}, +-{e['sigma_m'] * 100:.0f} cm)"
            for lf in named for j, e in enumerate(lf.ends or []) if e.get("gnss_fix") != "rtk_fixed"]
    if weak:
        return f" (log {ids}). Re-measure with an RTK fixed solution: {'; '.join(weak)}"
    return f" (log {ids}). Their end points are all RTK fixed: check that each point carries its log's id and end"


def fit_pile(points: np.ndarray, endpoints: Mapping[str, tuple[Any, Any]], extent_m: float,
             cfg: FitConfig | None = None, progress: Callable[[str], None] | None = None,
             georef: Any = None, notes: str = "",
             first_pass: Mapping[str, LogSpec] | None = None,
             sigmas: Mapping[str, tuple[float, float]] | None = None,
             place_ends: Callable[[str, LogSpec, str, np.ndarray, bool, np.ndarray], tuple[LogSpec, Any]] | None = None,
             optional: Collection[str] = (),
             in_part: Collection[str] = (),
             settle: Callable[[PileSpec, list[LogFit]], Any] | None = None,
             ) -> PileFit:
    """Fit a whole pile to scan ``points`` ((N, 3), pile frame) and GNSS ``endpoints``
    (``{log_id: (end_a, end_b)}``, pile frame: where each log is searched for). ``extent_m``: side
    of the terrain patch, centred on the origin. Returns a :class:`PileFit` whose ``pile`` has
    ``source="reconstructed"``.

    ``place_ends``: called once every log is placed, before the terrain, with (log id, its
    LogSpec, how it was placed, the scan points on no other log, whether end b is its butt, which of
    those points may show its top: not within ``end_walk_band_m`` of another log); returns
    the log with its ends moved and what placed them (two dicts, ends a and b, kept in
    ``LogFit.ends``; their ``source`` becomes ``LogFit.end_source``) — how
    :mod:`reconstruct.fitting.fuse` places each end from the scan and the survey by their accuracies.

    ``optional``: ids of logs found in the scan alone (no survey): one that has no scan points of its
    own once the other logs have taken theirs (a ridge made of other logs' pieces) is left out, with
    the reason in ``PileFit.dropped``, instead of failing the pile; it cannot be hidden, it was seen.
    ``in_part``: ids of logs the scan shows only a piece of (the matching's word: a ridge far shorter
    than the log's two precise survey points are apart): seen only in part, on their survey axes.
    ``settle``: in place of the twin's check (:func:`clear_pile`), called with the pile and the log fits;
    returns a :class:`reconstruct.fitting.clearance.Cleared` (the joint estimator's
    :class:`reconstruct.fitting.joint_settle.JointSettler`).

    Steps: :func:`_first_pass` (each log on its own), :class:`_Placement` (each scan point to the log
    whose surface it lies on, then each log refitted among the others; its ends placed), :func:`_ground`
    (terrain, obstacles), :func:`separate_logs` (the twin's check).
    """
    import time

    cfg = cfg or FitConfig()
    say = progress or (lambda s: None)
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
        raise ValueError(f"points must be a non-empty (N, 3) array, got shape {P.shape}")
    P = P[np.all(np.isfinite(P), axis=1)]
    if not endpoints:
        raise ValueError("no log endpoints given; the survey is empty")
    rng = np.random.default_rng(cfg.seed)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    ids = sorted(endpoints, key=natural_key)
    _check_endpoints(endpoints, ids, extent_m)
    first = _first_pass(P, ids, endpoints, cfg, rng, first_pass, sigmas, say)
    placement = _Placement(P, ids, endpoints, cfg, rng, sigmas, optional, say, in_part)
    placement.run(first)
    keep = [i for i in range(len(ids)) if ids[i] not in placement.dropped]
    ends_info: dict[int, tuple] = {}
    if place_ends is not None:
        before = {i: placement.placed[i].spec for i in keep}
        ends_info = placement.place_ends(keep, place_ends)
        if any(ids[i] in placement.dropped for i in keep):  # place the others again without it
            keep = [i for i in keep if ids[i] not in placement.dropped]
            for i in keep:
                placement.placed[i].spec = before[i]
            ends_info = placement.place_ends(keep, place_ends)
    fits = _log_fits(placement, keep, ends_info)
    logs = [placement.placed[i].spec for i in keep]
    timings["logs_s"] = time.perf_counter() - t0
    ground = _ground(P, logs, extent_m, cfg, timings, say)
    pile = PileSpec(terrain=ground.terrain, logs=tuple(logs), stumps=tuple(ground.stumps), rocks=tuple(ground.rocks),
                    georef=georef, source="reconstructed", notes=notes)
    move_notes: list[str] = []
    end_moves: list[str] = []
    if cfg.validate:
        t3 = time.perf_counter()
        say("checking the pile in the twin")
        before = pile.logs
        thinnable = [placement.placed[i].how == "scan" for i in keep]
        try:
            cleared = (settle(pile, fits) if settle is not None else
                       clear_pile(pile, [lf.ends or [] for lf in fits],
                                  lambda p: separate_logs(p, cfg, thinnable=thinnable), cfg.clearance))
        except SeparationError as exc:
            raise SeparationError(f"{exc}{_remeasure_hint(exc.logs, fits)}", logs=exc.logs) from exc
        pile, move_notes, end_moves = cleared.pile, cleared.notes, cleared.end_moves
        for (k, j), e in cleared.at_survey.items():
            fits[k].ends[j] = e
        for lf, log, old, dist in zip(fits, pile.logs, before, cleared.moved):
            lf.moved_m = float(dist)
            lf.thinned_m = float(old.diameter_m - log.diameter_m) / 2
            if log != old:
                butt, top = log.endpoints_m()
                lf.butt_m = tuple(float(v) for v in butt)
                lf.top_m = tuple(float(v) for v in top)
                lf.diameter_m, lf.top_diameter_m = log.diameter_m, log.top_diameter_m
        timings["validate_s"] = time.perf_counter() - t3
    return PileFit(pile=pile, logs=fits, terrain_coverage=ground.coverage, n_ground_points=int(ground.is_ground.sum()),
                   n_obstacle_points=ground.n_above, obstacles=ground.info, moves=move_notes, end_moves=end_moves,
                   timings_s=timings,
                   dropped=dict(placement.dropped))


# -- synthetic scans (tests, benchmarks) -----------------------------------------------------
def sample_top_view_points(pile: PileSpec, size_px: int = 500, noise_m: float = 0.0,
                           rng: np.random.Generator | None = None) -> np.ndarray:
    """Points of ``pile`` as seen from straight above (what a downward scanner sees, occlusion
    included): the exact orthographic height map of the twin at ``size_px`` pixels per side,
    one point per pixel, plus Gaussian noise of ``noise_m`` on every coordinate. Pile frame, (N, 3)."""
    from synth.geometry.frames import OrthoGrid
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    with World(pile) as world:
        obs = render_ortho(world, OrthoRenderConfig(size_px=size_px, n_renders=1))
    X, Y = OrthoGrid(size_px, pile.terrain.extent_m).pixel_centres()
    P = np.column_stack([X.ravel(), Y.ravel(), obs.height().ravel().astype(np.float64)])
    if noise_m > 0:
        rng = rng or np.random.default_rng(0)
        P = P + rng.normal(0.0, noise_m, size=P.shape)
    return P
