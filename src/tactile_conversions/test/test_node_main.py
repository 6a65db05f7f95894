"""run_node: how a node's process ends (real rclpy, no DDS traffic)."""

import signal

import pytest
import rclpy
from rclpy.node import Node
from std_msgs.msg import Header

from tactile_conversions.node_main import run_node


@pytest.fixture(autouse=True)
def restore_ctrl_c():
    """run_node leaves SIGINT ignored (its process is ending); give this test process its handler back."""
    previous = signal.getsignal(signal.SIGINT)
    yield
    signal.signal(signal.SIGINT, previous)


class ShutDownWhileStarting(Node):
    """What Ctrl-C during a node's constructor looks like: the context is shut down, then a publisher is made."""

    def __init__(self):
        super().__init__("shut_down_while_starting")
        rclpy.shutdown()
        self.create_publisher(Header, "/never", 1)


def test_an_error_after_shutdown_was_requested_ends_the_node_cleanly():
    with pytest.raises(Exception, match="destruction was requested"):  # what such a node does outside run_node
        rclpy.init()
        try:
            ShutDownWhileStarting()
        finally:
            rclpy.try_shutdown()
    assert run_node(ShutDownWhileStarting) is None
    assert not rclpy.ok()
    # A Ctrl-C repeated while the node shuts down (stop_nodes repeats it) must not interrupt the shutdown.
    assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN


def test_an_error_while_ros_runs_is_raised_and_ros_is_shut_down():
    def broken_node():
        raise ValueError("bad parameter")

    with pytest.raises(ValueError, match="bad parameter"):
        run_node(broken_node)
    assert not rclpy.ok()
