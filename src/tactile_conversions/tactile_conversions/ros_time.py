"""builtin_interfaces/Time <-> float seconds, exact to the nanosecond on the way back from an integer count."""

import math

from builtin_interfaces.msg import Time

#: The first time in seconds that a Time cannot hold, its `sec` being an int32 (in 2038). rclpy does not check the
#: range: a message stamped `sec=2**31` goes out as `sec=-2**31`.
TIME_LIMIT_S = 2**31


def time_to_seconds(stamp: Time) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def is_ros_time(seconds: float) -> bool:
    """Whether seconds_to_time takes `seconds`: 0 up to TIME_LIMIT_S (excluded), rounded to the nanosecond.

    A Time with a negative `sec` is a legal message, but not a time a node can stamp its output with."""
    return math.isfinite(seconds) and 0 <= round(seconds * 1e9) < TIME_LIMIT_S * 1_000_000_000


def seconds_to_time(seconds: float) -> Time:
    """A Time message for `seconds`, rounded to the nearest nanosecond; ValueError unless is_ros_time(seconds)."""
    if not is_ros_time(seconds):
        reason = "cannot be negative" if seconds < 0 else "must be a finite number below 2**31 s (sec is an int32)"
        raise ValueError(f"a ROS time {reason}, got {seconds} s")
    total_ns = round(seconds * 1e9)
    return Time(sec=total_ns // 1_000_000_000, nanosec=total_ns % 1_000_000_000)
