"""``classify``: the trial's outcome rules, every branch and the order they are checked in, without
physics."""

from __future__ import annotations

import pytest

from synth.physics.trial import Outcome, classify

LIMIT = 1000.0  # collision_force_n [N]


def outcome(held=(0, 1), enclosed=(0, 1), targets=(0, 1), n_targets=None, closed=True, force=0.0) -> Outcome:
    n = len(targets) if n_targets is None else n_targets
    return classify(force, LIMIT, closed, held, enclosed, targets, n)


def test_success_when_the_targets_are_held_and_nothing_dropped():
    assert outcome() is Outcome.SUCCESS
    assert outcome(held=(1, 0), enclosed=()) is Outcome.SUCCESS  # order and an empty enclosed set


def test_success_by_count_is_any_logs_of_that_number():
    assert outcome(held=(2, 3), enclosed=(2, 3), targets=None, n_targets=2) is Outcome.SUCCESS


def test_collision_is_checked_first_and_only_above_the_limit():
    assert outcome(force=LIMIT + 1e-9) is Outcome.COLLISION
    assert outcome(force=LIMIT) is Outcome.SUCCESS  # at the limit is not a collision
    assert outcome(force=LIMIT + 1, closed=False) is Outcome.COLLISION  # before NOT_CLOSED
    assert outcome(force=LIMIT + 1, held=(0,)) is Outcome.COLLISION  # before DROPPED
    assert outcome(force=LIMIT + 1, held=(), enclosed=()) is Outcome.COLLISION  # before FEWER_OR_OTHER


def test_not_closed_comes_before_every_held_set_rule():
    assert outcome(closed=False) is Outcome.NOT_CLOSED  # the targets "held" (lift skipped)
    assert outcome(closed=False, held=(0,)) is Outcome.NOT_CLOSED
    assert outcome(closed=False, held=(0, 1, 2), enclosed=(0, 1, 2)) is Outcome.NOT_CLOSED
    assert outcome(closed=False, held=(), enclosed=()) is Outcome.NOT_CLOSED


def test_dropped_when_an_enclosed_log_is_not_held():
    assert outcome(held=(0,)) is Outcome.DROPPED
    assert outcome(held=(), enclosed=(0,)) is Outcome.DROPPED


def test_dropped_beats_success_and_more_than_intended():
    assert outcome(held=(0, 1), enclosed=(0, 1, 2)) is Outcome.DROPPED  # targets held, one lost
    assert outcome(held=(0, 1, 2), enclosed=(0, 1, 2, 3)) is Outcome.DROPPED  # superset held, one lost
    assert outcome(held=(2, 3), enclosed=(1, 2, 3), targets=None, n_targets=2) is Outcome.DROPPED


def test_more_than_intended_is_a_strict_superset_of_the_targets():
    assert outcome(held=(0, 1, 2), enclosed=(0, 1, 2)) is Outcome.MORE_THAN_INTENDED
    assert outcome(held=(0, 2, 3), enclosed=(0, 2, 3)) is Outcome.FEWER_OR_OTHER  # more, but not all targets


def test_more_than_intended_by_count():
    assert outcome(held=(0, 1, 2), enclosed=(0,), targets=None, n_targets=2) is Outcome.MORE_THAN_INTENDED


@pytest.mark.parametrize("held, targets, n_targets", [
    ((), (0, 1), None),  # nothing held
    ((0,), (0, 1), None),  # fewer
    ((2, 3), (0, 1), None),  # others, as many
    ((0,), None, 2),  # fewer by count
    ((), None, 1),
])
def test_fewer_or_other(held, targets, n_targets):
    assert outcome(held=held, enclosed=held, targets=targets, n_targets=n_targets) is Outcome.FEWER_OR_OTHER


def test_takes_any_iterables():
    assert classify(0.0, LIMIT, True, iter([1, 0]), [0], (0, 1), 2) is Outcome.SUCCESS
