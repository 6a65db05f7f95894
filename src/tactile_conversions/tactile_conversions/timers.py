"""Timers that keep their pace whatever the system clock does."""

from __future__ import annotations

from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.timer import Timer


def steady_timer(node: Node, period_s: float, callback: Callable[[], None]) -> Timer:
    """A timer of `node` on the steady (monotonic) clock. `create_timer` uses the node's ROS clock, the system clock:
    an NTP step back of 30 s silenced a camera for 30 s (review). Stamps still come from the node's clock; only the
    pacing is steady (see clock_running for a simulated clock that does not run)."""
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


def clock_running(node: Node) -> bool:
    """Whether the node's clock gives stamps: not with use_sim_time before a /clock message came (it reads 0). A camera
    node publishes nothing then, and says so every 10 s: frames stamped 0 would be bundled with each other and with
    nothing else (review)."""
    if node.get_clock().now().nanoseconds:
        return True
    node.get_logger().warning("the node's clock reads 0 (use_sim_time true, and no /clock published yet?): no frame is "
                              "published until it runs", throttle_duration_sec=10.0)
    return False
