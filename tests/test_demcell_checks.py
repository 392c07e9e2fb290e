"""demcell.checks: the scalar path of Range.check gives the numpy path's answer, and the
messages stay one line."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from demcell import checks
from demcell.checks import ANY, POSITIVE, SEED, Range
from demcell.errors import InputError

RANGES = [ANY, POSITIVE, SEED, checks.STEP_BUDGET, checks.NON_NEGATIVE, Range(0.0, infinite=True),
          Range(1, integer=True, infinite=True), Range(0.0, 1.0, low_open=True, high_open=True), Range(-2.5, 3.0)]
VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10 ** 6, 10 ** 6),
                   st.sampled_from([0, 1, 0.0, 1.0, -0.0, 3.0, 2.5, 1e-300, 10 ** 15, 10 ** 15 + 1]))


@settings(max_examples=300, deadline=None, derandomize=True, database=None)   # the same draws every run
@given(value=VALUES, which=st.integers(0, len(RANGES) - 1))
def test_the_scalar_path_agrees_with_the_array_path(value, which):
    r = RANGES[which]
    assert r.admits(value) == bool(r.allows(value))


@pytest.mark.parametrize("value", [7, 7.0, np.int64(7), np.float64(7.0), np.array(7)])
def test_python_and_numpy_numbers_give_the_same_result(value):
    assert checks.number("n", value, checks.STEP_BUDGET) == 7
    assert type(checks.number("n", value, checks.STEP_BUDGET)) is int
    assert checks.number("x", value, POSITIVE) == 7.0


@pytest.mark.parametrize("value, allowed", [(-1, checks.STEP_BUDGET), (2.5, checks.STEP_BUDGET), (True, ANY),
                                            (math.nan, ANY), (math.inf, POSITIVE), (0.0, POSITIVE),
                                            (2 ** 63, SEED), ("3", ANY)])
def test_refusals_name_the_argument_on_one_line(value, allowed):
    with pytest.raises(InputError) as info:
        checks.number("n_steps", value, allowed)
    assert str(info.value).startswith("n_steps must be ") and "\n" not in str(info.value)


def test_array_without_a_copy_returns_the_callers_array_and_still_checks():
    a = np.ones((4, 3))
    assert checks.array("start", a, (4, 3), copy=False) is a
    assert checks.array("start", a, (4, 3)) is not a
    ints = np.ones((4, 3), dtype=np.int64)
    assert checks.array("start", ints, (4, 3), copy=False).dtype == np.float64
    a[2, 1] = np.nan
    with pytest.raises(InputError, match=r"start\[2\]\[1\] must be a finite number"):
        checks.array("start", a, (4, 3), copy=False)
