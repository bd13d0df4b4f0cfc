"""The paired difference's standard error: discordant piles, each count plus one half."""

import math

import numpy as np

from experiments.measure import paired_se, percentile


def test_paired_se_counts_only_the_piles_that_disagree():
    a = np.array([1, 1, 1, 0, 0, 1, 0, 1])
    b = np.array([1, 0, 1, 1, 0, 1, 0, 1])  # one pile only a, one only b
    n = len(a)
    expected = math.sqrt(1.5 + 1.5 - 0.0) / n
    assert paired_se(a, b) == expected
    # piles where both agree change nothing but n
    assert paired_se(np.r_[a, 1, 0], np.r_[b, 1, 0]) == math.sqrt(3.0) / (n + 2)


def test_paired_se_is_not_zero_when_no_pile_disagrees():
    same = np.ones(40)
    assert paired_se(same, same) == math.sqrt(1.0) / 40  # the half counts: no false certainty


def test_paired_se_with_a_one_sided_difference():
    a, b = np.zeros(10), np.r_[np.ones(4), np.zeros(6)]  # b wins on 4 piles
    assert math.isclose(paired_se(a, b), math.sqrt(0.5 + 4.5 - 4.0 ** 2 / 10) / 10)


def test_percentile_of_nothing_is_nan():
    assert math.isnan(percentile([], 50)) and percentile([1, 2, 3], 50) == 2.0
