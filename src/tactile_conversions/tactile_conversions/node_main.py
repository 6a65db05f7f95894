"""The `main()` of every node of the stack: init, spin until Ctrl-C or SIGTERM, shut down cleanly."""

from __future__ import annotations

import faulthandler
import signal
from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def run_node(make_node: Callable[[], Node], args: list[str] | None = None) -> None:
    """Spin the node built by `make_node` until interrupted (SIGINT) or terminated (SIGTERM, ros2 launch).

    rclpy's signal handler shuts the ROS context down at once, from another thread, wherever the node is: in
    its constructor or in a callback a `create_*` or `publish` then fails ("context is invalid"). Such an
    error after shutdown was requested is the shutdown itself, so it ends the node cleanly (exit code 0).

    Once the node is shutting down, SIGINT is ignored (and stays so: the process is ending), so that a repeated
    Ctrl-C does not interrupt the shutdown.

    SIGUSR1 (`kill -USR1 <pid>`) prints the stack of every thread to stderr and the node keeps running: how to
    see where a node that does not stop is stuck.
    """
    faulthandler.register(signal.SIGUSR1)
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():
            raise
    finally:
        # A repeated Ctrl-C (`stop_nodes` repeats it) must not interrupt the shutdown itself: once rclpy's handler
        # is gone (try_shutdown restores Python's), it would raise KeyboardInterrupt here and end the node with -2.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
