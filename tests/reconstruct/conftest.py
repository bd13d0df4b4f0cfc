"""Shared reconstruction test geometry."""

from __future__ import annotations

import pytest

from synth.scene.pile import LogSpec, PileSpec, TerrainSpec


# -- exact geometry for registration and comparison -------------------------------------------
@pytest.fixture(scope="module")
def crossed() -> PileSpec:
    terrain = TerrainSpec(extent_m=5.0, resolution=32, amplitude_m=0.0,
                          heights_m=tuple(tuple(0.0 for _ in range(32)) for _ in range(32)))
    logs = (
        LogSpec.from_endpoints((-1.0, -0.4, 0.08), (1.0, -0.4, 0.08), 0.16),
        LogSpec.from_endpoints((-0.9, 0.5, 0.07), (1.1, 0.3, 0.07), 0.14),
        LogSpec.from_endpoints((-0.6, -1.0, 0.233), (-0.4, 1.0, 0.233), 0.14),  # across both
    )
    return PileSpec(terrain=terrain, logs=logs)


