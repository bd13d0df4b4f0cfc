"""The twin's scan planned from the survey (make_twin_scan(plan=...)): the rendered pairs see every true
log end where the matcher gives depth, on a loose pile the fixed 2x2 grid does not cover; the survey
written is the one the plan saw."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reconstruct.scan.plan import ScanPlan, ScanPlanConfig
from reconstruct.scan.twin_scan import make_twin_scan, plan_twin_scan
from reconstruct.survey.gnss import read_gnss_csv
from synth.scene.pile import read_pile

#: small images (fast to render); the plan's camera is the same model at 320 x 180 px
SMALL = ScanPlanConfig(width_px=320, height_px=180)
LOOSE = {"pile_spread_m": 0.6, "yaw_spread_rad": 0.7}


def seen_with_depth(T_pile_cam: np.ndarray, points: np.ndarray, cfg: ScanPlanConfig) -> np.ndarray:
    """Which points the pair's left camera images in its depth-giving part (past the matcher's band on
    the left, inside the border)."""
    T = np.linalg.inv(np.asarray(T_pile_cam))
    cam = points @ T[:3, :3].T + T[:3, 3]
    f = cfg.focal_px()
    u = f * cam[:, 0] / cam[:, 2] + (cfg.width_px - 1) / 2
    v = f * cam[:, 1] / cam[:, 2] + (cfg.height_px - 1) / 2
    lo_a, _, _, _ = cfg.footprint_slopes()
    u0 = (cfg.width_px - 1) / 2 + lo_a * f
    return (cam[:, 2] > 0) & (u >= u0) & (u <= cfg.width_px - 1 - cfg.border_px) & (v >= cfg.border_px) & (
        v <= cfg.height_px - 1 - cfg.border_px)


@pytest.fixture(scope="module")
def loose_scan(tmp_path_factory):
    root = tmp_path_factory.mktemp("plan") / "scan"
    # a loose pile of 6 logs whose ends the 2x2 grid leaves out (found by the first assertion below)
    return make_twin_scan(root, seed=3390004, logs=(6, 6), obstacles=(0, 0), n_float=2, plan=SMALL, **LOOSE)


@pytest.mark.slow
def test_the_planned_pairs_see_every_true_end_the_2x2_grid_misses(loose_scan):
    info = json.loads((loose_scan / "scan.json").read_text())
    pile = read_pile(loose_scan / "truth" / "pile.json")
    ends = np.array([e for log in pile.logs for e in log.endpoints_m()])
    ends_above = ends - np.column_stack([np.zeros((len(ends), 2)), [pile.terrain.height_at(*e[:2]) for e in ends]])
    plan = info["plan"]
    old = ScanPlan((2, 2), tuple(plan["centre_xy_m"]), np.radians(plan["yaw_deg"]), (1.4, 1.0), 3.0, 0.0)
    assert old.slack_m(ends_above, SMALL).min() < 0  # the 2x2 grid misses an end
    assert tuple(plan["grid"]) > (2, 2) and info["pairs"] == plan["grid"][0] * plan["grid"][1]
    poses = json.loads((loose_scan / "truth" / "poses.json").read_text())["T_pile_cam"]
    assert len(poses) == info["pairs"] == len(list((loose_scan / "scan").glob("pair_*")))
    seen = np.zeros(len(ends), bool)
    for T in poses.values():
        seen |= seen_with_depth(np.array(T), ends, SMALL)
    assert seen.all(), np.flatnonzero(~seen)


@pytest.mark.slow
def test_the_written_survey_is_the_one_planned(loose_scan):
    info = json.loads((loose_scan / "scan.json").read_text())
    again = plan_twin_scan(read_pile(loose_scan / "truth" / "pile.json"),
                           read_gnss_csv(loose_scan / "gnss.csv", allow_float=True), SMALL)
    assert list(again.grid) == info["plan"]["grid"]
    assert np.allclose(again.centre_xy, info["plan"]["centre_xy_m"], atol=1e-3)


def test_pairs_over_no_terrain_are_left_out():
    """A planned pair with less than half its ground footprint on the twin's terrain patch is not rendered
    (the twin draws nothing beyond it to match); a grid over the patch keeps every pair."""
    from reconstruct.scan.twin_scan import pairs_beyond_terrain
    from synth.scene.pile import LogSpec, PileSpec, TerrainSpec

    pile = PileSpec(terrain=TerrainSpec(extent_m=5.0), logs=(LogSpec.from_endpoints((-1, 0, 0.1), (1, 0, 0.1), 0.2),))
    over = ScanPlan((2, 2), (0.0, 0.0), 0.0, (1.4, 1.0), 3.0, 0.3)
    assert pairs_beyond_terrain(pile, over, ScanPlanConfig()) == frozenset()
    # 4 pairs along, 1 m right of the patch's centre: the last pair sees 1.96-4.49 m along, 21 % of it on the
    # patch (edge 2.5 m); the one before it 0.56-3.09 m, 77 %
    wide = ScanPlan((4, 1), (1.0, 0.0), 0.0, (1.4, 1.0), 3.0, 0.3)
    assert pairs_beyond_terrain(pile, wide, ScanPlanConfig()) == frozenset({3})
