"""positive_float, period_s, rate_hz, whole_number, boolean and text on real rclpy nodes, with the values a command
line gives (no DDS traffic)."""

import math

import pytest
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter

from tactile_conversions.parameters import (
    MAX_PERIOD_S,
    MAX_RATE_HZ,
    MIN_RATE_HZ,
    ParameterError,
    boolean,
    period_s,
    positive_float,
    rate_hz,
    text,
    whole_number,
)


@pytest.fixture
def node_with():
    """node_with(value): a node whose parameter `period_s` is set to `value` (None: not set)."""
    rclpy.init()
    nodes = []

    def make(value):
        overrides = [] if value is None else [Parameter("period_s", value=value)]
        nodes.append(Node("parameters_test", parameter_overrides=overrides))
        return nodes[-1]

    yield make
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


@pytest.mark.parametrize("value, allow_zero, expected", [
    (None, False, 0.5),  # the default
    (30, False, 30.0),   # `-p period_s:=30` is an integer
    (0.25, False, 0.25),
    (0, True, 0.0),
])
def test_numbers_are_taken_as_floats(node_with, value, allow_zero, expected):
    result = positive_float(node_with(value), "period_s", 0.5, allow_zero=allow_zero)
    assert result == expected and isinstance(result, float)


@pytest.mark.parametrize("value, allow_zero, message", [
    (math.nan, False, "parameters_test: parameter period_s must be a finite number > 0, got nan"),
    (math.nan, True, "parameter period_s must be a finite number >= 0, got nan"),
    (math.inf, False, "must be a finite number > 0, got inf"),
    (0.0, False, "must be a finite number > 0, got 0.0"),
    (-1, True, "must be a finite number >= 0, got -1"),
    ("fast", False, "parameter period_s must be a finite number > 0, got 'fast'"),
    (True, False, "parameter period_s must be a finite number > 0, got True"),
])
def test_anything_else_is_refused_naming_the_parameter(node_with, value, allow_zero, message):
    with pytest.raises(ParameterError) as refused:
        positive_float(node_with(value), "period_s", 0.5, allow_zero=allow_zero)
    assert message in str(refused.value)


def test_a_period_of_up_to_a_day_and_a_rate_of_at_least_once_a_day_make_a_timer(node_with):
    node = node_with(MAX_PERIOD_S)
    assert period_s(node, "period_s", 0.5) == MAX_PERIOD_S
    assert node.create_timer(MAX_PERIOD_S, lambda: None).timer_period_ns == 86_400 * 10**9
    node = node_with(MIN_RATE_HZ)
    assert node.create_timer(1.0 / rate_hz(node, "period_s", 40.0), lambda: None).timer_period_ns == 86_400 * 10**9
    assert rate_hz(node_with(30), "period_s", 40.0) == 30.0
    node = node_with(MAX_RATE_HZ)
    assert node.create_timer(1.0 / rate_hz(node, "period_s", 40.0), lambda: None).timer_period_ns == 1_000_000


@pytest.mark.parametrize("helper, value, message", [
    (period_s, 1e12, "parameters_test: parameter period_s must be at most 86400 s (one day), got 1000000000000.0"),
    # rounded to whole nanoseconds, a bundle node's camera check (every half timeout) ran on every spin: a core held
    (period_s, 1e-10, "parameters_test: parameter period_s must be at least 0.001 s, got 1e-10"),
    (period_s, 86_401, "parameter period_s must be at most 86400 s (one day), got 86401"),
    (period_s, math.nan, "parameter period_s must be a finite number > 0, got nan"),
    (rate_hz, 1e-12, "parameters_test: parameter period_s must be at least 1.15741e-05 Hz (once a day), got 1e-12"),
    (rate_hz, 0, "parameter period_s must be a finite number > 0, got 0"),
    # a timer of period 0 (rcl rounds 1e-12 s to whole nanoseconds), which fires on every spin
    (rate_hz, 1e12, "parameters_test: parameter period_s must be at most 1000 Hz, got 1000000000000.0"),
    (rate_hz, 1000.5, "parameter period_s must be at most 1000 Hz, got 1000.5"),
])
def test_a_period_a_timer_cannot_take_is_refused_naming_the_parameter(node_with, helper, value, message):
    """rclpy's create_timer fails on a period past int64 nanoseconds with a TypeError naming no parameter, and makes
    a timer of period 0 from one below a nanosecond."""
    with pytest.raises(ParameterError) as refused:
        helper(node_with(value), "period_s", 0.5)
    assert message in str(refused.value)


@pytest.mark.parametrize("value, expected", [(None, 4), (10, 10), (1, 1)])
def test_whole_numbers_are_taken(node_with, value, expected):
    assert whole_number(node_with(value), "period_s", 4) == expected


@pytest.mark.parametrize("value, low, message", [
    (0, 1, "parameters_test: parameter period_s must be a whole number >= 1, got 0"),
    (-1, 0, "must be a whole number >= 0, got -1"),
    (2.0, 1, "must be a whole number >= 1, got 2.0"),  # rcl would have refused it with a traceback
    ("3", 1, "must be a whole number >= 1, got '3'"),
    (True, 1, "must be a whole number >= 1, got True"),
])
def test_anything_but_a_whole_number_is_refused_naming_the_parameter(node_with, value, low, message):
    with pytest.raises(ParameterError) as refused:
        whole_number(node_with(value), "period_s", 4, low)
    assert message in str(refused.value)


@pytest.mark.parametrize("helper, default, value, expected", [
    (boolean, True, None, True),
    (boolean, True, False, False),
    (text, "demo", None, "demo"),
    (text, "demo", "3", "3"),  # `-p period_s:="'3'"`
    (text, "demo", "", ""),
])
def test_switches_and_names_are_taken(node_with, helper, default, value, expected):
    assert helper(node_with(value), "period_s", default) == expected


@pytest.mark.parametrize("helper, default, value, message", [
    # rclpy's typed declaration refused these with an InvalidParameterTypeException traceback naming no node
    (boolean, True, 0, "parameters_test: parameter period_s must be a bool (true or false), got 0"),
    (boolean, True, "false", "parameter period_s must be a bool (true or false), got 'false'"),
    (text, "demo", 3, "parameters_test: parameter period_s must be a string, got 3"),
    (text, "demo", True, "parameter period_s must be a string, got True"),
])
def test_a_switch_or_a_name_of_another_type_is_refused_naming_the_parameter(node_with, helper, default, value,
                                                                            message):
    with pytest.raises(ParameterError) as refused:
        helper(node_with(value), "period_s", default)
    assert message in str(refused.value)


@pytest.mark.parametrize("declare", [positive_float, period_s, rate_hz])
def test_a_parameter_read_at_start_up_refuses_a_later_change(node_with, declare):
    """The nodes read their parameters once: a change later was reported a success and changed nothing, and left NaN
    in the parameter (review)."""
    node = node_with(2.0)
    assert declare(node, "period_s", 1.0) == 2.0
    result, = node.set_parameters([Parameter("period_s", value=math.nan)])
    assert not result.successful and "read-only" in result.reason
    assert node.get_parameter("period_s").value == 2.0
