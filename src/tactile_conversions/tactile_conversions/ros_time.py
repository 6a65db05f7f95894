"""builtin_interfaces/Time <-> float seconds, exact to the nanosecond on the way back from an integer count."""

from builtin_interfaces.msg import Time


def time_to_seconds(stamp: Time) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def seconds_to_time(seconds: float) -> Time:
    """A Time message for `seconds` (>= 0), rounded to the nearest nanosecond."""
    total_ns = round(seconds * 1e9)
    if total_ns < 0:
        raise ValueError(f"a ROS time cannot be negative, got {seconds} s")
    return Time(sec=total_ns // 1_000_000_000, nanosec=total_ns % 1_000_000_000)
