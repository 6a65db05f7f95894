"""positive_float and whole_number on real rclpy nodes, with the values a command line gives (no DDS traffic)."""

import math

import pytest
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter

from tactile_conversions.parameters import positive_float, whole_number


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
    with pytest.raises(ValueError) as refused:
        positive_float(node_with(value), "period_s", 0.5, allow_zero=allow_zero)
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
    with pytest.raises(ValueError) as refused:
        whole_number(node_with(value), "period_s", 4, low)
    assert message in str(refused.value)
