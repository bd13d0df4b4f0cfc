import json
import math

import numpy as np
import pytest

from synth.errors import PileFormatError, PileValidationError
from synth.scene.generate import validate_pile
from synth.scene.pile import (
    Georeference, LogSpec, PileSpec, RockSpec, RootSpec, StumpSpec, TerrainSpec, quat_from_euler,
    read_pile, write_pile,
)


def flat(h=0.0, n=32):
    return TerrainSpec(resolution=n, heights_m=tuple(tuple([h] * n) for _ in range(n)))


def sample_pile() -> PileSpec:
    return PileSpec(
        terrain=TerrainSpec(seed=4),
        logs=(
            LogSpec(centre_m=(0.1, 0.2, 0.3), orientation=quat_from_euler(0.1, 0.0, 0.7), length_m=2.4, diameter_m=0.17),
            LogSpec(centre_m=(-0.4, 0.2, 0.5), orientation=quat_from_euler(0, 0, 0.2), length_m=2.0,
                    diameter_m=0.2, top_diameter_m=0.12),
        ),
        stumps=(StumpSpec(position_m=(1.5, 1.5), height_m=0.4, bottom_radius_m=0.2, top_radius_m=0.17,
                          roots=(RootSpec(azimuth_rad=1.0, length_m=0.4, radius_m=0.07),)),),
        rocks=(RockSpec(position_m=(-1.5, -1.5, 0.1), orientation=(0, 0, 0, 1),
                        vertices_m=((0.3, 0, 0), (-0.3, 0, 0), (0, 0.3, 0), (0, -0.3, 0), (0, 0, 0.3))),),
        georef=Georeference(origin_lat_deg=64.1, origin_lon_deg=20.0, origin_h_m=50.0),
        seed=3,
    )


def test_round_trip(tmp_path):
    pile = sample_pile()
    path = write_pile(pile, tmp_path / "pile.json")
    assert read_pile(path) == pile
    assert read_pile(tmp_path) == pile  # a folder holding pile.json
    d = json.loads(path.read_text())
    assert d["format"] == "loggrasp.pile" and d["format_version"].startswith("1.")


def test_log_geometry_helpers():
    log = LogSpec.from_endpoints((0, 0, 0.1), (2.0, 0.0, 0.1), 0.2, 0.1)
    butt, top = log.endpoints_m()
    np.testing.assert_allclose(butt, (0, 0, 0.1), atol=1e-9)
    np.testing.assert_allclose(top, (2, 0, 0.1), atol=1e-9)
    assert log.volume_m3() == pytest.approx(math.pi * 2.0 * (0.01 + 0.005 + 0.0025) / 3)


def test_newer_major_version_fails_clearly(tmp_path):
    d = sample_pile().to_dict()
    d["format_version"] = "2.0"
    (tmp_path / "pile.json").write_text(json.dumps(d))
    with pytest.raises(PileFormatError, match="2.0.*not supported"):
        read_pile(tmp_path / "pile.json")


@pytest.mark.parametrize("text,match", [
    ("{not json", "not valid JSON"),
    ('{"format": "something else"}', "not a loggrasp pile"),
    ('{"format": "loggrasp.pile", "format_version": "1.0", "terrain": {}, "logs": [{"centre_m": [0,0]}]}', "malformed"),
])
def test_malformed_files(tmp_path, text, match):
    (tmp_path / "pile.json").write_text(text)
    with pytest.raises(PileFormatError, match=match):
        read_pile(tmp_path)


def test_missing_file(tmp_path):
    with pytest.raises(PileFormatError, match="cannot read"):
        read_pile(tmp_path / "nope.json")


@pytest.mark.parametrize("kwargs,match", [
    ({"length_m": -1.0}, "length_m"),
    ({"diameter_m": 5.0}, "diameter_m"),
    ({"orientation": (0, 0, 0, 2)}, "unit quaternion"),
    ({"centre_m": (0, float("nan"), 0)}, "finite"),
    ({"top_diameter_m": 0.5}, "top_diameter_m"),
])
def test_log_validation(kwargs, match):
    base = dict(centre_m=(0, 0, 0.1), orientation=(0, 0, 0, 1), length_m=2.0, diameter_m=0.16)
    base.update(kwargs)
    with pytest.raises(ValueError, match=match):
        LogSpec(**base)


def test_log_off_terrain_rejected():
    with pytest.raises(ValueError, match="outside"):
        PileSpec(terrain=flat(), logs=(LogSpec(centre_m=(2.0, 0, 0.1), orientation=(0, 0, 0, 1),
                                               length_m=2.0, diameter_m=0.16),))


def test_hand_written_pile_loads_and_validates():
    ok = PileSpec(terrain=flat(), logs=(
        LogSpec(centre_m=(0, 0, 0.08), orientation=(0, 0, 0, 1), length_m=2.0, diameter_m=0.16),
        LogSpec(centre_m=(0, 0.3, 0.08), orientation=(0, 0, 0, 1), length_m=2.0, diameter_m=0.16),
    ))
    validate_pile(ok)


def test_hand_written_pile_through_terrain_is_rejected():
    bad = PileSpec(terrain=flat(), logs=(LogSpec(centre_m=(0, 0, -0.05), orientation=(0, 0, 0, 1),
                                                 length_m=2.0, diameter_m=0.16),))
    with pytest.raises(PileValidationError, match="terrain"):
        validate_pile(bad)


def test_hand_written_logs_intersecting_are_rejected():
    bad = PileSpec(terrain=flat(), logs=(
        LogSpec(centre_m=(0, 0, 0.08), orientation=(0, 0, 0, 1), length_m=2.0, diameter_m=0.16),
        LogSpec(centre_m=(0, 0.05, 0.08), orientation=quat_from_euler(0, 0, 0.3), length_m=2.0, diameter_m=0.16),
    ))
    with pytest.raises(PileValidationError, match="log 0 and log 1 interpenetrate"):
        validate_pile(bad)


def test_terrain_explicit_heights_shape_checked():
    with pytest.raises(ValueError, match="heights_m must be 16x16"):
        TerrainSpec(resolution=16, heights_m=((0.0,) * 8,) * 8)
