"""positive_float on real rclpy nodes, with the values a command line gives (no DDS traffic)."""

import math

import pytest
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter

from tactile_conversions.parameters import positive_float


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
    (-1, True, "must be a finite number >= 0, got -1.0"),
    ("fast", False, "parameter period_s must be a number > 0, got 'fast'"),
    (True, False, "parameter period_s must be a number > 0, got True"),
])
def test_anything_else_is_refused_naming_the_parameter(node_with, value, allow_zero, message):
    with pytest.raises(ValueError) as refused:
        positive_float(node_with(value), "period_s", 0.5, allow_zero=allow_zero)
    assert message in str(refused.value)
