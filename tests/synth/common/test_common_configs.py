"""synth.common.configs.config_from_dict: the one way from plain values to a typed config."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from synth.common.configs import config_from_dict


@dataclass(frozen=True)
class Inner:
    width_m: float = 1.0
    mode: Literal["a", "b"] = "a"

    def __post_init__(self) -> None:
        if self.width_m <= 0:
            raise ValueError(f"width_m must be > 0, got {self.width_m}")


@dataclass(frozen=True)
class Outer:
    inner: Inner = field(default_factory=Inner)
    sizes: tuple[int, ...] = (1, 2)
    pair: tuple[float, float] = (0.0, 0.0)
    out: Path | None = None
    name: str = "x"


def test_round_trip_through_plain_values():
    c = Outer(Inner(2.0, "b"), (3, 4, 5), (1.5, 2.5), Path("/tmp/o"), "y")
    plain = {**asdict(c), "sizes": [3, 4, 5], "pair": [1.5, 2.5], "out": "/tmp/o"}  # what JSON gives back
    assert config_from_dict(Outer, plain) == c
    assert config_from_dict(Outer, {}) == Outer() and config_from_dict(Outer, {"out": None}).out is None


@pytest.mark.parametrize("d, match", [
    ({"inner": {"widht_m": 1.0}}, r"unknown Outer.inner fields \['widht_m'\]"),
    ({"colour": 1}, r"unknown Outer fields \['colour'\]"),
    ({"inner": {"mode": "c"}}, r"Outer.inner.mode must be one of \['a', 'b'\], got 'c'"),
    ({"pair": [1.0]}, r"Outer.pair must have 2 values, got 1"),
    ({"inner": {"width_m": -1.0}}, r"width_m must be > 0"),  # the dataclass's own validation runs
    ({"inner": 3}, r"Outer.inner must be a mapping"),
])
def test_bad_values_are_value_errors_naming_the_field(d, match):
    with pytest.raises(ValueError, match=match):
        config_from_dict(Outer, d)


def test_the_configs_that_use_it():
    from field.controller import ControllerConfig, controller_config_from_dict, controller_config_to_dict
    from planner.model import UNetConfig
    from planner.train import TrainConfig

    ctl = ControllerConfig(max_pile_age_s=60.0)
    assert controller_config_from_dict(controller_config_to_dict(ctl)) == ctl
    t = TrainConfig(epochs=3, model=UNetConfig.tiny(mask_injection="decoder"))
    assert TrainConfig.from_dict(asdict(t)) == t
    with pytest.raises(ValueError, match="mask_injection must be one of"):
        UNetConfig.from_dict({**asdict(UNetConfig()), "mask_injection": "encoder"})
