"""Each log's scan sigma from its own evidence (reconstruct.fitting.joint_scan_sigma, joint revision 11): a log
whose surface the scan shows less of is less sure, and the pile check's refusal is judged against the log's own
sigma. Hand-made logs and points on their surfaces; the twin checks each settled pile."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from reconstruct.errors import SeparationError
from reconstruct.fitting.fit_config import LogFit
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_scan_sigma import radius_misfit, scan_sigma
from reconstruct.fitting.joint_settle import JointSettler
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec

CFG = JointConfig(radius_states=False)  # the per-log sigmas with fixed radii (radius states: test_joint_radius)
R = 0.1  # the logs' radius [m]
BAND = 0.015  # how near its surface a point is on a log (FitConfig.inlier_band_m) [m]
TOL = 0.01  # the twin's tolerance [m]
FLAT = TerrainSpec(extent_m=4.0, resolution=16, heights_m=tuple(tuple(0.0 for _ in range(16)) for _ in range(16)))


def _log(y: float, z: float = R) -> LogSpec:
    return LogSpec.from_endpoints((-1.0, y, z), (1.0, y, z), 2 * R)


def _surface(log: LogSpec, lo_deg: float, hi_deg: float, along=(0.0, 1.0), noise_m: float = 0.002,
             seed: int = 0, ripple_m: float = 0.0) -> np.ndarray:
    """Points on ``log``'s round surface from ``lo_deg`` to ``hi_deg`` round from its top (+: toward +y, the
    across vector of a log along +x) over the share ``along`` of its length, every 1 cm and 3 deg, with noise
    and a ripple of ``ripple_m`` round the log (what stereo leaves: errors that cells do not average away)."""
    rng = np.random.default_rng(seed)
    butt, top = log.endpoints_m()
    t = np.arange(along[0], along[1], 0.01 / log.length_m)
    phi = np.radians(np.arange(lo_deg, hi_deg + 1e-9, 3.0))
    T, PHI = np.meshgrid(t, phi)
    axis = butt + np.outer(T.ravel(), top - butt)
    # across vector of an axis along +x: (-u_y, u_x, 0) = +y; up: +z
    rad = R + ripple_m * np.sin(7 * PHI.ravel())
    P = axis + rad[:, None] * np.column_stack([np.zeros(T.size), np.sin(PHI.ravel()), np.cos(PHI.ravel())])
    return P + rng.normal(0.0, noise_m, P.shape)


def test_a_log_seen_whole_is_surer_than_one_seen_from_one_side_or_only_on_top():
    log = _log(0.0)
    whole = scan_sigma(_surface(log, -90, 90), log, BAND, CFG)
    one_side = scan_sigma(_surface(log, -20, 90), log, BAND, CFG)
    top_arc = scan_sigma(_surface(log, -30, 30), log, BAND, CFG)
    shape = CFG.sigma_shape_per_radius * R
    assert whole.across_m[0] == pytest.approx(shape, rel=0.05)  # seen whole: the shape term alone
    assert whole.up_m[0] == pytest.approx(shape, rel=0.05)
    assert one_side.across_m[0] > 1.1 * whole.across_m[0]  # a flank it cannot see is looser
    assert top_arc.across_m[0] > 1.1 * one_side.across_m[0]  # ... and two flanks looser still
    assert top_arc.up_m[0] > 2 * whole.up_m[0]  # the underside of a top arc: its radius is loose
    assert top_arc.radius_m > 1.3 * whole.radius_m
    assert whole.arc_deg == pytest.approx((90, 90), abs=8) and top_arc.arc_deg == pytest.approx((30, 30), abs=8)


def test_an_end_the_scan_shows_nothing_near_is_less_sure_than_the_end_it_shows():
    log = _log(0.0)
    half = scan_sigma(_surface(log, -40, 40, along=(0.0, 0.3), ripple_m=0.004), log, BAND, CFG)  # the butt's 60 cm
    assert half.across_m[1] > 1.1 * half.across_m[0] and half.up_m[1] > half.up_m[0]
    nothing = scan_sigma(np.zeros((0, 3)), log, BAND, CFG)
    assert nothing.cells == 0 and nothing.across_m == (CFG.sigma_max_m, CFG.sigma_max_m)


def test_a_log_whose_cells_scatter_more_is_looser():
    log = _log(0.0)
    quiet = scan_sigma(_surface(log, -40, 40), log, BAND, CFG)
    rippled = scan_sigma(_surface(log, -40, 40, ripple_m=0.008), log, BAND, CFG)
    assert quiet.cell_noise_m == CFG.sigma_cell_min_m and rippled.cell_noise_m > 1.5 * quiet.cell_noise_m
    assert rippled.up_m[0] > 1.2 * quiet.up_m[0] and rippled.across_m[0] > quiet.across_m[0]


def _fit(log_id: str, index: int, log: LogSpec) -> LogFit:
    butt, top = log.endpoints_m()
    ends = [{"position_m": list(map(float, p)), "contradicted": False} for p in (butt, top)]
    return LogFit(log_id, index, tuple(butt), tuple(top), log.length_m, log.diameter_m, None, 100, 0.005, 1.0,
                  0.0, 0.0, 0.0, False, ends=ends, fit="scan")


def _two_logs_overlapping(gap_m: float):
    a, b = _log(-gap_m / 2), _log(gap_m / 2)
    return PileSpec(terrain=FLAT, logs=(a, b)), [_fit("log1", 0, a), _fit("log2", 1, b)]


def test_the_refusal_is_judged_against_each_logs_own_sigma():
    # round surfaces 8 cm into each other: clearing takes ~2 cm of each log, 1.4 sigma of logs seen whole
    pile, fits = _two_logs_overlapping(0.12)
    seen = np.vstack([_surface(lg, -90, 90, seed=k) for k, lg in enumerate(pile.logs)])
    settler = JointSettler({}, {}, CFG, TOL, 12, points=seen, band_m=BAND)
    out = settler(pile, fits)
    assert sorted(settler.sigmas) == ["log1", "log2"]
    assert all(s.across_m[0] == pytest.approx(CFG.sigma_shape_per_radius * R, rel=0.1) for s in settler.sigmas.values())
    assert all(0.015 < m < 0.03 for m in out.moved)
    # 8 cm closer: ~6 cm each, 4 sigma of logs seen whole - refused, the message giving their sigma
    pile, fits = _two_logs_overlapping(0.04)
    seen = np.vstack([_surface(lg, -90, 90, seed=k) for k, lg in enumerate(pile.logs)])
    with pytest.raises(SeparationError, match=r"what its scan \(\+-1\.5 cm across, \+-1\.5 cm up"):
        JointSettler({}, {}, CFG, TOL, 12, points=seen, band_m=BAND)(pile, fits)
    # the same move for logs the scan shows only a top arc of (packed: neighbours hide their flanks) is
    # within what their own evidence allows
    tops = np.vstack([_surface(lg, -20, 20, seed=k) for k, lg in enumerate(pile.logs)])
    settler = JointSettler({}, {}, CFG, TOL, 12, points=tops, band_m=BAND)
    out = settler(pile, fits)
    assert all(s.across_m[0] > 0.03 for s in settler.sigmas.values())
    assert all(0.04 < m < 0.08 for m in out.moved)


def test_without_per_log_sigma_every_scan_log_has_the_one_configured_sigma():
    pile, fits = _two_logs_overlapping(0.04)
    tops = np.vstack([_surface(lg, -20, 20, seed=k) for k, lg in enumerate(pile.logs)])
    settler = JointSettler({}, {}, replace(CFG, per_log_sigma=False), TOL, 12, points=tops, band_m=BAND)
    with pytest.raises(SeparationError, match=r"\+-2\.0 cm across"):  # revision 10's 2 cm: 6 cm each is refused
        settler(pile, fits)
    assert settler.sigmas == {}


def test_the_per_log_sigma_parameters_are_checked():
    for name in ("sigma_cell_along_m", "sigma_cell_deg", "sigma_cell_min_m", "sigma_radius_prior_m",
                 "sigma_shape_per_radius", "sigma_max_m"):
        with pytest.raises(ValueError, match=name):
            JointConfig(**{name: 0})


def _fitted(y: float, thick_m: float) -> LogSpec:
    """Log ``_log(y)`` as a fit ``thick_m`` too thick in radius would put it: its seen top kept, its axis lower."""
    return LogSpec.from_endpoints((-1.0, y, R - thick_m), (1.0, y, R - thick_m), 2 * (R + thick_m))


def test_a_fit_too_thick_leaves_its_own_points_inside_its_surface_and_its_radius_sigma_says_so():
    true = _log(0.0)
    seen = _surface(true, -90, 90)  # the top and both flanks of a log lying alone
    right = scan_sigma(seen, true, BAND, CFG, near=seen)
    assert right.radius_misfit_m < 0.001  # fitted right: its points as deep inside within the band as past it
    assert right.radius_m == pytest.approx(scan_sigma(seen, true, BAND, CFG).radius_m, rel=0.01)
    thick = _fitted(0.0, 0.04)  # fitted 8 cm too thick (3300153's log: 22 cm for 14): its flanks 4 cm inside
    blind = scan_sigma(seen, thick, BAND, CFG)  # the inlier band's cells alone: the flanks left out
    told = scan_sigma(seen, thick, BAND, CFG, near=seen)
    assert told.radius_misfit_m > 0.01
    assert told.radius_m == pytest.approx(math.hypot(blind.radius_m, told.radius_misfit_m))
    assert told.radius_m > blind.radius_m + 0.003
    assert (told.across_m, told.up_m, told.cell_noise_m) == (blind.across_m, blind.up_m, blind.cell_noise_m)


def test_the_radius_misfit_counts_only_points_inside_the_log_within_its_band_and_length():
    true = _log(0.0)
    seen = _surface(true, -90, 90)
    outside = np.array([[0.5, 0.0, 2 * R + 0.03]])  # a branch 3 cm over its top ...
    past = np.array([[1.3, 0.0, 2 * R - 0.02]])  # ... a point 2 cm inside its round extended past its top end
    deep = np.array([[0.0, 0.0, R]])  # on its axis: 10 cm inside, past radius_sigma_band_m
    extra = np.repeat(np.vstack([outside, past, deep]), 400, axis=0)
    assert radius_misfit(np.vstack([seen, extra]), true, BAND, CFG) < 0.001
    thick = _fitted(0.0, 0.04)
    assert radius_misfit(seen, thick, BAND, CFG) > 0.01
    assert radius_misfit(seen, thick, BAND, replace(CFG, radius_sigma_band_m=BAND)) == 0.0  # no wider: blind
    with pytest.raises(ValueError, match="radius_sigma_band_m"):
        JointConfig(radius_sigma_band_m=0.0)


def test_the_settle_gives_a_log_s_radius_sigma_its_misfit_only_with_radius_states_and_not_a_neighbour_s_points():
    thick, neighbour = _fitted(0.0, 0.04), _log(0.2)  # two true logs touching; log 0 fitted 8 cm too thick
    pile = PileSpec(terrain=FLAT, logs=(thick, neighbour))
    fits = [_fit("log1", 0, thick), _fit("log2", 1, neighbour)]
    mine = _surface(_log(0.0), -90, 60)  # its flank toward the neighbour partly hidden
    seen = np.vstack([mine, _surface(neighbour, -90, 90, seed=1)])  # the neighbour's flank 2 cm inside the fit
    off = JointSettler({}, {}, CFG, TOL, 12, points=seen, band_m=BAND)
    own, near = off.own_points(pile)
    assert near == [None, None]
    off.evidence(thick, fits[0], own[0])
    assert off.sigmas["log1"].radius_misfit_m == 0.0  # revision 13: its radius sigma as the band's cells say
    on = JointSettler({}, {}, replace(CFG, radius_states=True), TOL, 12, points=seen, band_m=BAND)
    own, near = on.own_points(pile)
    ev = on.evidence(thick, fits[0], own[0], near[0])
    assert on.sigmas["log1"].radius_misfit_m > 0.01 and ev.sigma_radius_m == on.sigmas["log1"].radius_m
    # the neighbour's surface is the neighbour's: its points inside the thick fit say nothing of it
    assert on.sigmas["log1"].radius_misfit_m == pytest.approx(radius_misfit(mine, thick, BAND, CFG), rel=0.02)
    assert radius_misfit(seen, thick, BAND, CFG) > 1.1 * radius_misfit(mine, thick, BAND, CFG)
    on.evidence(neighbour, fits[1], own[1], near[1])
    assert on.sigmas["log2"].radius_misfit_m < 0.002
