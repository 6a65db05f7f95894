"""builtin_interfaces/Time <-> float seconds. A float64 holds present-day stamps (1.7e9 s) to about a quarter of a
microsecond, so a Time converted to seconds and back may differ in its last hundreds of nanoseconds; the stack's stamps
are compared to microseconds at the finest."""

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
    # The bounds first: 1e300 s overflowed the rounding to nanoseconds (OverflowError, review).
    return (math.isfinite(seconds) and -1.0 < seconds < TIME_LIMIT_S + 1.0
            and 0 <= round(seconds * 1e9) < TIME_LIMIT_S * 1_000_000_000)


def is_ros_stamp(stamp: Time) -> bool:
    """Whether a received Time can stamp a message a node sends on as it is: `sec` in [0, 2**31) and `nanosec` below
    a second. A Time message holds any int32 and uint32 (rclpy checks neither on receipt): sec -1 with nanosec 1.5e9
    is 0.5 s as seconds (is_ros_time), but a negative stamp as the message republished."""
    return 0 <= stamp.sec < TIME_LIMIT_S and 0 <= stamp.nanosec < 1_000_000_000


def seconds_to_time(seconds: float) -> Time:
    """A Time message for `seconds`, rounded to the nearest nanosecond; ValueError unless is_ros_time(seconds)."""
    if not is_ros_time(seconds):
        reason = "cannot be negative" if seconds < 0 else "must be a finite number below 2**31 s (sec is an int32)"
        raise ValueError(f"a ROS time {reason}, got {seconds} s")
    total_ns = round(seconds * 1e9)
    return Time(sec=total_ns // 1_000_000_000, nanosec=total_ns % 1_000_000_000)
