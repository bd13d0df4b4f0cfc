"""The laptop's own checks before a command goes on the wire (field.link.safety.CommandGuard):
each rule its own test, on a fixed clock."""

from __future__ import annotations

import pytest

from field.errors import CommandRejected
from field.link.messages import GraspCommand, RejectReason
from field.link.safety import CommandGuard, SafetyConfig

NOW_S = 1_780_000_000.0  # the guard's clock [s since epoch]


def command(command_id: int, plan_time_s: float) -> GraspCommand:
    return GraspCommand.from_metres(command_id, 744_005.0, 7_112_000.0, 50.0, 30.0, 0.9, 2, plan_time_s)


def guard(**cfg) -> CommandGuard:
    return CommandGuard(SafetyConfig(max_pile_age_s=30.0, max_future_skew_s=2.0, **cfg), clock=lambda: NOW_S)


def test_fresh_command_passes_and_burns_its_id():
    g = guard()
    g.reserve(command(7, NOW_S - 1.0))
    assert g.used(7)


def test_stale_pile_data_is_refused_locally_and_the_id_burned():
    g = guard()
    with pytest.raises(CommandRejected) as ei:
        g.reserve(command(8, NOW_S - 31.0))
    assert ei.value.reason is RejectReason.STALE and ei.value.local and "31.0 s old" in str(ei.value)
    assert g.used(8)


@pytest.mark.parametrize("ahead_s, refused", [(1.5, False), (2.5, True), (3600.0, True)])
def test_plan_stamped_in_the_laptops_future_is_refused_beyond_the_skew(ahead_s, refused):
    """A plan time ahead of the laptop clock (a wrong clock somewhere) would pass any age limit."""
    g = guard()
    if not refused:
        g.reserve(command(9, NOW_S + ahead_s))
        return
    with pytest.raises(CommandRejected) as ei:
        g.reserve(command(9, NOW_S + ahead_s))
    assert ei.value.reason is RejectReason.STALE and ei.value.local and "future skew limit 2.0 s" in str(ei.value)


def test_a_used_id_is_never_sent_again():
    g = guard()
    g.reserve(command(10, NOW_S))
    with pytest.raises(CommandRejected) as ei:
        g.reserve(command(10, NOW_S))
    assert ei.value.reason is RejectReason.DUPLICATE_ID and ei.value.local


def test_new_ids_are_non_zero_and_never_used_ones(monkeypatch):
    import field.link.safety

    g = guard()
    g.reserve(command(5, NOW_S))
    draws = iter([5, 0, 5, 6])  # a used id, zero, the used id again, then a fresh one
    monkeypatch.setattr(field.link.safety.secrets, "randbits", lambda bits: next(draws))
    assert g.new_command_id() == 6
