"""Timers that keep their pace whatever the system clock does."""

from __future__ import annotations

from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.timer import Timer


def steady_timer(node: Node, period_s: float, callback: Callable[[], None]) -> Timer:
    """A timer of `node` on the steady (monotonic) clock. `create_timer` uses the node's ROS clock, the system clock:
    an NTP step back of 30 s silenced a camera for 30 s, and with use_sim_time and no /clock it never fired (review).
    Stamps still come from the node's clock; only the pacing is steady."""
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))
