"""The fusion tests' module pile: hand-made logs, and its exact top-view scan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reconstruct.fitting.fit import sample_top_view_points
from reconstruct.scan.stereo import ScanCloud
from synth.geometry.frames import make_T, rot_z
from synth.scene.pile import Georeference, LogSpec, PileSpec, TerrainSpec
from tests.reconstruct.fitting.fusion_helpers import ORIGIN


@pytest.fixture(scope="module")
def pile() -> PileSpec:
    """Four logs on flat ground: two side by side, one across both, one apart."""
    terrain = TerrainSpec(extent_m=5.0, resolution=32, amplitude_m=0.0,
                          heights_m=tuple(tuple(0.0 for _ in range(32)) for _ in range(32)))
    logs = (
        LogSpec.from_endpoints((-1.0, -0.5, 0.08), (1.0, -0.5, 0.08), 0.16),
        LogSpec.from_endpoints((-0.9, 0.35, 0.07), (1.1, 0.2, 0.07), 0.14),
        LogSpec.from_endpoints((-0.55, -1.1, 0.23), (-0.35, 0.95, 0.21), 0.14),  # across both
        LogSpec.from_endpoints((0.2, 1.0, 0.075), (1.9, 1.45, 0.075), 0.15),
    )
    T = make_T(rot_z(math.radians(25.0)), (3.0, -2.0, 0.0))
    return PileSpec(terrain=terrain, logs=logs,
                    georef=Georeference(*ORIGIN, T_site_pile=tuple(tuple(float(v) for v in r) for r in T)))


@pytest.fixture(scope="module")
def cloud(pile) -> ScanCloud:
    pts = sample_top_view_points(pile, 500, 0.003, np.random.default_rng(1))
    return ScanCloud(pts, np.full((len(pts), 3), 0.5, np.float32), camera_positions=np.array([[0.0, 0.0, 3.0]]))
