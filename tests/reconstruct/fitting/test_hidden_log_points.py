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
    with pytest.raises(FitError, match=r"'log4' .* 0\.19 m apart: shorter than any log .* re-measure both ends"):
        _survey_log((0.0, 0.0, 0.5), (0.19, 0.0, 0.5), 0.3, FitConfig(), "log4")
    _survey_log((0.0, 0.0, 0.5), (MIN_LOG_LENGTH_M + 0.01, 0.0, 0.5), 0.3, FitConfig(), "log4")
