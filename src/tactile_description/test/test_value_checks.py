"""The two predicates every input check of the stack uses."""

import math

import numpy as np
import pytest

from tactile_description.value_checks import is_number, is_whole_number


@pytest.mark.parametrize("value", [0, -3, 2.5, np.float32(0.1), np.int64(7), np.float64(-1e300)])
def test_finite_reals_are_numbers(value):
    assert is_number(value)


@pytest.mark.parametrize("value", [True, False, np.bool_(True), math.nan, math.inf, -math.inf, np.float64(np.nan),
                                   "1", None, [1], 1j])
def test_bools_non_finite_values_and_other_types_are_not_numbers(value):
    assert not is_number(value)


@pytest.mark.parametrize("value, low", [(1, 1), (10**12, 1), (0, 0), (np.int32(3), 1), (-2, -5)])
def test_integers_at_or_above_the_bound_are_whole_numbers(value, low):
    assert is_whole_number(value, low)


@pytest.mark.parametrize("value, low", [(0, 1), (-1, 0), (2.0, 1), (np.float64(3.0), 1), (True, 1), (False, 0),
                                        (np.bool_(True), 1), ("3", 1), (None, 0), (math.nan, 0)])
def test_floats_bools_and_integers_below_the_bound_are_not_whole_numbers(value, low):
    assert not is_whole_number(value, low)
