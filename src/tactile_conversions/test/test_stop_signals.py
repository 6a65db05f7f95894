"""Which errors mean that a Ctrl-C or SIGTERM stopped an rclpy process, and a block that such a stop ends quietly
(real rclpy context, no DDS traffic)."""

import pytest
import rclpy
from rclpy.executors import ExternalShutdownException

from tactile_conversions.stop_signals import stopped_by_signal, until_stop_signal


@pytest.fixture
def context():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_an_error_is_a_stop_only_once_rclpy_is_shut_down(context):
    assert stopped_by_signal(KeyboardInterrupt()) and stopped_by_signal(ExternalShutdownException())
    assert not stopped_by_signal(RuntimeError("failed to create timer"))  # a real failure while ROS runs
    rclpy.shutdown()  # what rclpy's handler does at once on SIGINT or SIGTERM
    assert stopped_by_signal(RuntimeError("failed to create timer: the given context is not valid"))
    assert not stopped_by_signal(SystemExit(1))  # not an error of an rcl call


def test_a_block_until_a_stop_signal_ends_quietly_on_the_stop_only(context):
    ran_on = []
    with until_stop_signal():
        raise KeyboardInterrupt
    with pytest.raises(RuntimeError, match="a real failure"), until_stop_signal():
        raise RuntimeError("a real failure")
    rclpy.shutdown()
    with until_stop_signal():
        raise RuntimeError("failed to get subscription count: publisher's context is invalid")
    ran_on.append(True)  # reached: the stop did not leave the function
    assert ran_on == [True]
