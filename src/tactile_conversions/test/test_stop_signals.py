"""Which errors mean that a Ctrl-C or SIGTERM stopped an rclpy process (real rclpy context, no DDS traffic)."""

import pytest
import rclpy
from rclpy.executors import ExternalShutdownException

from tactile_conversions.stop_signals import stopped_by_signal


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
