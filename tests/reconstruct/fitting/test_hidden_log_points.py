"""A log the scan does not show is placed from its GNSS points alone: points closer together than any
log are a survey error named as such, not a crash (held-out scan 3300102, degraded survey, crashed with
"log length_m must be in [0.3, 12] m" before)."""

from __future__ import annotations

import pytest

from reconstruct.errors import FitError
from reconstruct.fitting.ends import MIN_LOG_LENGTH_M
from reconstruct.fitting.fit_config import FitConfig
from reconstruct.fitting.partial import _survey_log


def test_a_hidden_log_is_placed_on_its_survey_axis():
    log = _survey_log((0.0, 0.0, 0.5), (2.0, 0.0, 0.5), 0.3, FitConfig(), "log4")
    assert log.length_m == pytest.approx(2.0) and log.diameter_m == pytest.approx(0.3)


def test_points_closer_than_any_log_are_refused_naming_the_log():
    with pytest.raises(FitError, match=r"'log4' is not seen .* 0\.19 m apart: shorter than any log .* re-measure both ends of 'log4'"):
        _survey_log((0.0, 0.0, 0.5), (0.19, 0.0, 0.5), 0.3, FitConfig(), "log4")
    _survey_log((0.0, 0.0, 0.5), (MIN_LOG_LENGTH_M + 0.01, 0.0, 0.5), 0.3, FitConfig(), "log4")


def test_a_hidden_log_too_short_to_lie_under_others_is_left_to_the_survey_axis():
    """The sandwich (a hidden log on the ground under others) is not built for ends closer than any log:
    it returns None and the survey's axis decides (and refuses them)."""
    import numpy as np

    from reconstruct.fitting.partial import _sandwiched_log

    from synth.scene.pile import LogSpec

    P = np.zeros((500, 3))
    P[:, :2] = np.random.default_rng(0).uniform(-1, 1, (500, 2))  # ground at 0 m
    over = [LogSpec.from_endpoints((0.0, -1.0, 0.5), (0.0, 1.0, 0.5), 0.3)]  # a log across, 0.35 m up
    assert _sandwiched_log(P, (-0.6, 0.0, 0.175), (0.6, 0.0, 0.175), over, FitConfig()) is not None
    assert _sandwiched_log(P, (-0.08, 0.0, 0.175), (0.08, 0.0, 0.175), over, FitConfig()) is None
