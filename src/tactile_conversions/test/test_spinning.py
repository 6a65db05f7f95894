import math

import pytest
import rclpy
from rclpy.node import Node

from tactile_conversions.spinning import spin_until


@pytest.fixture
def node():
    rclpy.init()
    made = Node("spinning_test")
    yield made
    made.destroy_node()
    rclpy.try_shutdown()


def test_spin_until_says_whether_the_condition_came_true_in_time(node):
    calls = []
    assert spin_until(node, lambda: calls.append(1) or len(calls) >= 3, 5.0) and len(calls) == 3
    assert not spin_until(node, lambda: False, 0.1)


@pytest.mark.parametrize("timeout_s", [math.nan, math.inf, -1.0])
def test_a_wait_without_a_finite_timeout_is_refused(node, timeout_s):
    """A NaN deadline never came: the wait never ended (review). The condition gives up after 20 calls, so that a
    regression fails here instead of hanging the run."""
    calls = []
    with pytest.raises(ValueError, match="spin_until: timeout_s must be a finite number >= 0"):
        spin_until(node, lambda: calls.append(1) or len(calls) > 20, timeout_s)
    assert calls == []
