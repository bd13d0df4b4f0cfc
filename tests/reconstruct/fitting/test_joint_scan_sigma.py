"""Each log's scan sigma from its own evidence (reconstruct.fitting.joint_scan_sigma, joint revision 11): a log
whose surface the scan shows less of is less sure, and the pile check's refusal is judged against the log's own
sigma. Hand-made logs and points on their surfaces; the twin checks each settled pile."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruct.errors import SeparationError
from reconstruct.fitting.fit_config import LogFit
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_scan_sigma import scan_sigma
from reconstruct.fitting.joint_settle import JointSettler
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec

CFG = JointConfig()
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
    settler = JointSettler({}, {}, JointConfig(per_log_sigma=False), TOL, 12, points=tops, band_m=BAND)
    with pytest.raises(SeparationError, match=r"\+-2\.0 cm across"):  # revision 10's 2 cm: 6 cm each is refused
        settler(pile, fits)
    assert settler.sigmas == {}


def test_the_per_log_sigma_parameters_are_checked():
    for name in ("sigma_cell_along_m", "sigma_cell_deg", "sigma_cell_min_m", "sigma_radius_prior_m",
                 "sigma_shape_per_radius", "sigma_max_m"):
        with pytest.raises(ValueError, match=name):
            JointConfig(**{name: 0})
