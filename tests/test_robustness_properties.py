"""Property tests (Hypothesis) of every demo's command line: any values of one to three of its
numeric options at once, NaN, inf, zero, negative, huge and tiny included, are refused in one line before any work
(always so outside the option's declared range), or the run ends cleanly: completed with
finite outputs, stopped with a reason, or, when still running after the time limit,
interrupted by SIGTERM with its outputs readable (tests/robustness.py judges).

A few derandomized draws per demo in `make test` (ROBUSTNESS_EXAMPLES, default 3); the
sweep over every option (`benchmarks/robustness/robustness_sweep.py`) and a larger random run of this
file (`make benchmark`: ROBUSTNESS_EXAMPLES=25, ROBUSTNESS_RANDOM=1) go further."""
import math
import os

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import robustness

pytestmark = pytest.mark.serial
EXAMPLES = int(os.environ.get("ROBUSTNESS_EXAMPLES", "3"))
DERANDOMIZE = os.environ.get("ROBUSTNESS_RANDOM", "0") != "1"


def value_strategy(spec):
    """The special values, and values inside and just outside the declared range."""
    low = spec["low"] if spec["low"] is not None else -1e6
    high = spec["high"] if spec["high"] is not None else max(1e6, 10 * abs(spec["default"] or 1.0))
    if spec["integer"]:
        inside = st.integers(int(low) - 2, int(min(high, low + 1000)) + 2).map(float)
    else:
        span = high - low
        inside = st.floats(min_value=low - 0.1 * span, max_value=high + 0.1 * span, allow_nan=False)
    return st.one_of(st.sampled_from(robustness.SPECIAL_VALUES), inside)


@pytest.mark.parametrize("demo", list(robustness.BASELINES))
def test_any_option_value_is_refused_or_ends_cleanly(demo, tmp_path):
    options = robustness.describe_options(demo)
    assert options, f"{demo} declares no numeric option"

    @settings(max_examples=EXAMPLES, deadline=None, derandomize=DERANDOMIZE, database=None,
              suppress_health_check=list(HealthCheck))
    @given(data=st.data())
    def check(data):
        # one to three options at once: a value may be fine alone and not with another
        chosen = data.draw(st.lists(st.sampled_from(sorted(options)), min_size=1, max_size=3, unique=True),
                           label="options")
        values = {option: data.draw(value_strategy(options[option]), label=option) for option in chosen}
        outcome, detail = robustness.run_case(demo, values, str(tmp_path / "out"), timeout=60)
        outside = [option for option, value in values.items() if not robustness.in_range(options[option], value)]
        if outside:
            assert outcome == "refused" and any(option in detail for option in outside), (values, outcome, detail)

    check()


def test_a_value_outside_the_range_is_always_named():
    """The judge itself: a declared range is what the refusals are checked against."""
    spec = dict(low=0.0, high=0.5, low_open=True, high_open=True, integer=False, infinite=False, default=0.1)
    assert robustness.in_range(spec, 0.25)
    assert not any(robustness.in_range(spec, v) for v in (0.0, 0.5, -1.0, math.nan, math.inf))
    count = dict(low=1, high=None, low_open=False, high_open=False, integer=True, infinite=False, default=1)
    assert robustness.in_range(count, 3.0) and not robustness.in_range(count, 2.5)
